"""ISA-independent floating-point primitives: the only place the simulator computes a
transcendental function or a matrix product (issue 20, "same data on every CPU").

Why. numpy, OpenBLAS, OpenCV and torch pick their kernels at run time from the CPU's instruction
set, and the kernels do not agree in the last bits:

- numpy's float64 ``sin, cos, tan, arctan2, exp, log, power, ...`` call glibc's scalar libm on an
  AVX2 CPU but Intel SVML or numpy's own AVX-512 kernels on an AVX512_SKX CPU; numpy's float32
  ``sin, cos, tan, arctan2, exp, log`` are numpy's own SIMD code on AVX2 (about 1 value in 7 differs
  from libm in the last bit) and libm on a CPU without AVX2.
- ``a @ b`` of small float64 matrices is OpenBLAS ``dgemm``: the Haswell kernel accumulates with
  FMA, the Sandybridge/Prescott kernels without it (half of all rotation matrices differ by an ULP),
  SkylakeX has its own small-matrix kernels.
- torch's ``sin``/``cos`` are SLEEF kernels chosen per ATen CPU capability.

One ULP of a coordinate or an angle is enough to move a texel across a threshold or a pixel across
a uint8 step, so a dataset rendered on an AVX-512 machine had other bytes (and every training unit
key, which follows the dataset digest, changed with them).

What is used instead:

- **Transcendental functions** are evaluated by glibc's scalar libm in float64 through numba
  (``math.*`` without fastmath compiles to plain libm calls; SVML is switched off in
  ``benchmark/sim/__init__.py``). glibc picks one implementation per function at load time, the
  FMA variant on every CPU with FMA and AVX2 (every x86-64-v3 CPU, AVX-512 ones included), so the
  result is a function of the input alone. It is also bit-for-bit what CPython's ``math`` module
  returns, the reference the tests use. float32 input is evaluated in float64 and rounded once to
  float32 (the correctly rounded float32 result except in astronomically rare double-rounding
  cases, independent of any float32 kernel); the result keeps the input's dtype, as numpy's would.
- **Matrix products** are explicit multiply-adds in a fixed order, ``((a0 b0 + a1 b1) + a2 b2)``,
  one IEEE operation per numpy call, so no kernel can fuse or reorder them.
- **Image filters** (the camera model's defocus and motion blur, formerly OpenCV's
  ``GaussianBlur``/``filter2D``, whose float32 SIMD paths differ between SSE, AVX2 and AVX-512):
  :func:`correlate2d`, the same fixed-order multiply-adds over the kernel taps.
- Everything else the simulator does in floating point is exact per IEEE 754 on every CPU and
  needs no care: ``+ - * /``, ``sqrt``, ``abs``, ``floor``, ``rint``, ``min``/``max``, ``mod``,
  comparisons, casts, numpy's sums (a fixed pairwise order), ``x ** 2`` (numpy squares), ``math.*``
  on Python floats (the same libm) and numba kernels without fastmath.
  ``tests/sim/test_isa_independence.py`` checks statically that ``benchmark/sim`` and the
  dataset-writing modules of ``benchmark/data`` call nothing else, and renders a dataset with every
  lower instruction set forced to compare its manifest with the default one.

Cost: libm is scalar, 10-25 ns per value against 1-3 ns for numpy's SIMD kernels; building a full
3584 x 2560 m city evaluates about ten full-grid functions, under a second of its ~20 s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import vectorize

__all__ = [
    "arctan2", "correlate2d", "cos", "exp", "hypot", "log", "matmul", "power", "sin", "tan",
]  # fmt: skip

# Each kernel has a float32 and a float64 loop; the float32 one widens to float64, calls the
# float64 libm function and rounds once (the return type is float32). float32 comes first: numpy
# takes the first loop its input casts to safely, and float32 casts safely to float64 too.
_UNARY = ["float32(float32)", "float64(float64)"]
_BINARY = ["float32(float32, float32)", "float64(float64, float64)"]


@vectorize(_UNARY, cache=True)
def _sin(x):
    return math.sin(np.float64(x))


@vectorize(_UNARY, cache=True)
def _cos(x):
    return math.cos(np.float64(x))


@vectorize(_UNARY, cache=True)
def _tan(x):
    return math.tan(np.float64(x))


@vectorize(_UNARY, cache=True)
def _exp(x):
    return math.exp(np.float64(x))


@vectorize(_UNARY, cache=True)
def _log(x):
    return math.log(np.float64(x))


@vectorize(_BINARY, cache=True)
def _arctan2(y, x):
    return math.atan2(np.float64(y), np.float64(x))


@vectorize(_BINARY, cache=True)
def _hypot(x, y):
    return math.hypot(np.float64(x), np.float64(y))


@vectorize(_BINARY, cache=True)
def _power(x, p):
    return math.pow(np.float64(x), np.float64(p))


def _float_args(name: str, *args: Any) -> list[np.ndarray]:
    """The arguments as float32/float64 arrays of one common dtype (numpy's promotion, with
    Python scalars taking the array's dtype as in numpy 2); TypeError for complex or objects."""
    arrays = [np.asarray(a) for a in args]
    for a in arrays:
        if a.dtype.kind not in "biuf":
            raise TypeError(f"detmath.{name}: expected real numbers, got dtype {a.dtype}")
    dtype = np.result_type(*args)
    dtype = np.dtype(np.float32) if dtype == np.float32 else np.dtype(np.float64)
    return [a.astype(dtype, copy=False) for a in arrays]


def _unary(kernel: Any, name: str, x: Any) -> Any:
    (a,) = _float_args(name, x)
    return kernel(a)


def _binary(kernel: Any, name: str, x: Any, y: Any) -> Any:
    a, b = _float_args(name, x, y)
    return kernel(a, b)


def sin(x: Any) -> Any:
    """``sin(x)``, ``x`` radians (array or scalar, float32 or float64: the result keeps it)."""
    return _unary(_sin, "sin", x)


def cos(x: Any) -> Any:
    """``cos(x)``, ``x`` radians; shape and dtype as :func:`sin`."""
    return _unary(_cos, "cos", x)


def tan(x: Any) -> Any:
    """``tan(x)``, ``x`` radians; shape and dtype as :func:`sin`."""
    return _unary(_tan, "tan", x)


def exp(x: Any) -> Any:
    """``e ** x``; shape and dtype as :func:`sin`."""
    return _unary(_exp, "exp", x)


def log(x: Any) -> Any:
    """Natural logarithm (``x > 0``); shape and dtype as :func:`sin`."""
    return _unary(_log, "log", x)


def arctan2(y: Any, x: Any) -> Any:
    """The angle of ``(x, y)`` in ``[-pi, pi]`` radians (``numpy.arctan2`` argument order);
    broadcast shapes, float32 only if both inputs are float32 (or Python scalars)."""
    return _binary(_arctan2, "arctan2", y, x)


def hypot(x: Any, y: Any) -> Any:
    """``sqrt(x**2 + y**2)`` without overflow (libm ``hypot``); broadcast like :func:`arctan2`."""
    return _binary(_hypot, "hypot", x, y)


def power(x: Any, p: Any) -> Any:
    """``x ** p`` for real ``p`` (libm ``pow``; a negative ``x`` with a non-integer ``p`` gives
    NaN); broadcast like :func:`arctan2`. For ``p == 2`` plain ``x * x`` is exact already."""
    return _binary(_power, "power", x, p)


def matmul(a: Any, b: Any) -> np.ndarray:
    """``a @ b`` for ``a (..., M, K)`` and ``b (..., K, N)`` (batch dimensions broadcast), as
    ``sum_k a[..., i, k] b[..., k, j]`` added in the order k = 0, 1, ..., K-1, each product and
    each sum rounded once. Meant for small K (rotation matrices, K = 3): no BLAS kernel whose
    accumulation order or FMA use depends on the CPU. Result dtype: numpy's promotion of the two.
    """
    a = np.asarray(a)
    b = np.asarray(b)
    if a.ndim < 2 or b.ndim < 2:
        raise ValueError(
            f"detmath.matmul: expected (..., M, K) and (..., K, N) arrays, got shapes "
            f"{a.shape} and {b.shape}"
        )
    if a.shape[-1] != b.shape[-2]:
        raise ValueError(
            f"detmath.matmul: inner sizes differ: a {a.shape} has K = {a.shape[-1]}, "
            f"b {b.shape} has K = {b.shape[-2]}"
        )
    if a.shape[-1] == 0:
        raise ValueError(f"detmath.matmul: K must be >= 1, got shapes {a.shape} and {b.shape}")
    # a[..., :, k, None] is (..., M, 1) and b[..., None, k, :] is (..., 1, N): their product is
    # the k-th outer-product term; the sum runs left to right, one rounding per step.
    out = a[..., :, 0, None] * b[..., None, 0, :]
    for k in range(1, a.shape[-1]):
        out = out + a[..., :, k, None] * b[..., None, k, :]
    return out


def correlate2d(image: Any, kernel: Any) -> np.ndarray:
    """Correlate ``image (H, W)`` or ``(H, W, C)`` with an odd-sized ``kernel (kh, kw)`` (the
    kernel is not flipped, as OpenCV's ``filter2D``), mirrored at the border without repeating the
    edge pixel (``fedcba|abcdef``: OpenCV ``BORDER_REFLECT``, numpy ``pad(mode="symmetric")``).

    ``out[y, x] = sum_ij kernel[i, j] image[y + i - kh // 2, x + j - kw // 2]``, the terms added in
    row-major kernel order, one rounding per product and per sum, in the promoted dtype of image
    and kernel (float32 for both float32). Returns an array of the image's shape.
    """
    img = np.asarray(image)
    k = np.asarray(kernel)
    if img.ndim not in (2, 3) or img.dtype.kind not in "biuf":
        raise ValueError(f"detmath.correlate2d: expected a real (H, W[, C]) image, got {img.shape}")
    if k.ndim != 2 or k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0 or k.dtype.kind not in "biuf":
        raise ValueError(f"detmath.correlate2d: expected an odd-sized 2-D kernel, got {k.shape}")
    H, W = img.shape[:2]
    ch, cw = k.shape[0] // 2, k.shape[1] // 2
    pad = np.pad(img, ((ch, ch), (cw, cw)) + ((0, 0),) * (img.ndim - 2), mode="symmetric")
    out = None
    for i in range(k.shape[0]):
        for j in range(k.shape[1]):
            term = k[i, j] * pad[i : i + H, j : j + W]
            out = term if out is None else out + term
    return out
