"""``ModelConfig``: the one description of a pair model, used everywhere (issue 13).

The same frozen dataclass is what :func:`benchmark.models.create_model` builds, what
``TrainConfig.model`` holds (``uavbench train --set model.attitude_options.hidden=512``), what a
table spec row produces, and what a checkpoint saves next to the weights::

    ModelConfig(
        encoder="googlenet", encoder_options={"norm": "group"},
        variant="a-f", width=1.0, input_size=None,         # None: the dataset's image size
        attitude="pd_re_net", attitude_options={"kappa": 5.0},
        translation="regression", translation_options={},
        aux_weight=0.3, channels_last=True, shared_satellite=True, satellite_input="image",
    )

Head and encoder options are checked against the constructor of the named head (encoder factory)
when the config is made, before any data is opened: an option it does not take is a ValueError
naming the head and every option it accepts; a value is converted to the type of the parameter
(its annotation, else its default's type; strings are read as YAML scalars, so ``"512"`` -> 512);
and a value equal to the constructor's default is dropped, so that "kappa 10" and "no kappa" are
one model with one hash (Fig. 7's kappa 10 is Table 1's Pd/Re-Net). Option values themselves
(e.g. ``kappa > 0``) are checked by the head when the model is built. The typing is
``benchmark.config.convert``, the converter of every config class, so an option and a config
field read ``"true"``, ``"1e3"`` or ``"none"`` alike.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from benchmark.config import convert, parse_scalar, split_optional

PAPER_INPUT_SIZE = 224  # what create_model builds when neither config nor caller give a size
SATELLITE_INPUTS = ("image", "blank")
# Field names of the format-1 checkpoints (before issue 13) and where they live now.
LEGACY_FIELDS = {
    "attitude_kwargs": "attitude_options",
    "translation_kwargs": "translation_options",
    "encoder_kwargs": "encoder_options",
}
_ENCODER_ARGS = ("variant", "width", "input_size")  # passed by build_model, not options
_SCALARS = (bool, int, float, str)  # the option types convert is asked for; others stay as given
__all__ = [
    "LEGACY_FIELDS",
    "PAPER_INPUT_SIZE",
    "SATELLITE_INPUTS",
    "ModelConfig",
    "check_satellite_input",
    "describe_options",
    "normalize_options",
    "option_parameters",
    "parse_scalar",
]


def check_satellite_input(value: object, where: str = "ModelConfig") -> str:
    """``value`` if it is one of :data:`SATELLITE_INPUTS`; ValueError naming it otherwise."""
    if value not in SATELLITE_INPUTS:
        raise ValueError(
            f"{where}: satellite_input must be one of {SATELLITE_INPUTS}, got {value!r}"
        )
    return str(value)


def option_type(annotation: Any, default: Any) -> Any:
    """What ``convert`` types an option by: the parameter's annotation when it is one of
    bool/int/float/str (or that ``| None``), else the type of its default when that is one of
    them, else ``Any`` (strings still read as YAML scalars); ``| None`` also when the default is
    None."""
    optional, inner = split_optional(annotation)
    tp = inner if inner in _SCALARS else None
    if tp is None and default not in (inspect.Parameter.empty, None):
        tp = type(default) if type(default) in _SCALARS else None
    tp = Any if tp is None else tp
    return tp | None if optional or default is None else tp


def option_parameters(
    fn: Callable[..., Any], skip: tuple[str, ...]
) -> dict[str, inspect.Parameter] | None:
    """The keyword options of ``fn`` (a head class or an encoder factory) without ``skip``;
    None when it takes ``**kwargs`` (anything goes)."""
    target = fn.__init__ if isinstance(fn, type) else fn
    params = inspect.signature(target).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return None
    return {
        n: p
        for n, p in params.items()
        if n not in ("self", *skip)
        and p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    }


def describe_options(params: Mapping[str, inspect.Parameter]) -> str:
    """``"alpha (default 80000000.0), hidden (default 160)"``: what an error message lists."""
    parts = [
        n if p.default is inspect.Parameter.empty else f"{n} (default {p.default!r})"
        for n, p in sorted(params.items())
    ]
    return ", ".join(parts) or "no options"


def normalize_options(
    fn: Callable[..., Any],
    options: Mapping[str, Any],
    *,
    owner: str,
    field_name: str,
    skip: tuple[str, ...] = ("in_features",),
) -> dict[str, Any]:
    """``options`` checked against ``fn``'s signature, typed, defaults dropped, keys sorted.

    ``owner`` (e.g. ``"attitude head 'pd_re_net'"``) and ``field_name`` (``"attitude_options"``)
    name the culprit in the ValueError of an unknown option or a value of the wrong type.
    """
    if not isinstance(options, Mapping):
        raise ValueError(f"{field_name}: expected a mapping of options, got {options!r}")
    params = option_parameters(fn, skip)
    if params is None:
        return {str(k): options[k] for k in sorted(options, key=str)}
    unknown = sorted(set(map(str, options)) - set(params))
    if unknown:
        raise ValueError(
            f"{field_name}: {owner} takes no option {', '.join(map(repr, unknown))}; "
            f"it takes: {describe_options(params)}"
        )
    try:
        hints = typing.get_type_hints(fn.__init__ if isinstance(fn, type) else fn)
    except Exception:  # an annotation that does not resolve: fall back to the defaults' types
        hints = {}
    out: dict[str, Any] = {}
    for name in sorted(options):
        param, value = params[name], options[name]
        default = param.default
        tp = option_type(hints.get(name), default)
        if isinstance(value, str) and split_optional(tp)[1] is not str:
            value = parse_scalar(value)  # "512" -> 512 also for an untyped option
        value = convert(value, tp, f"{field_name}.{name}")
        if not _same(value, default):
            out[name] = value
    return out


def _same(value: Any, default: Any) -> bool:
    if default is inspect.Parameter.empty or type(value) is not type(default):
        return False
    if isinstance(value, float) and math.isnan(value):
        return False
    return bool(value == default)


def _encoder_factory(name: str) -> Callable[..., Any]:
    """The factory registered as encoder ``name`` (the registry has no public getter yet)."""
    from benchmark.models import registry

    known = registry.list_encoders()  # runs discovery
    if name not in known:
        raise ValueError(f"unknown encoder {name!r}; known: {', '.join(known)}")
    return registry._ENCODERS[name]


@dataclass(frozen=True)
class ModelConfig:
    """Everything that defines a ``PoseModel``; saved with its checkpoints. See the module doc."""

    # Field names before issue 13 -> now (benchmark.config refuses them with this hint).
    MOVED: ClassVar[dict[str, str]] = LEGACY_FIELDS

    encoder: str = "googlenet"
    encoder_options: dict[str, Any] = field(default_factory=dict)
    variant: str = "a-f"  # "/", "a" (SE on the final branch), "f" (triple fusion), "a-f" (AGTFM)
    width: float = 1.0  # channel multiplier of the encoder
    input_size: int | None = None  # px; None: the dataset's (create_model: 224, the paper's)
    attitude: str = "pd_re_net"
    attitude_options: dict[str, Any] = field(default_factory=dict)  # final and both aux heads
    translation: str = "regression"
    translation_options: dict[str, Any] = field(default_factory=dict)
    aux_weight: float = 0.3  # w1 = w2 of Algorithm 1 (paper Sec. 3.3)
    channels_last: bool = True  # memory format only: 1.2-2x faster convolutions on CPU
    # Encode each distinct satellite image of a batch once (``sat_ids``; exact with the default
    # per-sample GroupNorm, benchmark.models.pair). False: the model ignores ``sat_ids``.
    shared_satellite: bool = True
    satellite_input: str = "image"  # "blank": the UAV-only control, the satellite image is grey

    def __post_init__(self) -> None:
        from benchmark.models.registry import get_head_class

        for name in ("encoder", "variant", "attitude", "translation"):
            if not isinstance(getattr(self, name), str):
                raise ValueError(f"{name} must be a name (str), got {getattr(self, name)!r}")
        width = self.width
        if isinstance(width, bool) or not isinstance(width, (int, float)):
            raise ValueError(f"width must be a number > 0, got {width!r}")
        if not (math.isfinite(width) and width > 0):
            raise ValueError(f"width must be > 0 and finite, got {width!r}")
        size = self.input_size
        if size is not None and (isinstance(size, bool) or not isinstance(size, int) or size < 1):
            raise ValueError(f"input_size must be an int >= 1 or None, got {size!r}")
        aux = self.aux_weight
        if isinstance(aux, bool) or not isinstance(aux, (int, float)) or not math.isfinite(aux):
            raise ValueError(f"aux_weight must be a finite number, got {aux!r}")
        if aux < 0:
            raise ValueError(f"aux_weight must be >= 0.0, got {aux!r}")
        for name in ("channels_last", "shared_satellite"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        check_satellite_input(self.satellite_input)
        encoder_factory = _encoder_factory(self.encoder)  # unknown encoder: lists the known
        heads = {
            "attitude_options": get_head_class(self.attitude, "attitude"),
            "translation_options": get_head_class(self.translation, "translation"),
        }
        owners = {
            "attitude_options": f"attitude head {self.attitude!r}",
            "translation_options": f"translation head {self.translation!r}",
        }
        normalized = {
            name: normalize_options(cls, getattr(self, name), owner=owners[name], field_name=name)
            for name, cls in heads.items()
        }
        normalized["encoder_options"] = normalize_options(
            encoder_factory,
            self.encoder_options,
            owner=f"encoder {self.encoder!r}",
            field_name="encoder_options",
            skip=_ENCODER_ARGS,
        )
        for name, value in normalized.items():
            object.__setattr__(self, name, value)  # frozen: the canonical copy, set once
        object.__setattr__(self, "width", float(width))
        object.__setattr__(self, "aux_weight", float(aux))

    def __hash__(self) -> int:  # the option dicts are not hashable; their JSON is
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (JSON/YAML safe); ``ModelConfig.from_dict`` reads it back."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "model config") -> ModelConfig:
        """Build from a mapping (e.g. a checkpoint's ``model_config``), accepting the field names
        of checkpoint format 1 (``attitude_kwargs`` ...); unknown fields are a ValueError
        naming ``where``."""
        data = {LEGACY_FIELDS.get(k, k): v for k, v in data.items()}
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"{where}: unknown model config field(s) {unknown}; known: {sorted(known)}"
            )
        return cls(**data)

    def resolved(self, input_size: int | None = None) -> ModelConfig:
        """This config with ``input_size`` set: its own, else ``input_size`` (the dataset's),
        else :data:`PAPER_INPUT_SIZE`. Both given and different is a ValueError."""
        if self.input_size is not None:
            if input_size is not None and input_size != self.input_size:
                raise ValueError(
                    f"input_size={self.input_size} but the images are {input_size} px; leave "
                    "input_size unset to follow the dataset"
                )
            return self
        return dataclasses.replace(self, input_size=input_size or PAPER_INPUT_SIZE)
