"""Camera degradations of the flight-test analogue (benchmark.data.camera_effects)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmark.data.camera_effects import CameraEffects, _motion_kernel, apply_camera_effects


def checkerboard(size: int = 96, cell: int = 4) -> np.ndarray:
    yy, xx = np.mgrid[0:size, 0:size]
    board = ((yy // cell + xx // cell) % 2).astype(np.uint8) * 160 + 48
    return np.repeat(board[..., None], 3, axis=2)


def high_frequency_energy(img: np.ndarray) -> float:
    g = img.astype(np.float64).mean(axis=2)
    return float(np.mean(np.diff(g, axis=0) ** 2) + np.mean(np.diff(g, axis=1) ** 2))


NO_EFFECT = CameraEffects(
    defocus_sigma_px=(0.0, 0.0), motion_length_px=(0.0, 0.0), exposure_gain=(1.0, 1.0),
    white_balance_std=0.0, gamma=(1.0, 1.0), read_noise_dn=(0.0, 0.0), shot_noise=(0.0, 0.0),
    vignetting=(0.0, 0.0), jpeg_quality=(100, 100),
)  # fmt: skip


class TestApplyCameraEffects:
    def test_shape_dtype_and_determinism(self):
        img = checkerboard()
        a = apply_camera_effects(img, np.random.default_rng(5))
        b = apply_camera_effects(img, np.random.default_rng(5))
        c = apply_camera_effects(img, np.random.default_rng(6))
        assert a.shape == img.shape and a.dtype == np.uint8
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)

    def test_identity_settings_nearly_lossless(self):
        img = checkerboard()
        out = apply_camera_effects(img, np.random.default_rng(0), NO_EFFECT)
        assert np.abs(out.astype(int) - img.astype(int)).max() <= 3  # JPEG at quality 100 only

    def test_blur_removes_high_frequencies(self):
        img = checkerboard()
        fx = dataclasses.replace(NO_EFFECT, defocus_sigma_px=(2.0, 2.0))
        out = apply_camera_effects(img, np.random.default_rng(0), fx)
        assert high_frequency_energy(out) < 0.5 * high_frequency_energy(img)

    def test_noise_level_matches_read_noise(self):
        flat = np.full((128, 128, 3), 128, np.uint8)
        fx = dataclasses.replace(NO_EFFECT, read_noise_dn=(6.0, 6.0), jpeg_quality=None)
        out = apply_camera_effects(flat, np.random.default_rng(1), fx).astype(np.float64)
        assert out.std() == pytest.approx(6.0, rel=0.05)
        assert out.mean() == pytest.approx(128.0, abs=0.2)

    def test_default_strength_visible_but_bounded(self):
        img = checkerboard()
        out = apply_camera_effects(img, np.random.default_rng(2))
        diff = np.abs(out.astype(float) - img.astype(float)).mean()
        assert 2.0 < diff < 60.0

    def test_rejects_bad_input(self):
        with pytest.raises(ValueError, match="uint8"):
            apply_camera_effects(np.zeros((8, 8, 3), np.float32), np.random.default_rng(0))


class TestMotionKernel:
    def test_normalised_and_oriented(self):
        k = _motion_kernel(7.0, 0.0)  # horizontal streak
        assert k.sum() == pytest.approx(1.0)
        assert k.shape == (7, 7)
        assert k[3].sum() > 0.95  # mass on the middle row
        kv = _motion_kernel(7.0, np.pi / 2)
        np.testing.assert_allclose(kv, k.T, atol=1e-6)
