"""Reproduction runner: the paper's tables from specs, through four floors that import only down.

``plan`` (specs, scales, units) <- ``execute`` (workers, executors, tracking of a unit's run) <-
``claims`` (per-frame errors, intervals, verdicts) <- ``report`` (tables, figures, README, logbook).
``reproduction`` strings them together::

    from benchmark.runner import ReproduceConfig, reproduce

    result = reproduce(ReproduceConfig(profile="smoke", tracker="null"))  # result.ok, .written

(``uavbench reproduce`` is ``benchmark.commands.reproduce``: it parses its flags into a
``ReproduceConfig``.) The two names load on first use, so importing one floor loads no other.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from benchmark.runner.reproduction import ReproduceConfig, reproduce

__all__ = ["ReproduceConfig", "reproduce"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from benchmark.runner import reproduction

        return getattr(reproduction, name)
    raise AttributeError(f"module 'benchmark.runner' has no attribute {name!r}")
