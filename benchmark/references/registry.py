"""The references by name: ``create_reference(name, **options)``, ``list_references()``."""

from __future__ import annotations

import inspect

from benchmark.references.base import Reference
from benchmark.references.oracle import GeometryOracle
from benchmark.references.pnp import FeaturePnP
from benchmark.references.template import GravityTemplate

__all__ = ["REFERENCES", "create_reference", "get_reference_class", "list_references"]

REFERENCES: dict[str, type[Reference]] = {
    cls.name: cls for cls in (GeometryOracle, GravityTemplate, FeaturePnP)
}


def list_references() -> list[str]:
    """Registered reference names, in report order (oracle, gravity-aided, feature + PnP)."""
    return list(REFERENCES)


def get_reference_class(name: str) -> type[Reference]:
    """The class registered as ``name``; ValueError listing the known names otherwise."""
    try:
        return REFERENCES[name]
    except KeyError:
        raise ValueError(
            f"unknown reference {name!r}; known: {', '.join(list_references())}"
        ) from None


def create_reference(name: str, **options: object) -> Reference:
    """Build reference ``name`` with ``options`` (its constructor's keyword arguments).

    An option it does not take raises TypeError naming it and the accepted ones with their
    defaults; a bad value raises the reference's own ValueError.
    """
    cls = get_reference_class(name)
    params = inspect.signature(cls.__init__).parameters
    accepted = {k: p.default for k, p in params.items() if k != "self"}
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        listed = ", ".join(f"{k}={v!r}" for k, v in accepted.items())
        raise TypeError(f"reference {name!r} takes no option(s) {unknown}; it takes: {listed}")
    return cls(**options)
