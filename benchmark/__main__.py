"""``python -m benchmark`` is the ``uavbench`` command."""

from benchmark.commands.main import main

raise SystemExit(main())
