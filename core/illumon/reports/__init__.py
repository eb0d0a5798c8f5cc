"""Reproducible reports (Markdown + PNG + JSON) on illumon's models and data."""
