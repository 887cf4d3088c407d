"""What a non-learned reference is: a per-frame estimator of the UAV pose from one pair of images
plus the true values it declares it is given, and nothing else.

A reference sees a :class:`Frame`: the UAV image, the satellite image it is served (the pair's own
or, in the swap probe, another place's), what is legitimately known about the pair without its
labels, and exactly the true pose values the reference is given. Legitimately known (what every
method, learned or not, has): the satellite image's geo-reference (:class:`SatelliteGrid`: the
capture point E, N, the ground plane's height ``sat_U - sat_height_m`` and the footprint of the
pair's *true* satellite image, which is what the labels are relative to) and the UAV camera's
intrinsics (image size, field of view). Not known: the UAV's true pose (:data:`TRUE_POSE_COLUMNS`),
the labels derived from it (``R00``..``R22``, ``dE``, ``dN``, ``dU``), the flight, time and
illumination of the UAV frame.

What a reference is given is declared once, in its ``given_values`` (a tuple of
:class:`GivenValue`): the evaluation builds each frame's :class:`TrueValues` from those columns
only, so a withheld value is absent from the frame, not merely unread; and the reference's row
label and its ``given`` wording (the report's "reads the true ...") are derived from the same
declaration when the class is defined.
"""

from __future__ import annotations

import abc
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from benchmark.references.ground import SatelliteGrid
from benchmark.sim import Camera

__all__ = [
    "ALTITUDE",
    "PITCH",
    "POSITION",
    "ROLL",
    "TRUE_POSE_COLUMNS",
    "Estimate",
    "Frame",
    "GivenValue",
    "Reference",
    "TrueValues",
    "WithheldError",
    "check_yaw_sweep",
]

# The true UAV pose a pair row carries (absolute ENU metres, radians): what a reference may be
# given. The labels derived from it (R00..R22, dE, dN, dU) are never given.
TRUE_POSE_COLUMNS: tuple[str, ...] = ("E", "N", "U", "yaw", "pitch", "roll")


@dataclass(frozen=True)
class GivenValue:
    """One true value a reference may be given: the pose-table ``columns`` it carries (of
    :data:`TRUE_POSE_COLUMNS`), its ``words`` in the report ("reads the true <words>, ...") and
    its ``short`` name in the row label ("given true <short>, ...")."""

    columns: tuple[str, ...]
    words: str
    short: str

    def __post_init__(self) -> None:
        unknown = [c for c in self.columns if c not in TRUE_POSE_COLUMNS]
        if not self.columns or unknown:
            raise ValueError(
                f"GivenValue.columns must name some of {TRUE_POSE_COLUMNS}, got {self.columns}"
            )


POSITION = GivenValue(("E", "N", "U"), "position E, N, U", "position")
PITCH = GivenValue(("pitch",), "pitch", "pitch")
ROLL = GivenValue(("roll",), "roll", "roll")
# The height above the ground plane z_g, carried as the true U: z_g is known (the satellite's
# geo-reference), so U and U - z_g are the same information, and a reference given it returns the
# true U exactly (not z_g + (U - z_g), which can differ from U in the last bit).
ALTITUDE = GivenValue(("U",), "altitude above the ground", "altitude")


class WithheldError(KeyError):
    """A reference asked for a true value it is not given (the frame does not hold it)."""


class TrueValues(Mapping[str, float]):
    """The true pose values one reference is given for one frame, by pose-table column
    (:data:`TRUE_POSE_COLUMNS`; absolute ENU metres, radians), and no other: a withheld column is
    not stored, and asking for it raises :class:`WithheldError`."""

    __slots__ = ("_values",)

    def __init__(self, values: Mapping[str, float]) -> None:
        unknown = sorted(set(values) - set(TRUE_POSE_COLUMNS))
        if unknown:
            raise ValueError(f"TrueValues: {unknown} are not true pose columns {TRUE_POSE_COLUMNS}")
        self._values = {c: float(values[c]) for c in TRUE_POSE_COLUMNS if c in values}

    @classmethod
    def select(cls, pose: Mapping[str, float], columns: Collection[str]) -> TrueValues:
        """The values of ``columns`` taken from ``pose`` (any mapping holding them, e.g. a whole
        pair row); everything else in ``pose`` is left behind."""
        return cls({c: pose[c] for c in columns})

    def __getitem__(self, column: str) -> float:
        try:
            return self._values[column]
        except KeyError:
            given = ", ".join(self._values) or "none"
            raise WithheldError(
                f"true {column!r} is withheld from this reference (given: {given})"
            ) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return f"TrueValues({self._values!r})"

    def position(self) -> np.ndarray:
        """``(3,)`` float64 true position ``(E, N, U)``, absolute ENU metres (WithheldError unless
        all three are given)."""
        return np.array([self["E"], self["N"], self["U"]], np.float64)


@dataclass(frozen=True)
class Frame:
    """One pair as a reference sees it: the images, what is known without the labels, and the
    true values it is given (module docstring).

    ``uav``: uint8 ``(H, W, 3)`` RGB; ``sat``: uint8 ``(S, S, 3)`` RGB (the image served);
    ``grid``: the pair's satellite geo-reference; ``camera``: the UAV camera's intrinsics;
    ``truth``: the true pose values the reference declares it is given (``given_values``), only
    those.
    """

    uav: np.ndarray
    sat: np.ndarray
    grid: SatelliteGrid
    camera: Camera
    truth: TrueValues

    @property
    def height_above_ground_m(self) -> float:
        """The UAV's height above the ground plane ``z_g``: true ``U - z_g`` (given as "altitude";
        WithheldError when U is not given)."""
        return self.truth["U"] - self.grid.ground_u


@dataclass(frozen=True)
class Estimate:
    """A reference's answer for one frame.

    ``R_bn``: ``(3, 3)`` UAV attitude ``R_b^n``; ``position``: ``(3,)`` absolute ENU metres;
    ``failed``: True when the method gave up (the evaluation then substitutes the fallback pose and
    counts the frame as failed); ``score``: the method's own match score (higher = better), NaN
    when it has none.
    """

    R_bn: np.ndarray
    position: np.ndarray
    failed: bool = False
    score: float = float("nan")


class Reference(abc.ABC):
    """A non-learned pose estimator evaluated like a model.

    Declared by a subclass: ``name`` (registry key), ``title`` (the report row's name) and
    ``given_values`` (the true values it is given: the one declaration, :class:`GivenValue`).
    Derived from them when the class is defined, never set by hand: ``label`` (the report row:
    says "not learned" and what true values it is given), ``given`` (those values in words, for
    the report's "reads the true ...") and ``given_columns`` (the pose-table columns its frames
    carry, in :data:`TRUE_POSE_COLUMNS` order).
    """

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    given_values: ClassVar[tuple[GivenValue, ...]] = ()
    label: ClassVar[str] = ""
    given: ClassVar[tuple[str, ...]] = ()
    given_columns: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        by_hand = [k for k in ("label", "given", "given_columns") if k in cls.__dict__]
        if by_hand:
            raise TypeError(
                f"{cls.__name__} sets {by_hand}: declare title and given_values, the rest is "
                "derived from them"
            )
        values = tuple(cls.given_values)
        shorts = ", ".join(v.short for v in values)
        cls.given_values = values
        cls.given = tuple(v.words for v in values)
        cls.given_columns = tuple(
            c for c in TRUE_POSE_COLUMNS if any(c in v.columns for v in values)
        )
        cls.label = f"{cls.title} (not learned; " + (
            f"given true {shorts})" if values else "given no true pose values)"
        )

    @abc.abstractmethod
    def estimate(self, frame: Frame) -> Estimate:
        """The pose of one frame (``frame.truth`` holds exactly ``given_columns``)."""

    def options(self) -> dict[str, object]:
        """The options this instance was built with (recorded beside its results)."""
        return {}


def check_yaw_sweep(
    owner: str,
    *,
    step_deg: float,
    refine_step_deg: float,
    max_range_m: float,
    gradient_weight: float,
    uav_blur_px: float,
    min_count: tuple[str, int],
) -> dict[str, float | int]:
    """The options shared by the references that sweep the yaw, checked and normalised.

    ``min_count`` is ``(option name, value)`` of the reference's minimum of valid samples a yaw
    needs (an integer >= 3). Returns the options by name (floats, the count an int); a bad value
    raises ValueError naming ``owner``, the option and the range expected.
    """
    if not (0 < step_deg <= 90):
        raise ValueError(f"{owner}: step_deg must be in (0, 90], got {step_deg!r}")
    if not (0 <= refine_step_deg < step_deg):
        raise ValueError(
            f"{owner}: refine_step_deg must be in [0, step_deg), got {refine_step_deg!r}"
        )
    if not max_range_m > 0:
        raise ValueError(f"{owner}: max_range_m must be > 0, got {max_range_m!r}")
    if not gradient_weight >= 0:
        raise ValueError(f"{owner}: gradient_weight must be >= 0, got {gradient_weight!r}")
    if not uav_blur_px >= 0:
        raise ValueError(f"{owner}: uav_blur_px must be >= 0, got {uav_blur_px!r}")
    count_name, count = min_count
    if not (isinstance(count, int) and count >= 3):
        raise ValueError(f"{owner}: {count_name} must be an integer >= 3, got {count!r}")
    return {
        "step_deg": float(step_deg),
        "refine_step_deg": float(refine_step_deg),
        "max_range_m": float(max_range_m),
        "gradient_weight": float(gradient_weight),
        "uav_blur_px": float(uav_blur_px),
        count_name: int(count),
    }
