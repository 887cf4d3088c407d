"""ISA-independent primitives (benchmark.sim.detmath): bit-for-bit against independent references.

The references are CPython's ``math`` module (the platform libm, called per Python float), plain
Python float arithmetic (IEEE double, never fused) and scipy/OpenCV/scipy Rotation for the
meaning of the filters and rotations.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math

import cv2
import numpy as np
import pytest
from scipy.ndimage import correlate
from scipy.spatial.transform import Rotation

from benchmark.sim import detmath, euler_to_rotmat_np


def _values(n: int, lo: float, hi: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.uniform(lo, hi, n)
    # Exact special points and a few large arguments (sin/cos range reduction, exp overflow edge).
    special = [0.0, -0.0, 1.0, -1.0, math.pi, -math.pi / 2, 1e-30, 80.0, -80.0, 1e5, -3e4]
    return np.concatenate([x, [v for v in special if lo <= v <= hi]])


def _reference(fn, *args: np.ndarray, dtype) -> np.ndarray:
    """CPython math on float64 values, rounded once to ``dtype``."""
    cols = [np.asarray(a, np.float64).tolist() for a in args]
    return np.array([fn(*t) for t in zip(*cols, strict=True)], np.float64).astype(dtype)


UNARY = [
    ("sin", detmath.sin, math.sin, (-1e5, 1e5)),
    ("cos", detmath.cos, math.cos, (-1e5, 1e5)),
    ("tan", detmath.tan, math.tan, (-10.0, 10.0)),
    ("exp", detmath.exp, math.exp, (-80.0, 80.0)),
    ("log", detmath.log, math.log, (1e-30, 1e6)),
]


def _load_libm_hypot():
    libm = ctypes.CDLL(ctypes.util.find_library("m"))
    libm.hypot.restype = ctypes.c_double
    libm.hypot.argtypes = [ctypes.c_double, ctypes.c_double]
    return libm.hypot


_LIBM_HYPOT = _load_libm_hypot()


def _libm_hypot(x: float, y: float) -> float:
    """glibc's hypot through ctypes: CPython's math.hypot is its own algorithm, not libm's."""
    return _LIBM_HYPOT(x, y)


BINARY = [
    ("arctan2", detmath.arctan2, math.atan2, (-50.0, 50.0), (-50.0, 50.0)),
    ("hypot", detmath.hypot, _libm_hypot, (-50.0, 50.0), (-50.0, 50.0)),
    ("power", detmath.power, math.pow, (1e-3, 20.0), (-5.0, 5.0)),
]


class TestTranscendental:
    @pytest.mark.parametrize("dtype", [np.float64, np.float32])
    @pytest.mark.parametrize("name, fn, ref, rng", UNARY, ids=[u[0] for u in UNARY])
    def test_unary_bitwise_equals_libm(self, name, fn, ref, rng, dtype):
        x = _values(3000, *rng, seed=1).astype(dtype)
        got = fn(x)
        assert got.dtype == dtype and got.shape == x.shape
        np.testing.assert_array_equal(got, _reference(ref, x, dtype=dtype), strict=True)

    @pytest.mark.parametrize("dtype", [np.float64, np.float32])
    @pytest.mark.parametrize("name, fn, ref, ra, rb", BINARY, ids=[b[0] for b in BINARY])
    def test_binary_bitwise_equals_libm(self, name, fn, ref, ra, rb, dtype):
        a = _values(3000, *ra, seed=2).astype(dtype)
        b = _values(3000, *rb, seed=3)[: len(a)].astype(dtype)
        b = np.resize(b, a.shape)
        got = fn(a, b)
        assert got.dtype == dtype and got.shape == a.shape
        np.testing.assert_array_equal(got, _reference(ref, a, b, dtype=dtype), strict=True)

    def test_scalars_broadcasting_and_dtypes(self):
        assert isinstance(detmath.sin(1.0), np.float64) and detmath.sin(1.0) == math.sin(1.0)
        assert detmath.cos(np.float32(0.5)).dtype == np.float32
        assert detmath.sin(np.arange(3)).dtype == np.float64  # integers: float64, as numpy
        x32 = np.linspace(0.1, 2.0, 12, dtype=np.float32).reshape(3, 4)
        assert detmath.power(x32, 1.5).dtype == np.float32  # a Python scalar takes the array's
        assert detmath.arctan2(x32, x32.astype(np.float64)).dtype == np.float64
        assert detmath.arctan2(x32[:, :1], x32[:1, :]).shape == (3, 4)

    def test_complex_input_is_refused_with_the_function_named(self):
        with pytest.raises(
            TypeError, match=r"detmath\.exp: expected real numbers, got dtype complex"
        ):
            detmath.exp(np.array([1j]))


def _python_matmul(a: list, b: list) -> list:
    """Row-by-column sums in k order with Python floats (IEEE double, one rounding per op)."""
    out = []
    for row in a:
        out_row = []
        for j in range(len(b[0])):
            acc = row[0] * b[0][j]
            for k in range(1, len(b)):
                acc = acc + row[k] * b[k][j]
            out_row.append(acc)
        out.append(out_row)
    return out


class TestMatmul:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_bitwise_equals_fixed_order_python_sums(self, batch):
        rng = np.random.default_rng(batch)
        a = rng.normal(size=(batch, 3, 3))
        b = rng.normal(size=(batch, 3, 4))
        got = detmath.matmul(a, b)
        want = np.array([_python_matmul(a[i].tolist(), b[i].tolist()) for i in range(batch)])
        np.testing.assert_array_equal(got, want, strict=True)
        np.testing.assert_allclose(got, a @ b, rtol=1e-13, atol=1e-15)

    def test_points_times_one_matrix_broadcasts(self):
        rng = np.random.default_rng(0)
        pts, R = rng.normal(size=(50, 3)), rng.normal(size=(3, 3))
        got = detmath.matmul(pts, R)
        assert got.shape == (50, 3)
        np.testing.assert_array_equal(got, np.array(_python_matmul(pts.tolist(), R.tolist())))

    def test_bad_shapes_are_named(self):
        with pytest.raises(ValueError, match=r"inner sizes differ: a \(2, 3\) has K = 3"):
            detmath.matmul(np.zeros((2, 3)), np.zeros((2, 3)))
        with pytest.raises(ValueError, match=r"expected \(\.\.\., M, K\)"):
            detmath.matmul(np.zeros(3), np.zeros((3, 3)))


class TestCorrelate2d:
    @pytest.mark.parametrize("channels", [None, 1, 3])
    def test_same_meaning_as_scipy_and_opencv_reflect(self, channels):
        rng = np.random.default_rng(5)
        shape = (17, 23) if channels is None else (17, 23, channels)
        img = rng.uniform(0, 255, shape).astype(np.float32)
        k = rng.uniform(0, 1, (5, 3)).astype(np.float32)
        got = detmath.correlate2d(img, k)
        assert got.dtype == np.float32 and got.shape == img.shape
        kk = k if channels is None else k[..., None]
        np.testing.assert_allclose(got, correlate(img, kk, mode="reflect"), rtol=2e-6, atol=1e-3)
        cv = cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REFLECT)
        np.testing.assert_allclose(got, cv.reshape(img.shape), rtol=2e-6, atol=1e-3)

    def test_bitwise_equals_fixed_order_python_sums(self):
        rng = np.random.default_rng(6)
        img = rng.uniform(0, 1, (6, 5))
        k = rng.uniform(0, 1, (3, 3))
        pad = np.pad(img, 1, mode="symmetric").tolist()
        want = [
            [
                sum_in_order(k[i][j] * pad[y + i][x + j] for i in range(3) for j in range(3))
                for x in range(5)
            ]
            for y in range(6)
        ]
        np.testing.assert_array_equal(detmath.correlate2d(img, k), np.array(want), strict=True)

    def test_even_kernel_is_refused(self):
        with pytest.raises(ValueError, match="odd-sized 2-D kernel"):
            detmath.correlate2d(np.zeros((4, 4)), np.ones((2, 3)))


def sum_in_order(terms) -> float:
    it = iter(terms)
    acc = next(it)
    for t in it:
        acc = acc + t
    return acc


class TestEulerToRotmatNp:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_matches_scipy_intrinsic_zxy(self, batch):
        rng = np.random.default_rng(batch)
        yaw, pitch, roll = rng.uniform(-math.pi, math.pi, (3, batch))
        got = euler_to_rotmat_np(yaw, pitch, roll)
        want = Rotation.from_euler("ZXY", np.stack([yaw, pitch, roll], 1)).as_matrix()
        assert got.shape == (batch, 3, 3)
        np.testing.assert_allclose(got, want, atol=1e-14)

    def test_batched_is_bitwise_the_per_frame_rotation(self):
        # The plan's labels use the batched call, the renderer one frame at a time.
        rng = np.random.default_rng(9)
        yaw, pitch, roll = rng.uniform(-math.pi, math.pi, (3, 20))
        batch = euler_to_rotmat_np(yaw, pitch, roll)
        for i in range(20):
            one = euler_to_rotmat_np(float(yaw[i]), float(pitch[i]), float(roll[i]))
            assert one.shape == (3, 3)
            np.testing.assert_array_equal(batch[i], one, strict=True)
