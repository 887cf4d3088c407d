"""Errors shared by every layer. Imports nothing, so any package may raise them."""

from __future__ import annotations


class UsageError(ValueError):
    """Bad user input: the CLI prints it without a traceback and exits with code 2."""
