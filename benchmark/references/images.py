"""Image channels the references compare: grey level and gradient magnitude, float32."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["check_rgb", "gradient_magnitude", "grey"]


def check_rgb(image: np.ndarray, name: str) -> np.ndarray:
    """``image`` as a uint8 ``(H, W, 3)`` array; ValueError naming ``name`` otherwise."""
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise ValueError(
            f"{name} must be a uint8 (H, W, 3) RGB image, got {arr.dtype} {tuple(arr.shape)}"
        )
    return arr


def grey(image: np.ndarray, blur_sigma_px: float = 0.0) -> np.ndarray:
    """uint8 RGB ``(H, W, 3)`` -> float32 grey ``(H, W)`` in [0, 255], optionally Gaussian-blurred
    (``blur_sigma_px`` pixels; 0 = none)."""
    g = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY).astype(np.float32)
    if blur_sigma_px > 0:
        g = cv2.GaussianBlur(g, (0, 0), float(blur_sigma_px))
    return g


def gradient_magnitude(g: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude ``(H, W)`` float32 of a grey image (edges replicated)."""
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    return cv2.magnitude(gx, gy)
