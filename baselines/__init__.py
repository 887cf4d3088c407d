"""Representation heads, one file each.

Importing this package imports every module in it, so that each registers its heads
(``@register_head``). The head registry imports it through this project's entry point
``uavbench.heads: baselines`` (``pyproject.toml``), never by name: the registry sits below the
heads.
"""

import importlib
import pkgutil

for _module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
    if not _module.name.startswith("_"):
        # A head module that fails to import is a bug in this repository: let the error surface.
        importlib.import_module(f"{__name__}.{_module.name}")
