"""Subcommand ``fit`` (being written)."""
