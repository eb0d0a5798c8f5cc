"""illumon."""
