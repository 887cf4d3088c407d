"""Errors shared by every layer. Imports nothing, so any package may raise them.

``InputError`` is the library's typed error for input it cannot use: a file, a field or a value
that is wrong. Its message names that file, field or value (by its Python name: a config field,
an argument, a path; never a command-line flag) and what was expected. ``UsageError`` is the
command line's: a flag the command layer refuses. The dispatcher (``benchmark.commands.main``)
prints either without a traceback and exits with code 2; only ``benchmark/commands/`` and the
config validation (``benchmark.config``) raise ``UsageError``.
"""

from __future__ import annotations


class InputError(ValueError):
    """Input a library function cannot use; the message names it and what was expected."""


class UsageError(InputError):
    """Bad command-line use (raised by ``benchmark.commands`` and config validation): the CLI
    prints it without a traceback and exits with code 2."""
