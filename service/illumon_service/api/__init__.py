"""HTTP API of the illumon service."""
