"""Real-camera degradations for the flight-test analogue (paper Sec. 3.5).

The paper's flight-test images come from a DJI camera: slightly defocused, motion-blurred by the
flight, noisy, with their own exposure and white balance and JPEG compression. The simulated UAV
image of a ``flight/*`` sample goes through :func:`apply_camera_effects` with the sample's own
generator, so the degradation is deterministic per sample and independent of the worker.

All strengths are given for a 224 px image and scale with the image width, so a 96 px image of
the same view is degraded the same way relative to its content.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from benchmark.sim import detmath


@dataclass(frozen=True)
class CameraEffects:
    """Ranges (uniformly sampled per image) of each degradation, at 224 px."""

    defocus_sigma_px: tuple[float, float] = (0.3, 1.0)
    motion_length_px: tuple[float, float] = (0.0, 5.0)
    exposure_gain: tuple[float, float] = (0.8, 1.2)
    white_balance_std: float = 0.05  # per-channel gain std
    gamma: tuple[float, float] = (0.85, 1.15)
    read_noise_dn: tuple[float, float] = (1.0, 4.0)  # std in 0-255 units
    shot_noise: tuple[float, float] = (0.02, 0.12)  # variance per DN of signal
    vignetting: tuple[float, float] = (0.0, 0.25)  # relative darkening at the corners
    jpeg_quality: tuple[int, int] | None = (55, 90)  # None: no JPEG coding


def _motion_kernel(length: float, angle: float) -> np.ndarray:
    """A normalised line kernel of ``length`` px at ``angle`` rad (anti-aliased end points)."""
    size = math.ceil(length) | 1
    k = np.zeros((size, size), np.float32)
    c = (size - 1) / 2.0
    n = max(2, int(4 * size))
    for s in np.linspace(-length / 2.0, length / 2.0, n):
        x, y = c + s * math.cos(angle), c + s * math.sin(angle)
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        for dx, dy, w in (
            (0, 0, (1 - fx) * (1 - fy)),
            (1, 0, fx * (1 - fy)),
            (0, 1, (1 - fx) * fy),
            (1, 1, fx * fy),
        ):
            if 0 <= x0 + dx < size and 0 <= y0 + dy < size:
                k[y0 + dy, x0 + dx] += w
    return k / k.sum()


def _gaussian_kernel(sigma: float) -> np.ndarray:
    """Normalised float32 Gaussian taps of standard deviation ``sigma`` px, cut at ``4 sigma``
    (at least one tap each side), as OpenCV sizes its float kernels."""
    radius = max(1, round(4.0 * sigma))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = detmath.exp(-(x * x) / (2.0 * sigma * sigma))
    return (w / w.sum()).astype(np.float32)


def apply_camera_effects(
    image: np.ndarray, rng: np.random.Generator, effects: CameraEffects | None = None
) -> np.ndarray:
    """Degrade a rendered uint8 ``(H, W, 3)`` image like a real UAV camera; returns uint8 (H, W, 3).

    Order follows the physics: optics (defocus, motion) act on scene radiance, then exposure and
    vignetting, sensor noise (shot + read) in linear-ish units, gamma, and finally JPEG coding.
    """
    fx = effects or CameraEffects()
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(
            f"apply_camera_effects: expected uint8 (H, W, 3), got {image.dtype} {image.shape}"
        )
    h, w = image.shape[:2]
    scale = w / 224.0
    img = image.astype(np.float32)

    # The filters are detmath's fixed-order float32 multiply-adds, not OpenCV's GaussianBlur /
    # filter2D, whose SIMD paths (SSE, AVX2 with FMA, AVX-512) round differently (issue 20).
    sigma = rng.uniform(*fx.defocus_sigma_px) * scale
    if sigma > 0.05:
        g = _gaussian_kernel(sigma)
        img = detmath.correlate2d(detmath.correlate2d(img, g[None, :]), g[:, None])
    length = rng.uniform(*fx.motion_length_px) * scale
    angle = rng.uniform(0.0, math.pi)
    if length >= 1.0:
        img = detmath.correlate2d(img, _motion_kernel(length, angle))

    gain = rng.uniform(*fx.exposure_gain) * (1.0 + fx.white_balance_std * rng.standard_normal(3))
    img = img * gain.astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    img = img * (1.0 - rng.uniform(*fx.vignetting) * r2)[..., None]

    var = rng.uniform(*fx.shot_noise) * np.clip(img, 0, None) + rng.uniform(*fx.read_noise_dn) ** 2
    img = img + np.sqrt(var) * rng.standard_normal(img.shape).astype(np.float32)

    img = np.clip(img, 0.0, 255.0) / 255.0
    img = 255.0 * detmath.power(img, np.float32(rng.uniform(*fx.gamma)))
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)

    if fx.jpeg_quality is None:
        return out
    quality = int(rng.integers(fx.jpeg_quality[0], fx.jpeg_quality[1] + 1))
    ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover - cv2 always encodes a valid uint8 image
        raise RuntimeError("apply_camera_effects: JPEG encoding failed")
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
