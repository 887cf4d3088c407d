"""The command layer, the top floor: one module per ``uavbench`` subcommand.

A command module only parses its arguments: it exposes ``HELP: str`` (one line for
``uavbench --help``), ``add_arguments(parser)`` and ``run(args) -> int`` (the exit code), where
``run`` checks the flags, builds the library's frozen config and calls the library function
below, which never sees an ``argparse.Namespace``. ``benchmark.commands.main`` is the dispatcher
(the console script ``uavbench``); ``benchmark.commands.bench`` dispatches ``uavbench bench
TARGET`` to the ``bench_*`` modules. argparse is imported nowhere else in ``benchmark/``.

Nothing below imports this package; bad user input is ``benchmark.errors.UsageError`` (exit 2).
"""
