"""``python -m benchmark`` is the ``uavbench`` command."""

from benchmark.cli import main

raise SystemExit(main())
