"""The matching encoder's options, grouped by what they decide, each group a small frozen config
that checks its own values.

- :class:`MatchingLoss`: the protocol and the encoder's own loss;
- :class:`MatchingGeometry`: the bird's-eye view and the searched pose volume;
- :class:`MatchingCamera`: the geometry assumed when an item brings no ``context``;
- :class:`MatchingNetwork`: the CNNs, the gravity branch, the correlation and its temperature;
- :class:`MatchingAugmentation`: what perturbs the training inputs.

The defaults are declared here, once. A config names the options flat
(``model.encoder_options.n_yaw=24``, as stored in every run key), and :meth:`MatchingOptions.
from_flat` routes each to its group; the registered factory ``matching`` publishes the same flat
names, defaults and annotations (:meth:`MatchingOptions.parameters`), so the factory, the configs
and the class cannot drift apart (``tests/models/test_matching_factory.py``). No torch here: the
report reads the defaults too.
"""

from __future__ import annotations

import dataclasses
import inspect
import itertools
import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "CORRELATIONS",
    "PROTOCOLS",
    "MatchingAugmentation",
    "MatchingCamera",
    "MatchingGeometry",
    "MatchingLoss",
    "MatchingNetwork",
    "MatchingOptions",
]

PROTOCOLS = ("vision_only", "gravity_aided")
CORRELATIONS = ("xdft", "dft", "fft", "conv")  # matching_ops.correlate's methods


def _error(message: str) -> ValueError:
    return ValueError(f"matching encoder: {message}")


def _non_negative(**values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value >= 0):
            raise _error(f"{name} must be >= 0, got {value!r}")


def _positive(**values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise _error(f"{name} must be > 0, got {value!r}")


@dataclass(frozen=True)
class MatchingLoss:
    """``protocol``: ``"vision_only"`` (the paper's: the view from the gravity branch at test
    time, from the sensor priors in training) or ``"gravity_aided"`` (from the priors always).
    ``volume_nll_weight`` x the NLL of the pose volume at the true pose (0: the heads' loss
    only), its target smoothed by Gaussians of ``smoothing`` cells / yaw bins;
    ``gravity_weight`` x the gravity branch's smooth L1 error."""

    protocol: str = "vision_only"
    volume_nll_weight: float = 1.0
    gravity_weight: float = 1.0
    smoothing: float = 0.5

    def __post_init__(self) -> None:
        if self.protocol not in PROTOCOLS:
            raise _error(f"protocol must be one of {PROTOCOLS}, got {self.protocol!r}")
        _non_negative(volume_nll_weight=self.volume_nll_weight, gravity_weight=self.gravity_weight)
        _positive(smoothing=self.smoothing)


@dataclass(frozen=True)
class MatchingGeometry:
    """``n_yaw`` yaw bins; ``cell_m`` the grid cell (m); ``search_m`` the half-side of the
    searched square (m); ``template_m`` the bird's-eye radius (m); ``height_planes`` /
    ``plane_spacing_m`` the height-aware view (0 planes: the flat ground);
    ``altitude_offsets_m`` metres around the view's altitude, the volume's scale dimension
    (empty: one altitude)."""

    n_yaw: int = 36
    cell_m: float = 20.8
    search_m: float = 400.0
    template_m: float = 250.0
    height_planes: int = 0
    plane_spacing_m: float = 10.0
    altitude_offsets_m: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        _positive(cell_m=self.cell_m, search_m=self.search_m, template_m=self.template_m)
        if self.n_yaw < 4:
            raise _error(f"need n_yaw >= 4, got {self.n_yaw}")
        if self.height_planes < 0 or self.height_planes == 1:
            raise _error(f"height_planes must be 0 (the ground plane only) or >= 2, got "
                         f"{self.height_planes!r}")  # fmt: skip
        _positive(plane_spacing_m=self.plane_spacing_m)
        offsets = tuple(float(d) for d in self.altitude_offsets_m)
        if offsets and (
            len(offsets) < 2
            or not all(math.isfinite(d) for d in offsets)
            or any(b <= a for a, b in itertools.pairwise(offsets))
        ):
            raise _error(f"altitude_offsets_m must be empty (one altitude) or at least 2 finite, "
                         f"strictly increasing offsets in metres, got "
                         f"{self.altitude_offsets_m!r}")  # fmt: skip
        if offsets and self.height_planes:
            raise _error("altitude_offsets_m and height_planes cannot be combined (the "
                         "height-aware view has no altitude search)")  # fmt: skip
        object.__setattr__(self, "altitude_offsets_m", offsets)

    @property
    def search_cells(self) -> int:
        """Cells from the centre to the edge of the searched square."""
        return max(1, round(self.search_m / self.cell_m))

    @property
    def template_cells(self) -> int:
        """Cells from the centre to the edge of the bird's-eye view."""
        return max(1, round(self.template_m / self.cell_m))


@dataclass(frozen=True)
class MatchingCamera:
    """The geometry assumed for an item without a ``context``: the UAV camera's horizontal field
    of view (deg), the satellite image's E x N footprint (m) and its capture height (m)."""

    default_fov_deg: float = 60.0
    default_footprint_m: tuple[float, float] = (2000.0, 1000.0)
    default_sat_height_m: float = 1000.0

    def __post_init__(self) -> None:
        footprint = tuple(float(x) for x in self.default_footprint_m)
        if len(footprint) != 2:
            raise _error(f"default_footprint_m must be (E, N) metres, got "
                         f"{self.default_footprint_m!r}")  # fmt: skip
        object.__setattr__(self, "default_footprint_m", footprint)


@dataclass(frozen=True)
class MatchingNetwork:
    """``channels`` / ``out_channels`` size the two CNNs, ``gravity_dim`` the gravity branch;
    ``temperature`` the correlation's initial temperature; ``correlation`` how the volume is
    computed (``"xdft"``: a real DFT along the columns and one batched GEMM along the rows, the
    fastest here; ``"dft"``: the 2-D DFT by complex matrix products, the default before issue 40
    and ``bench train``'s base row; ``"fft"``, ``"conv"``: all the same numbers to float32
    rounding); ``grey_gradient`` adds fixed grey-level and gradient channels."""

    channels: int = 16
    out_channels: int = 8
    gravity_dim: int = 32
    temperature: float = 50.0
    correlation: str = "xdft"
    grey_gradient: bool = False

    def __post_init__(self) -> None:
        if self.channels < 1 or self.out_channels < 1 or self.gravity_dim < 1:
            raise _error(f"need channels, out_channels, gravity_dim >= 1; got {self.channels}, "
                         f"{self.out_channels}, {self.gravity_dim}")  # fmt: skip
        _positive(temperature=self.temperature)
        if self.correlation not in CORRELATIONS:
            raise _error(f"correlation must be one of {CORRELATIONS}, got {self.correlation!r}")


@dataclass(frozen=True)
class MatchingAugmentation:
    """``photometric``: strength of the training images' colour jitter (0: none);
    ``train_view_noise_deg`` / ``train_view_noise_m``: extra Gaussian noise on the training
    view's pitch and roll (deg) and height (m), on top of the sensor priors'."""

    photometric: float = 0.0
    train_view_noise_deg: float = 0.0
    train_view_noise_m: float = 0.0

    def __post_init__(self) -> None:
        _non_negative(photometric=self.photometric, train_view_noise_deg=self.train_view_noise_deg,
                      train_view_noise_m=self.train_view_noise_m)  # fmt: skip


_GROUPS = {
    "loss": MatchingLoss,
    "geometry": MatchingGeometry,
    "camera": MatchingCamera,
    "network": MatchingNetwork,
    "augmentation": MatchingAugmentation,
}


@dataclass(frozen=True)
class MatchingOptions:
    """Every option of the matching encoder, by group (each group's doc says what it decides)."""

    loss: MatchingLoss = field(default_factory=MatchingLoss)
    geometry: MatchingGeometry = field(default_factory=MatchingGeometry)
    camera: MatchingCamera = field(default_factory=MatchingCamera)
    network: MatchingNetwork = field(default_factory=MatchingNetwork)
    augmentation: MatchingAugmentation = field(default_factory=MatchingAugmentation)

    @staticmethod
    def names() -> list[str]:
        """The flat option names, group by group, in declaration order."""
        return [f.name for group in _GROUPS.values() for f in dataclasses.fields(group)]

    @classmethod
    def from_flat(cls, options: Mapping[str, Any]) -> MatchingOptions:
        """The groups holding ``options`` (flat names, as in a config); the rest at their
        defaults. An unknown name is a ValueError listing the accepted ones."""
        unknown = sorted(set(options) - set(cls.names()))
        if unknown:
            raise _error(f"no option {', '.join(map(repr, unknown))}; it takes: "
                         f"{', '.join(cls.names())}")  # fmt: skip
        groups = {}
        for name, group in _GROUPS.items():
            own = {f.name for f in dataclasses.fields(group)}
            groups[name] = group(**{k: v for k, v in options.items() if k in own})
        return cls(**groups)

    def flat(self) -> dict[str, Any]:
        """Every option by its flat name (defaults included)."""
        return {
            f.name: getattr(getattr(self, name), f.name)
            for name, group in _GROUPS.items()
            for f in dataclasses.fields(group)
        }

    @staticmethod
    def parameters() -> list[inspect.Parameter]:
        """The flat options as keyword-only parameters with their defaults and annotations: the
        signature the registered factory publishes (``ModelConfig`` reads it)."""
        out = []
        for group in _GROUPS.values():
            hints = typing.get_type_hints(group)
            for f in dataclasses.fields(group):
                default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
                kind = inspect.Parameter.KEYWORD_ONLY
                out.append(inspect.Parameter(f.name, kind, default=default,
                                             annotation=hints[f.name]))  # fmt: skip
        return out
