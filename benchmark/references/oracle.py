"""The geometry oracle: what the pixels allow when everything but the heading is known.

Given: the true UAV position (E, N, U) and the true pitch and roll. Estimated: the yaw alone; the
translation, pitch and roll it returns are the true ones, so its dE, dN, dU, dtheta and dgamma are
0 by construction and only dpsi (and dphi, which then equals the yaw error) measures it.

Method (issue 21): cast every UAV pixel whose ray meets the ground plane within ``max_range_m``
onto the plane (``benchmark.references.ground``: one cast at yaw 0, each yaw a rotation of the
offsets), sample the satellite image there (bilinear) and score each yaw by the normalised
cross-correlation of grey levels plus ``gradient_weight`` times that of the Sobel gradient
magnitude, over the pixels that land inside the satellite image. A sweep of ``step_deg`` over the
full circle, then ``refine_step_deg`` steps within one coarse step of the best; the best yaw wins.
The UAV grey image is blurred by ``uav_blur_px`` first: the satellite image has 10-20 m pixels,
the UAV's near field 1-3 m ones, and fine texture the satellite cannot show only adds noise to
the correlation.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from benchmark.references.base import (
    PITCH,
    POSITION,
    ROLL,
    Estimate,
    Frame,
    Reference,
    check_yaw_sweep,
)
from benchmark.references.ground import cast_uav_pixels, rotate_offsets
from benchmark.references.images import check_rgb, gradient_magnitude, grey
from benchmark.sim import euler_to_rotmat_np

__all__ = ["GeometryOracle", "masked_ncc"]


def masked_ncc(a: np.ndarray, b: np.ndarray, valid: np.ndarray, min_count: int) -> np.ndarray:
    """Normalised cross-correlation of ``a`` ``(P,)`` with each row of ``b`` ``(K, P)`` over the
    entries where ``valid`` ``(K, P)`` holds: ``(K,)`` in [-1, 1]; -inf for a row with fewer than
    ``min_count`` valid entries or no variance. float64 sums (grey levels up to 255 squared over
    thousands of pixels)."""
    w = valid.astype(np.float64)
    n = w.sum(axis=1)
    a64 = a.astype(np.float64)[None, :]
    b64 = np.where(valid, b, 0.0).astype(np.float64)
    safe_n = np.maximum(n, 1.0)
    ma = (w * a64).sum(axis=1) / safe_n
    mb = b64.sum(axis=1) / safe_n
    cov = (w * a64 * b64).sum(axis=1) / safe_n - ma * mb
    va = (w * a64 * a64).sum(axis=1) / safe_n - ma * ma
    vb = (b64 * b64).sum(axis=1) / safe_n - mb * mb
    denom = np.sqrt(np.maximum(va, 0.0) * np.maximum(vb, 0.0))
    ok = (n >= min_count) & (denom > 1e-9)
    return np.where(ok, cov / np.where(ok, denom, 1.0), -np.inf)


class GeometryOracle(Reference):
    """Yaw sweep given the true position, pitch and roll (module docstring).

    Options: ``step_deg`` (coarse sweep, 5), ``refine_step_deg`` (0.5; 0 = no refinement),
    ``max_range_m`` (horizontal reach of the cast pixels, 800 m), ``gradient_weight`` (1.0),
    ``uav_blur_px`` (Gaussian sigma on the UAV grey image, pixels, 1.0), ``min_pixels`` (valid
    pixels a yaw needs to be scored, 50).
    """

    name = "geometry_oracle"
    title = "Geometry oracle"
    given_values = (POSITION, PITCH, ROLL)

    def __init__(
        self,
        step_deg: float = 5.0,
        refine_step_deg: float = 0.5,
        max_range_m: float = 800.0,
        gradient_weight: float = 1.0,
        uav_blur_px: float = 1.0,
        min_pixels: int = 50,
    ) -> None:
        self._options = check_yaw_sweep(
            "geometry_oracle",
            step_deg=step_deg,
            refine_step_deg=refine_step_deg,
            max_range_m=max_range_m,
            gradient_weight=gradient_weight,
            uav_blur_px=uav_blur_px,
            min_count=("min_pixels", min_pixels),
        )
        for name, value in self._options.items():
            setattr(self, name, value)

    def options(self) -> dict[str, object]:
        return dict(self._options)

    def yaw_scores(self, frame: Frame, yaws: np.ndarray) -> np.ndarray:
        """The match score ``(K,)`` of each candidate yaw ``(K,)`` radians (-inf: too few pixels
        inside the satellite image)."""
        uav = check_rgb(frame.uav, "uav")
        sat = check_rgb(frame.sat, "sat")
        truth = frame.truth
        cast = cast_uav_pixels(
            frame.camera,
            truth["pitch"],
            truth["roll"],
            frame.height_above_ground_m,
            max_range_m=self.max_range_m,
        )
        yaws = np.asarray(yaws, np.float64).reshape(-1)
        if len(cast.rows) < self.min_pixels:
            return np.full(yaws.shape, -np.inf)
        g_uav = grey(uav, self.uav_blur_px)
        g_sat = grey(sat)
        de, dn = rotate_offsets(cast.offsets, yaws)
        x, y = frame.grid.enu_to_pixel(truth["E"] + de, truth["N"] + dn)
        size = frame.grid.size
        inside = (x >= 0) & (x <= size - 1) & (y >= 0) & (y <= size - 1)
        mx, my = x.astype(np.float32), y.astype(np.float32)

        def sample(img: np.ndarray) -> np.ndarray:
            return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

        score = masked_ncc(g_uav[cast.rows, cast.cols], sample(g_sat), inside, self.min_pixels)
        if self.gradient_weight > 0:
            m_uav = gradient_magnitude(g_uav)[cast.rows, cast.cols]
            m_sat = sample(gradient_magnitude(g_sat))
            score = score + self.gradient_weight * masked_ncc(m_uav, m_sat, inside, self.min_pixels)
        return score

    def estimate_yaw(self, frame: Frame) -> tuple[float, float]:
        """``(yaw, score)``: the best yaw in (-pi, pi] radians and its score (-inf: none scored)."""
        step = math.radians(self.step_deg)
        coarse = np.arange(-math.pi, math.pi - 1e-9, step)
        scores = self.yaw_scores(frame, coarse)
        k = int(np.argmax(scores))
        best, best_score = float(coarse[k]), float(scores[k])
        if self.refine_step_deg > 0 and math.isfinite(best_score):
            fine = math.radians(self.refine_step_deg)
            n = math.floor(step / fine)
            cand = best + fine * np.arange(-n, n + 1)
            fine_scores = self.yaw_scores(frame, cand)
            j = int(np.argmax(fine_scores))
            if fine_scores[j] >= best_score:
                best, best_score = float(cand[j]), float(fine_scores[j])
        return float(math.remainder(best, 2 * math.pi)), best_score

    def estimate(self, frame: Frame) -> Estimate:
        yaw, score = self.estimate_yaw(frame)
        R = euler_to_rotmat_np(yaw, frame.truth["pitch"], frame.truth["roll"])
        return Estimate(R, frame.truth.position(), failed=not math.isfinite(score), score=score)
