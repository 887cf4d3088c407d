"""Generic machinery for frozen-dataclass configs: overrides, flattening, hashing, YAML.

Each stage owns its config dataclasses (``benchmark.training.config`` etc.); this module knows only
dataclasses and their type annotations:

- ``apply_overrides(cfg, ["optim.lr=0.01", "model.attitude=re_net_r"])``: a new config; each value
  is converted by the annotation of the field it targets (``int``, ``float``, ``bool``, ``str``,
  ``tuple[...]``, ``Optional[...]`` / ``X | None``, ``Literal[...]``, nested dataclasses,
  ``dict[str, Any]``). An entry of a mapping field is set by its key,
  ``model.attitude_options.hidden=512``: the value is read as a YAML scalar and the owning
  dataclass types it. A class may list keys it no longer has in a ``MOVED`` class attribute
  (``{"loss.kappa": "model.attitude_options.kappa"}``); such a key is refused with where it lives.
- ``flatten(cfg)``: ``{"optim.lr": 0.001, ...}`` (dotted keys, scalar values) for MLflow params.
- ``config_hash(cfg)``: sha256 of a canonical JSON form; the same config always gives the same hash.
- ``to_dict`` / ``from_dict`` / ``load_yaml`` / ``save_yaml``: round trip, errors naming the
  file and the field.

Every error is a :class:`ConfigError` (a ``ValueError``) naming the key, the value and the type that
was expected.

:func:`convert` is the project's one converter from strings and YAML scalars to typed values:
``ModelConfig`` types head and encoder options with it too (``benchmark.models.model_config``),
by the constructor parameter's annotation. Why not pydantic (installed, as a dependency of mlflow
and fastapi, not of ours) or OmegaConf (not installed): their lax coercion is another set of rules
(pydantic reads ``"t"``/``"y"`` as true and refuses ``"1e3"`` for an int), their errors would have
to be translated back to the ``key=value: expected type`` lines users and tests read, and the
dotted overrides, ``MOVED`` keys and options mappings stay ours either way; the converter is ~100
lines.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar, Union

T = TypeVar("T")

_TRUE = {"true", "yes", "on", "1"}
_FALSE = {"false", "no", "off", "0"}
_NONE = {"none", "null", "~"}


class ConfigError(ValueError):
    """Bad configuration: the message names the key (and file), the value and the expected type."""


def _field_types(cls: type) -> dict[str, Any]:
    # get_type_hints resolves string annotations (``from __future__ import annotations``).
    return typing.get_type_hints(cls)


def _type_name(tp: Any) -> str:
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def split_optional(tp: Any) -> tuple[bool, Any]:
    """``(True, X)`` for ``X | None`` / ``Optional[X]`` (X a union itself when it has several
    members), else ``(False, tp)``."""
    origin = typing.get_origin(tp)
    if origin is Union or origin is types.UnionType:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) != len(typing.get_args(tp)):
            inner = args[0] if len(args) == 1 else Union[tuple(args)]  # noqa: UP007
            return True, inner
    return False, tp


def _split_sequence(text: str) -> list[str]:
    text = text.strip()
    if text[:1] in "([" and text[-1:] in ")]":
        text = text[1:-1]
    return [part.strip() for part in text.split(",") if part.strip()]


def convert(value: Any, tp: Any, key: str) -> Any:
    """Convert ``value`` (a string from the CLI or a YAML scalar/list) to annotation ``tp``.

    Raises :class:`ConfigError` naming ``key``. Ints are not silently truncated from floats, bools
    are not silently read from ints other than 0/1, and non-finite floats are allowed (``"nan"``).
    """

    def fail(extra: str = "") -> ConfigError:
        return ConfigError(f"{key}={value!r}: expected {_type_name(tp)}{extra}")

    optional, inner = split_optional(tp)
    if optional:
        if value is None or (isinstance(value, str) and value.strip().lower() in _NONE):
            return None
        return convert(value, inner, key)
    if tp is Any:
        return value
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        choices = typing.get_args(tp)
        for choice in choices:
            try:
                if convert(value, type(choice), key) == choice:
                    return choice
            except ConfigError:
                continue
        raise ConfigError(f"{key}={value!r}: expected one of {', '.join(map(repr, choices))}")
    if origin in (dict, Mapping) or tp is dict:
        # An options mapping (e.g. model.attitude_options): a YAML mapping, or on the command
        # line a flow mapping "{kappa: 5, hidden: 512}". Values stay as given (YAML-typed); the
        # owning dataclass checks and types them.
        mapping = parse_yaml_value(value) if isinstance(value, str) else value
        if not isinstance(mapping, Mapping):
            raise fail(" (a mapping, e.g. {name: value})")
        return {str(k): v for k, v in mapping.items()}
    if origin in (tuple, list):
        args = typing.get_args(tp)
        items = _split_sequence(value) if isinstance(value, str) else value
        if not isinstance(items, (list, tuple)):
            raise fail(" (a sequence)")
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            out = [convert(v, args[0], f"{key}[{i}]") for i, v in enumerate(items)]
        elif origin is tuple and args:
            if len(items) != len(args):
                raise fail(f" ({len(args)} items, got {len(items)})")
            out = [
                convert(v, a, f"{key}[{i}]")
                for i, (v, a) in enumerate(zip(items, args, strict=True))
            ]
        else:
            elem = args[0] if args else Any
            out = [convert(v, elem, f"{key}[{i}]") for i, v in enumerate(items)]
        return tuple(out) if origin is tuple else out
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if isinstance(value, Mapping):
            return from_dict(tp, value, _prefix=f"{key}.")
        raise ConfigError(
            f"{key}={value!r}: is a section ({tp.__name__}); set one of its fields, e.g. "
            f"{key}.{dataclasses.fields(tp)[0].name}=..."
        )
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, int) and value in (0, 1):
            return bool(value)
        if isinstance(value, str) and value.strip().lower() in _TRUE | _FALSE:
            return value.strip().lower() in _TRUE
        raise fail(" (true/false)")
    if tp is int:
        if isinstance(value, bool):
            raise fail()
        if isinstance(value, int):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, str):
            try:
                return int(value.strip().replace("_", ""))
            except ValueError:
                try:
                    as_float = float(value)
                except ValueError:
                    raise fail() from None
                if math.isfinite(as_float) and as_float.is_integer():
                    return int(as_float)  # "1e3" -> 1000
        raise fail()
    if tp is float:
        if isinstance(value, bool):
            raise fail()
        if isinstance(value, (int, float)):
            return float(value)
        if isinstance(value, str):
            try:
                return float(value.strip())
            except ValueError:
                raise fail() from None
        raise fail()
    if tp is str:
        if isinstance(value, (str, int, float)) and not isinstance(value, bool):
            return str(value)
        raise fail()
    if tp is Path:
        if isinstance(value, (str, Path)):
            return Path(value)
        raise fail()
    raise ConfigError(f"{key}: unsupported annotation {_type_name(tp)} in the config class")


def parse_yaml_value(text: str) -> Any:
    """``text`` read as YAML (``"512"`` -> 512, ``"{a: 1}"`` -> dict); a number YAML 1.1 keeps
    as a string (``"1e-3"``) becomes a float; unparsable text stays the string."""
    import yaml

    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def parse_scalar(text: str) -> Any:
    """A string as a YAML scalar: ``"512"`` -> 512, ``"1e-3"`` -> 0.001 (YAML 1.1 would keep
    it a string), ``"true"`` -> True, ``"null"`` -> None, anything else the string itself."""
    value = parse_yaml_value(text)
    return value if isinstance(value, (bool, int, float, type(None))) else text


def _moved(cls: type, key: str, prefix: str = "") -> str | None:
    """Where a key that config class ``cls`` no longer has lives now, from its ``MOVED`` class
    mapping (old dotted key relative to ``cls`` -> new one), or None. ``prefix`` is ``cls``'s own
    place in the whole config (``"model."``)."""
    moved: Mapping[str, str] = getattr(cls, "MOVED", {})
    hits = [
        f"{prefix}{old} -> {prefix}{new}"
        for old, new in moved.items()
        if old == key or old.startswith(f"{key}.") or key.startswith(f"{old}.")
    ]
    return "; ".join(hits) or None


def _require_dataclass(cfg: Any) -> None:
    if not dataclasses.is_dataclass(cfg) or isinstance(cfg, type):
        raise TypeError(f"expected a dataclass instance, got {type(cfg).__name__}")


def _set_path(cfg: Any, path: list[str], raw: Any, full_key: str) -> Any:
    name = path[0]
    names = [f.name for f in dataclasses.fields(cfg)]
    if name not in names:
        prefix = full_key[: len(full_key) - len(".".join(path))]
        moved = _moved(type(cfg), ".".join(path), prefix)
        if moved:
            raise ConfigError(f"config key {full_key!r} has moved: {moved}")
        raise ConfigError(
            f"unknown config key {full_key!r}: {type(cfg).__name__} has no field {name!r} "
            f"(known: {', '.join(prefix + n for n in names)})"
        )
    tp = _field_types(type(cfg))[name]
    current = getattr(cfg, name)
    if len(path) == 1:
        new = convert(raw, tp, full_key)
    elif isinstance(current, Mapping) and len(path) == 2:
        # One entry of an options mapping, e.g. model.attitude_options.hidden=512: the value is
        # read as a YAML scalar here and typed by the owning dataclass.
        value = parse_yaml_value(raw) if isinstance(raw, str) else raw
        new = {**current, path[1]: value}
    else:
        optional, inner = split_optional(tp)
        if current is None and optional and dataclasses.is_dataclass(inner):
            current = inner()  # an unset optional section: start from its defaults
        if not dataclasses.is_dataclass(current):
            raise ConfigError(
                f"unknown config key {full_key!r}: {name!r} is of type {_type_name(tp)}, "
                "not a section"
            )
        new = _set_path(current, path[1:], raw, full_key)
    return dataclasses.replace(cfg, **{name: new})


def split_assignment(item: str, example: str = "optim.lr=0.01") -> tuple[str, str]:
    """``"a.b=value"`` -> ``("a.b", "value")``: the one KEY=VALUE reader of every ``--set``
    (config overrides, model options, reference options). The value is returned as written;
    :func:`parse_scalar` or the field's type converts it. ConfigError naming ``item`` and
    ``example`` without a ``=`` or a key."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"{item!r}: expected KEY=VALUE, e.g. {example}")
    return key, raw


def apply_overrides(cfg: T, overrides: Iterable[str]) -> T:
    """Return ``cfg`` with each ``"a.b=value"`` applied in order (``cfg`` itself is frozen)."""
    _require_dataclass(cfg)
    for item in overrides:
        try:
            key, raw = split_assignment(item)
        except ConfigError as err:
            raise ConfigError(f"override {err}") from None
        try:
            cfg = _set_path(cfg, key.split("."), raw, key)
        except (TypeError, ValueError) as err:  # __post_init__ validation of the new dataclass
            if isinstance(err, ConfigError):
                raise
            raise ConfigError(f"override {item!r}: {err}") from err
    return cfg


def to_dict(cfg: Any) -> dict[str, Any]:
    """Nested plain dict (tuples become lists, Paths strings): JSON and YAML safe."""
    _require_dataclass(cfg)

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        if isinstance(v, Path):
            return str(v)
        if isinstance(v, Mapping):
            return {str(k): plain(x) for k, x in v.items()}
        return v

    return plain(cfg)


def flatten(cfg: Any, sep: str = ".", *, drop_none: bool = False) -> dict[str, Any]:
    """``{"optim.lr": 0.001, "data.size": [96, 96] -> "(96, 96)"}``: scalar values only.

    Sequences become their string form so MLflow shows them in one param. ``drop_none``: leave
    out the fields that are ``None`` (unset), so a tracker shows no ``None`` param.
    """
    out: dict[str, Any] = {}

    def walk(prefix: str, v: Any) -> None:
        if isinstance(v, dict):
            for k, x in v.items():
                walk(f"{prefix}{sep}{k}" if prefix else k, x)
        elif isinstance(v, list):
            out[prefix] = "(" + ", ".join(str(x) for x in v) + ")"
        elif v is not None or not drop_none:
            out[prefix] = v

    walk("", to_dict(cfg))
    return out


def canonical_json(cfg: Any) -> str:
    """Sorted keys, no whitespace, floats by ``repr`` (shortest round-trip): byte-stable."""
    return json.dumps(to_dict(cfg), sort_keys=True, separators=(",", ":"), allow_nan=True)


def config_hash(cfg: Any, length: int = 16) -> str:
    """First ``length`` hex digits of sha256 of :func:`canonical_json` (plus the class name, so two
    config classes with equal fields do not collide)."""
    payload = f"{type(cfg).__module__}.{type(cfg).__qualname__}:{canonical_json(cfg)}"
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()[:length]


def from_dict(cls: type[T], data: Mapping[str, Any], *, source: str = "", _prefix: str = "") -> T:
    """Build ``cls`` from a nested mapping; missing fields keep their defaults.

    ``source`` (a file name) prefixes every error message.
    """
    where = f"{source}: " if source else ""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}{_prefix.rstrip('.') or cls.__name__}: expected a mapping")
    types_ = _field_types(cls)
    known = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(map(str, data)) - known)
    for name in unknown:
        moved = _moved(cls, name, _prefix)
        if moved:
            raise ConfigError(f"{where}config key {_prefix + name!r} has moved: {moved}")
    if unknown:
        raise ConfigError(
            f"{where}unknown config key {_prefix + unknown[0]!r} "
            f"(known in {cls.__name__}: {', '.join(sorted(known))})"
        )
    kwargs = {}
    for name, value in data.items():
        key = _prefix + str(name)
        try:
            kwargs[name] = convert(value, types_[name], key)
        except ConfigError as err:
            if where and not str(err).startswith(where):
                raise ConfigError(f"{where}{err}") from None
            raise
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        if isinstance(err, ConfigError):
            raise
        raise ConfigError(f"{where}{_prefix.rstrip('.') or cls.__name__}: {err}") from err


def load_yaml(path: str | Path, cls: type[T] | None = None) -> T | dict[str, Any]:
    """Read a YAML file: into ``cls`` if given (validated), else the raw mapping."""
    import yaml

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read the config file ({err.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML ({err})") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data if cls is None else from_dict(cls, data, source=str(path))


def save_yaml(cfg: Any, path: str | Path, header: str | None = None) -> Path:
    """Write ``cfg`` as YAML (fields in declaration order); ``header`` lines become comments."""
    import yaml

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = yaml.safe_dump(to_dict(cfg), sort_keys=False, default_flow_style=None)
    lines = [f"# {line}" for line in (header or "").splitlines()]
    path.write_text("\n".join([*lines, body]) if lines else body, encoding="utf-8")
    return path
