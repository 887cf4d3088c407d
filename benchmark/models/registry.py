"""Name -> class registries for heads and encoders (timm style).

Heads::

    @register_head("re_net_r")
    class ReNetR(AttitudeHead): ...

    head = create_head("re_net_r", in_features=4096)
    list_heads("attitude")  # ['pd_net_e', 'pd_net_q', ...]

Heads are found through the entry-point group ``uavbench.heads`` on the first registry lookup (an
entry point may name a module, which registers its heads on import, or a head class, which is
registered under the entry point's name). The built-in heads come the same way as any other
package's: this project's ``pyproject.toml`` declares the entry point ``baselines = "baselines"``,
and importing ``baselines`` imports every module in it (so a new head is one new file there). The
registry therefore names no package above it: the heads depend on the contract, never the reverse.
Encoders work the same way with ``register_encoder`` / ``create_encoder`` / ``list_encoders`` and
the group ``uavbench.encoders`` (the two built-in encoders live beside the registry).

An entry point of this project's own distribution that fails to load is a bug in this repository and
raises; another package's only warns, so that a broken plug-in cannot take the built-in heads down.
The registries are plain dicts; discovery runs once per process and is idempotent.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect
import types
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

from benchmark.models.heads import AttitudeHead, Head, TranslationHead

HEAD_ENTRY_POINT_GROUP = "uavbench.heads"
ENCODER_ENTRY_POINT_GROUP = "uavbench.encoders"
_BUILTIN_ENCODER_MODULES = ("benchmark.models.googlenet", "benchmark.models.matching")
# The distribution whose entry points are this repository's own (the built-in heads): strict.
PROJECT_DISTRIBUTION = "uavbench"

_HEADS: dict[str, type[Head]] = {}
_ENCODERS: dict[str, Callable[..., Any]] = {}
_discovered = {"heads": False, "encoders": False}

H = TypeVar("H", bound=type[Head])
F = TypeVar("F", bound=Callable[..., Any])


def _qualified(obj: Any) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', repr(obj))}"


def head_kind(cls: type[Head]) -> str:
    """``'attitude'`` or ``'translation'`` for a head class."""
    if issubclass(cls, AttitudeHead):
        return "attitude"
    if issubclass(cls, TranslationHead):
        return "translation"
    raise TypeError(f"{cls.__name__} is neither an AttitudeHead nor a TranslationHead")


def register_head(name: str) -> Callable[[H], H]:
    """Class decorator: make a head constructible by ``create_head(name, ...)``.

    The class must derive from ``AttitudeHead`` or ``TranslationHead``; it receives ``cls.name``.
    Registering a different class under a taken name is an error (re-registering the same class,
    e.g. after ``importlib.reload``, is allowed).
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"head name must be a Python identifier, got {name!r}")

    def decorator(cls: H) -> H:
        if not (isinstance(cls, type) and issubclass(cls, (AttitudeHead, TranslationHead))):
            raise TypeError(
                f"@register_head({name!r}) needs an AttitudeHead or TranslationHead subclass, "
                f"got {cls!r}"
            )
        old = _HEADS.get(name)
        if old is not None and _qualified(old) != _qualified(cls):
            raise ValueError(
                f"head name {name!r} is already registered by {old.__module__}.{old.__qualname__}"
            )
        cls.name = name
        _HEADS[name] = cls
        return cls

    return decorator


def register_encoder(name: str) -> Callable[[F], F]:
    """Decorator for an encoder factory ``(variant, width, input_size, **kwargs) -> Encoder``."""

    def decorator(factory: F) -> F:
        old = _ENCODERS.get(name)
        if old is not None and _qualified(old) != _qualified(factory):
            raise ValueError(f"encoder name {name!r} is already registered by {old!r}")
        _ENCODERS[name] = factory
        return factory

    return decorator


def _is_own(ep: importlib.metadata.EntryPoint) -> bool:
    dist = getattr(ep, "dist", None)
    return dist is not None and dist.name == PROJECT_DISTRIBUTION


def _load_entry_points(group: str, registry: dict[str, Any], register: Callable) -> None:
    for ep in importlib.metadata.entry_points(group=group):
        try:
            obj = ep.load()
        except Exception as err:
            if _is_own(ep):  # this repository's own heads: a bug here, let it surface
                raise
            # a broken plug-in must not break the built-in heads
            warnings.warn(
                f"entry point {ep.name!r} ({ep.value}) in group {group!r} failed to load: {err}",
                stacklevel=3,
            )
            continue
        # A module registers its heads/encoders when imported; a class or factory is registered
        # under the entry point's name unless it registered itself already.
        if not isinstance(obj, types.ModuleType) and obj not in registry.values():
            try:
                register(ep.name)(obj)
            except (TypeError, ValueError) as err:
                if _is_own(ep):
                    raise
                warnings.warn(f"entry point {ep.name!r} in group {group!r}: {err}", stacklevel=3)


def _discover_heads() -> None:
    if _discovered["heads"]:
        return
    # A failed load raises before discovery is marked done, so the next lookup tries again.
    _load_entry_points(HEAD_ENTRY_POINT_GROUP, _HEADS, register_head)
    if not _HEADS:
        raise RuntimeError(
            f"no heads registered: the built-in heads (baselines/) are found through the entry "
            f"point group {HEAD_ENTRY_POINT_GROUP!r} of the installed {PROJECT_DISTRIBUTION!r} "
            f"distribution, and it declares none here; install the project as the README says "
            f'(pip install torch==2.13.0 -e ".[dev]"), again after a pull that changed '
            f"pyproject.toml"
        )
    _discovered["heads"] = True


def _discover_encoders() -> None:
    if _discovered["encoders"]:
        return
    for module in _BUILTIN_ENCODER_MODULES:
        importlib.import_module(module)
    _load_entry_points(ENCODER_ENTRY_POINT_GROUP, _ENCODERS, register_encoder)
    _discovered["encoders"] = True


def list_heads(kind: str | None = None) -> list[str]:
    """Sorted registered head names; ``kind`` = ``'attitude'`` / ``'translation'`` filters."""
    if kind not in (None, "attitude", "translation"):
        raise ValueError(f"kind must be None, 'attitude' or 'translation', got {kind!r}")
    _discover_heads()
    return sorted(n for n, c in _HEADS.items() if kind is None or head_kind(c) == kind)


def get_head_class(name: str, kind: str | None = None) -> type[Head]:
    """The class registered as ``name``; an unknown name raises ValueError listing the known."""
    _discover_heads()
    cls = _HEADS.get(name)
    if cls is None or (kind is not None and head_kind(cls) != kind):
        what = f"{kind} head" if kind else "head"
        raise ValueError(f"unknown {what} {name!r}; known: {', '.join(list_heads(kind))}")
    return cls


def head_versions(attitude: str, translation: str) -> dict[str, int]:
    """``{"attitude": v, "translation": v}``: the ``version`` of the two named heads.

    Part of a finished run's identity (runner units, ``uavbench train``), so that a change to a
    head's maths, which bumps its version, invalidates the runs made with the old maths.
    """
    return {
        "attitude": get_head_class(attitude, "attitude").version,
        "translation": get_head_class(translation, "translation").version,
    }


def create_head(name: str, kind: str | None = None, **kwargs: Any) -> Head:
    """Instantiate the head registered as ``name`` with ``kwargs`` (e.g. ``in_features=4096``).

    An option the head does not take raises ``TypeError`` naming it and the accepted ones.
    """
    cls = get_head_class(name, kind)
    params = inspect.signature(cls.__init__).parameters
    if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        unknown = sorted(set(kwargs) - set(params))
        if unknown:
            accepted = [p for p in params if p not in ("self", "in_features")]
            raise TypeError(
                f"head {name!r} does not take option(s) {', '.join(unknown)}; "
                f"it takes: {', '.join(accepted) or 'none'}"
            )
    return cls(**kwargs)


def list_encoders() -> list[str]:
    _discover_encoders()
    return sorted(_ENCODERS)


def create_encoder(name: str, **kwargs: Any) -> Any:
    """Build the encoder registered as ``name``; unknown names list the known ones."""
    _discover_encoders()
    factory = _ENCODERS.get(name)
    if factory is None:
        raise ValueError(f"unknown encoder {name!r}; known: {', '.join(sorted(_ENCODERS))}")
    return factory(**kwargs)
