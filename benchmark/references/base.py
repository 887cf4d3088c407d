"""What a non-learned reference is: a per-frame estimator of the UAV pose from one pair of images
plus the true values it declares it is given.

A reference sees a :class:`Frame`: the UAV image, the satellite image it is served (the pair's own
or, in the swap probe, another place's), the pair's satellite geometry (:class:`SatelliteGrid`:
where the *true* satellite image lies, which is what the pair's labels are relative to) and the
UAV camera, plus the UAV's true pose. Every reference reads only the parts of the true pose listed
in its ``given`` (the report labels say so); the rest of the pose it must estimate.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from benchmark.references.ground import SatelliteGrid
from benchmark.sim import Camera

__all__ = ["Estimate", "Frame", "Reference", "check_yaw_sweep"]


@dataclass(frozen=True)
class Frame:
    """One pair as a reference sees it.

    ``uav``: uint8 ``(H, W, 3)`` RGB; ``sat``: uint8 ``(S, S, 3)`` RGB (the image served);
    ``grid``: the pair's satellite geometry; ``camera``: the UAV camera; ``position``: ``(3,)``
    true UAV position, absolute ENU metres; ``yaw``, ``pitch``, ``roll``: true UAV attitude,
    radians. References read only what their ``given`` names.
    """

    uav: np.ndarray
    sat: np.ndarray
    grid: SatelliteGrid
    camera: Camera
    position: np.ndarray
    yaw: float
    pitch: float
    roll: float

    @property
    def height_above_ground_m(self) -> float:
        """The UAV's height above the ground plane ``z_g`` (given as "altitude")."""
        return float(self.position[2]) - self.grid.ground_u


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

    Class attributes: ``name`` (registry key), ``label`` (the report row: says "not learned" and
    what true values it is given), ``given`` (the true values it reads, in words).
    """

    name: str = ""
    label: str = ""
    given: tuple[str, ...] = ()

    @abc.abstractmethod
    def estimate(self, frame: Frame) -> Estimate:
        """The pose of one frame."""

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
