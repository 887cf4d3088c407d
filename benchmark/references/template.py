"""Gravity-aided classical matching: a bird's-eye template of the UAV view searched over the whole
satellite image at every yaw (OpenCV's masked TM_CCOEFF_NORMED, computed for all yaws at once).

Given: the true pitch and roll (what an IMU gives) and the true height above the ground plane (an
altimeter). Estimated: the yaw and the horizontal position (dE, dN); dU, pitch and roll are the
given ones, so dtheta, dgamma and dU are 0 by construction.

Method. The UAV pixels whose rays meet the ground within ``max_range_m`` are cast onto the plane
(``benchmark.references.ground``). For each candidate yaw their offsets from the UAV are turned,
converted to satellite pixels (anisotropic: ``footprint / size`` metres per column and per row)
and averaged into the cells of a bird's-eye template on the satellite's own pixel grid, the UAV at
its centre cell (``np.bincount``: every UAV pixel counts once, so the near field, where many UAV
pixels share a cell, is averaged down to the satellite's resolution, and cells no ray reaches are
masked out). Every placement of the UAV on a satellite pixel is scored by the masked normalised
cross-correlation, exactly ``cv2.matchTemplate(image, template, TM_CCOEFF_NORMED, mask=mask)``
on the image padded with its mean grey (so a UAV near the image's edge can be placed; the padding
has no variance, so it adds nothing to the correlation but dilutes it): :func:`masked_ncc_map`
computes it by FFT for all yaws in one batch instead of one ``matchTemplate`` call per yaw (the
tests compare the two). Optionally a Sobel gradient magnitude template
is matched too and its score added (``gradient_weight``). The best (yaw, placement) over a
``step_deg`` sweep, refined by ``refine_step_deg`` steps within one coarse step, gives the yaw;
the placement, refined to a fraction of a pixel by a parabola through the peak and its
neighbours, gives the position.
"""

from __future__ import annotations

import math

import numpy as np

from benchmark.references.base import (
    ALTITUDE,
    PITCH,
    ROLL,
    Estimate,
    Frame,
    Reference,
    check_yaw_sweep,
)
from benchmark.references.ground import cast_uav_pixels, rotate_offsets
from benchmark.references.images import check_rgb, gradient_magnitude, grey
from benchmark.sim import euler_to_rotmat_np

__all__ = ["GravityTemplate"]


def _parabola_offset(left: float, centre: float, right: float) -> float:
    """Sub-sample peak offset in [-0.5, 0.5] of a parabola through three samples."""
    denom = left - 2.0 * centre + right
    if not (math.isfinite(denom) and denom < 0):
        return 0.0
    return float(np.clip(0.5 * (left - right) / denom, -0.5, 0.5))


def _standardise(image: np.ndarray) -> np.ndarray:
    """Zero mean, unit standard deviation (float32 FFT sums then stay well conditioned; masked
    NCC is invariant to an affine change of the image)."""
    x = image.astype(np.float64)
    return ((x - x.mean()) / max(float(x.std()), 1e-6)).astype(np.float32)


def masked_ncc_map(image: np.ndarray, templates: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """Masked normalised cross-correlation (``cv2.TM_CCOEFF_NORMED`` with a template mask) of
    ``K`` centred templates at every pixel of ``image``, the image padded with its mean.

    Args:
        image: ``(H, W)`` float, standardised (:func:`_standardise`: zero mean, so the zero
            padding is the mean grey and adds no variance: a template hanging over the border is
            diluted, not rewarded).
        templates, masks: ``(K, 2 ry + 1, 2 rx + 1)``; template cell ``(i, j)`` is compared with
            image pixel ``(y + i - ry, x + j - rx)`` for the placement ``(y, x)``; ``masks`` 0/1.
    Returns:
        ``(K, H, W)`` float64 correlations in [-1, 1]; -inf for a template with fewer than 3
        valid cells or no variance, or a placement with no image variance under it.

    Per placement, with the ``n`` valid cells: ``cov = sum T' I`` (``T'`` the template minus its
    masked mean, zero off the mask), ``var_I = sum M I^2 - (sum M I)^2 / n``; the three sums over
    the image are cross-correlations, computed by FFT on a grid large enough that the placements
    inside the image never wrap. This is cv2's masked TM_CCOEFF_NORMED (checked in the tests)
    for all K templates in one batch.
    """
    from scipy import fft

    k, th, tw = templates.shape
    ry, rx = th // 2, tw // 2
    h, w = image.shape
    # Circular correlation on an (h + ry) x (w + rx) grid: the image sits at [ry, ry + h) x
    # [rx, rx + w) and the zeros before it double as the zeros after it, so a template hanging
    # over either border of a placement inside the image only ever meets padding, never wraps
    # onto image pixels (the largest index y + i = h + 2 ry - 1 wraps to ry - 1 < ry).
    shape = (fft.next_fast_len(h + ry, real=True), fft.next_fast_len(w + rx, real=True))
    padded = np.zeros(shape, np.float32)
    padded[ry : ry + h, rx : rx + w] = image
    m = masks.astype(np.float64)
    n = m.reshape(k, -1).sum(axis=1)
    t = templates.astype(np.float64) * m
    t_mean = t.reshape(k, -1).sum(axis=1) / np.maximum(n, 1.0)
    t_dev = (t - t_mean[:, None, None]) * m
    var_t = (t_dev * t_dev).reshape(k, -1).sum(axis=1)

    def spec(a: np.ndarray) -> np.ndarray:
        return fft.rfft2(a.astype(np.float32), s=shape, axes=(-2, -1), workers=1)

    f_i, f_i2 = spec(padded), spec(padded * padded)
    f_m, f_t = spec(m), spec(t_dev)

    def corr(f_tmpl: np.ndarray, f_img: np.ndarray) -> np.ndarray:
        # sum_ij A[i, j] B[y + i, x + j] = IFFT(conj(FFT(A)) FFT(B)) at (y, x)
        full = fft.irfft2(np.conj(f_tmpl) * f_img[None], s=shape, axes=(-2, -1), workers=1)
        return full[:, :h, :w].astype(np.float64)

    s_i, s_i2, cov = corr(f_m, f_i), corr(f_m, f_i2), corr(f_t, f_i)
    safe_n = np.maximum(n, 1.0)[:, None, None]
    var_i = np.maximum(s_i2 - s_i * s_i / safe_n, 0.0)
    denom = np.sqrt(var_i * var_t[:, None, None])
    ok = (n[:, None, None] >= 3) & (var_t[:, None, None] > 1e-9) & (var_i > 1e-6 * safe_n)
    return np.where(ok, np.clip(cov / np.where(ok, denom, 1.0), -1.0, 1.0), -np.inf)


class GravityTemplate(Reference):
    """Bird's-eye template matching given the true pitch, roll and altitude (module docstring).

    Options: ``step_deg`` (5), ``refine_step_deg`` (1; 0 = none), ``max_range_m`` (400),
    ``gradient_weight`` (0.0: on 60 standard/val pairs the gradient channel lowered the share
    within 10 deg from 52 % to 42 %), ``uav_blur_px`` (0.0), ``min_cells`` (valid template cells
    a yaw needs, 12).
    """

    name = "gravity_template"
    title = "Gravity-aided template matching"
    given_values = (PITCH, ROLL, ALTITUDE)

    def __init__(
        self,
        step_deg: float = 5.0,
        refine_step_deg: float = 1.0,
        max_range_m: float = 400.0,
        gradient_weight: float = 0.0,
        uav_blur_px: float = 0.0,
        min_cells: int = 12,
    ) -> None:
        self._options = check_yaw_sweep(
            "gravity_template",
            step_deg=step_deg,
            refine_step_deg=refine_step_deg,
            max_range_m=max_range_m,
            gradient_weight=gradient_weight,
            uav_blur_px=uav_blur_px,
            min_count=("min_cells", min_cells),
        )
        for name, value in self._options.items():
            setattr(self, name, value)

    def options(self) -> dict[str, object]:
        return dict(self._options)

    def _prepare(self, frame: Frame) -> dict | None:
        uav = check_rgb(frame.uav, "uav")
        sat = check_rgb(frame.sat, "sat")
        cast = cast_uav_pixels(
            frame.camera,
            frame.truth["pitch"],
            frame.truth["roll"],
            frame.height_above_ground_m,
            max_range_m=self.max_range_m,
        )
        if len(cast.rows) < self.min_cells:
            return None
        g_uav = grey(uav, self.uav_blur_px)
        g_sat = grey(sat)
        channels = [(g_uav[cast.rows, cast.cols], _standardise(g_sat), 1.0)]
        if self.gradient_weight > 0:
            m_uav = gradient_magnitude(g_uav)[cast.rows, cast.cols]
            m_sat = _standardise(gradient_magnitude(g_sat))
            channels.append((m_uav, m_sat, self.gradient_weight))
        return {"cast": cast, "channels": channels}

    def score_maps(self, frame: Frame, prep: dict, yaws: np.ndarray) -> np.ndarray:
        """``(K, S, S)`` summed correlations of the yaw-``yaws[k]`` template with the UAV placed
        at each satellite pixel (row, column); -inf where a placement does not qualify."""
        cast = prep["cast"]
        sx, sy = frame.grid.metres_per_px
        rx = math.ceil(self.max_range_m / sx) + 1
        ry = math.ceil(self.max_range_m / sy) + 1
        th, tw = 2 * ry + 1, 2 * rx + 1
        de, dn = rotate_offsets(cast.offsets, np.asarray(yaws, np.float64))
        # Template cells on the satellite's pixel grid, the UAV at the centre cell (ry, rx): cell
        # (i, j) averages the UAV pixels whose ground point is (j - rx, i - ry) pixels from it.
        col = np.rint(de / sx).astype(np.int64) + rx
        row = np.rint(-dn / sy).astype(np.int64) + ry
        k = len(yaws)
        flat = (np.arange(k)[:, None] * (th * tw) + row * tw + col).ravel()
        count = np.bincount(flat, minlength=k * th * tw).reshape(k, th, tw)
        masks = (count > 0).astype(np.float32)
        total = None
        for values, sat, weight in prep["channels"]:
            sums = np.bincount(flat, weights=np.tile(values, k), minlength=k * th * tw)
            templ = (sums.reshape(k, th, tw) / np.maximum(count, 1)).astype(np.float32)
            ncc = masked_ncc_map(sat, templ, masks)
            ncc[masks.reshape(k, -1).sum(axis=1) < self.min_cells] = -np.inf
            total = ncc * weight if total is None else total + ncc * weight
        assert total is not None
        return total

    @staticmethod
    def _failed(frame: Frame) -> Estimate:
        """No match: yaw 0 with the given pitch and roll, at the given altitude over the capture
        point (the evaluation gives the frame the fallback pose; it has no horizontal position of
        its own, and the true E, N are not given)."""
        R = euler_to_rotmat_np(0.0, frame.truth["pitch"], frame.truth["roll"])
        east, north = frame.grid.centre_en
        return Estimate(R, np.array([east, north, frame.truth["U"]]), failed=True)

    def estimate(self, frame: Frame) -> Estimate:
        prep = self._prepare(frame)
        if prep is None:
            return self._failed(frame)
        step = math.radians(self.step_deg)
        yaws = np.arange(-math.pi, math.pi - 1e-9, step)
        maps = self.score_maps(frame, prep, yaws)
        kb, yb, xb = np.unravel_index(int(np.argmax(maps)), maps.shape)
        if self.refine_step_deg > 0 and math.isfinite(float(maps[kb, yb, xb])):
            fine = math.radians(self.refine_step_deg)
            n = math.floor(step / fine)
            cand = yaws[kb] + fine * np.arange(-n, n + 1)
            fine_maps = self.score_maps(frame, prep, cand)
            kf, yf, xf = np.unravel_index(int(np.argmax(fine_maps)), fine_maps.shape)
            if fine_maps[kf, yf, xf] >= maps[kb, yb, xb]:
                yaws, maps, kb, yb, xb = cand, fine_maps, kf, yf, xf
        best = maps[kb]
        score = float(best[yb, xb])
        if not math.isfinite(score):
            return self._failed(frame)
        fx = fy = 0.0
        if 0 < xb < best.shape[1] - 1:
            fx = _parabola_offset(best[yb, xb - 1], score, best[yb, xb + 1])
        if 0 < yb < best.shape[0] - 1:
            fy = _parabola_offset(best[yb - 1, xb], score, best[yb + 1, xb])
        enu = frame.grid.pixel_to_enu(np.array(xb + fx), np.array(yb + fy))
        # The altitude is given: U = the ground plane + the height above it = the true U.
        position = np.array([enu[0], enu[1], frame.truth["U"]])
        yaw = math.remainder(float(yaws[kb]), 2 * math.pi)
        R = euler_to_rotmat_np(yaw, frame.truth["pitch"], frame.truth["roll"])
        return Estimate(R, position, failed=False, score=score)
