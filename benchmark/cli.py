"""The old path of the ``uavbench`` entry point, kept for ``python -m benchmark.cli`` and
``from benchmark.cli import main`` (tests, scripts): the dispatcher is
:mod:`benchmark.commands.main`."""

from benchmark.commands.main import main
from benchmark.errors import UsageError  # re-exported: benchmark.cli.UsageError still works

__all__ = ["UsageError", "main"]

if __name__ == "__main__":
    raise SystemExit(main())
