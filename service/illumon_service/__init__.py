"""illumon service."""
