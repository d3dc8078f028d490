"""Subcommand ``ripple`` (being written)."""
