"""Conversions between attitude representations (paper Sec. 2.2.1, Eq. 1-7).

Conventions (DEVELOPERS.md): navigation frame ENU; body x right, y forward, z up;
``R_b^n = Rz(yaw) Rx(pitch) Ry(roll)`` maps body vectors into the navigation frame. Quaternions are
``(w, x, y, z)``. Angles are radians. Every function is batched over leading dimensions ``...``,
works in float32 and float64 and is differentiable wherever the map itself is smooth.

Why not roma's maps (BSD-3, not installed; ``benchmark/geometry/so3.py`` says why not for the
projection): its quaternions are ``(x, y, z, w)`` and its Euler angles take a convention string,
so every call would be wrapped in a reorder; the paper's own maps (Eq. 3 ``rotmat_to_quat_paper``
with its sign rule, Eq. 1's ``Rz Rx Ry`` order) are not in it; and the labels of every dataset and
the targets of every head are computed here, so other rounding would change the numbers.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry._checks import check_finite, check_last_dims, check_tensor

__all__ = [
    "SAT_Q_N",
    "SAT_R_N",
    "euler_to_rotmat",
    "quat_conjugate",
    "quat_multiply",
    "quat_to_rotmat",
    "relative_rotation",
    "rotmat_to_euler",
    "rotmat_to_quat",
    "rotmat_to_quat_paper",
    "rotmat_to_rotvec",
    "rotvec_to_rotmat",
]

# Below this cos(pitch) the yaw/roll split is not observable (gimbal lock); see rotmat_to_euler.
_GIMBAL_EPS = 1e-6


def euler_to_rotmat(yaw: Tensor, pitch: Tensor, roll: Tensor) -> Tensor:
    """Paper Eq. 1: ``R = Rz(yaw) Rx(pitch) Ry(roll)``.

    Args:
        yaw, pitch, roll: ``(...)`` radians, broadcastable against each other.
    Returns:
        ``(..., 3, 3)`` rotation matrix mapping body vectors to the navigation frame.
        Its columns are the body axes (right, forward, up) expressed in ENU.
    """
    for name, angle in {"yaw": yaw, "pitch": pitch, "roll": roll}.items():
        check_finite(check_tensor(angle, name), name)
    yaw, pitch, roll = torch.broadcast_tensors(yaw, pitch, roll)
    cy, sy = torch.cos(yaw), torch.sin(yaw)
    cp, sp = torch.cos(pitch), torch.sin(pitch)
    cr, sr = torch.cos(roll), torch.sin(roll)
    rows = [
        [cy * cr - sy * sp * sr, -sy * cp, cy * sr + sy * sp * cr],
        [sy * cr + cy * sp * sr, cy * cp, sy * sr - cy * sp * cr],
        [-cp * sr, sp, cp * cr],
    ]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def rotmat_to_euler(R: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Inverse of :func:`euler_to_rotmat`.

    Args:
        R: ``(..., 3, 3)`` rotation matrices.
    Returns:
        ``(yaw, pitch, roll)``, each ``(...)``: yaw and roll in (-pi, pi], pitch in [-pi/2, pi/2].

    Gimbal lock: when ``cos(pitch) < 1e-6`` only ``yaw + roll`` (pitch = +90 deg) or ``yaw - roll``
    (pitch = -90 deg) is defined. We then return ``roll = 0`` and put the whole in-plane angle into
    yaw, ``yaw = atan2(R21, R11)``, so that ``euler_to_rotmat`` of the result reproduces ``R``.
    Gradients are finite away from gimbal lock (the map is not differentiable there).
    """
    R = check_last_dims(R, (3, 3), "R")
    r12, r22, r32 = R[..., 0, 1], R[..., 1, 1], R[..., 2, 1]
    r31, r33 = R[..., 2, 0], R[..., 2, 2]
    r11, r21 = R[..., 0, 0], R[..., 1, 0]
    cos_pitch = torch.sqrt(r31 * r31 + r33 * r33)
    pitch = torch.atan2(r32, cos_pitch)
    locked = cos_pitch < _GIMBAL_EPS
    # double-where: feed atan2 harmless values in the branch that is not taken, so that its
    # gradient (0/0 at the singularity) cannot poison the selected branch with NaN.
    one, zero = torch.ones_like(r11), torch.zeros_like(r11)
    yaw_free = torch.atan2(torch.where(locked, zero, -r12), torch.where(locked, one, r22))
    roll_free = torch.atan2(torch.where(locked, zero, -r31), torch.where(locked, one, r33))
    yaw_locked = torch.atan2(torch.where(locked, r21, zero), torch.where(locked, r11, one))
    yaw = torch.where(locked, yaw_locked, yaw_free)
    roll = torch.where(locked, zero, roll_free)
    return yaw, pitch, roll


def _quat_candidates(R: Tensor) -> tuple[Tensor, Tensor]:
    """The four Shepperd candidates ``(..., 4, 4)`` (row k pivots on component k) and the pivots
    ``4 q_k^2`` as ``(..., 4)``.

    Candidate k divides by ``4 q_k``; it is accurate when ``|q_k|`` is the largest component
    (then ``|q_k| >= 1/2``). Square roots are clamped so unused candidates stay finite.
    """
    r = R
    t = r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]
    pivots = torch.stack(
        [
            1 + t,
            1 + r[..., 0, 0] - r[..., 1, 1] - r[..., 2, 2],
            1 - r[..., 0, 0] + r[..., 1, 1] - r[..., 2, 2],
            1 - r[..., 0, 0] - r[..., 1, 1] + r[..., 2, 2],
        ],
        dim=-1,
    )
    half = 0.5 * torch.sqrt(pivots.clamp_min(1e-12))  # (..., 4): |q_k| for pivot k
    w_x = r[..., 2, 1] - r[..., 1, 2]
    w_y = r[..., 0, 2] - r[..., 2, 0]
    w_z = r[..., 1, 0] - r[..., 0, 1]
    x_y = r[..., 0, 1] + r[..., 1, 0]
    x_z = r[..., 0, 2] + r[..., 2, 0]
    y_z = r[..., 1, 2] + r[..., 2, 1]
    q_w, q_x, q_y, q_z = half.unbind(-1)
    c_w = torch.stack([q_w, w_x / (4 * q_w), w_y / (4 * q_w), w_z / (4 * q_w)], dim=-1)
    c_x = torch.stack([w_x / (4 * q_x), q_x, x_y / (4 * q_x), x_z / (4 * q_x)], dim=-1)
    c_y = torch.stack([w_y / (4 * q_y), x_y / (4 * q_y), q_y, y_z / (4 * q_y)], dim=-1)
    c_z = torch.stack([w_z / (4 * q_z), x_z / (4 * q_z), y_z / (4 * q_z), q_z], dim=-1)
    return torch.stack([c_w, c_x, c_y, c_z], dim=-2), pivots


def rotmat_to_quat(R: Tensor) -> Tensor:
    """Rotation matrix to unit quaternion, robust everywhere (Shepperd's method).

    Args:
        R: ``(..., 3, 3)``.
    Returns:
        ``(..., 4)`` quaternion ``(w, x, y, z)`` with the canonical sign ``w >= 0``. At exactly
        ``w = 0`` (180 deg rotations) the sign is whatever the pivot component gives; both signs
        represent the same rotation.
    """
    R = check_last_dims(R, (3, 3), "R")
    candidates, pivots = _quat_candidates(R)
    best = pivots.argmax(dim=-1)  # (...)
    index = best[..., None, None].expand(*best.shape, 1, 4)
    q = torch.take_along_dim(candidates, index, dim=-2).squeeze(-2)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    sign = torch.where(q[..., :1] < 0, -1.0, 1.0).to(q.dtype)
    return q * sign


def rotmat_to_quat_paper(R: Tensor) -> Tensor:
    """Paper Eq. 3 with its four-case split and case order, for the continuity study (Fig. 2).

    The case is chosen by the first condition that holds, in the paper's order:
    ``R11 >= R22 + R33`` (pivot x), ``R22 >= R11 + R33`` (pivot y), ``R33 >= R11 + R22`` (pivot z),
    otherwise pivot w. Each condition guarantees its pivot component is >= 1/2 in magnitude, so each
    case is numerically safe; but the sign of the result is that of the pivot, never canonicalised,
    so the output jumps to ``-q`` (or near it) when the case changes. That jump is what the paper's
    Fig. 2 shows.

    Fixes of evident typos in the printed Eq. 3 (each checked against ``quat_to_rotmat``):
      1. case x: ``q0 = (R32 - R23) / 4q1`` (printed ``R32 - R31``);
      2. case y: ``q2 = sqrt(1 - R11 + R22 - R33) / 2`` (printed ``1 - R11 - R22 - R33``);
      3. case z: ``q3 = sqrt(1 - R11 - R22 + R33) / 2`` (printed ``1 - R11 - R22 - R33``);
      4. case w: ``q1 = (R32 - R23) / 4q0`` (printed ``R32 - R31``).

    Args:
        R: ``(..., 3, 3)``.
    Returns:
        ``(..., 4)`` quaternion ``(w, x, y, z)``; sign as in the paper (not canonical).
    """
    R = check_last_dims(R, (3, 3), "R")
    candidates, _ = _quat_candidates(R)
    r11, r22, r33 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    case_x = r11 >= r22 + r33
    case_y = ~case_x & (r22 >= r11 + r33)
    case_z = ~case_x & ~case_y & (r33 >= r11 + r22)
    case = torch.full_like(r11, 0, dtype=torch.long)  # w
    case = torch.where(case_x, 1, torch.where(case_y, 2, torch.where(case_z, 3, case)))
    index = case[..., None, None].expand(*case.shape, 1, 4)
    return torch.take_along_dim(candidates, index, dim=-2).squeeze(-2)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """Unit quaternion ``(w, x, y, z)`` to rotation matrix.

    Args:
        q: ``(..., 4)``; normalised here, so any non-zero scale is accepted (the map is then the
        rotation of ``q / |q|``). A zero quaternion raises ValueError.
    Returns:
        ``(..., 3, 3)``.
    """
    q = check_last_dims(q, (4,), "q")
    norm = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    if bool((norm < 1e-12).any()):
        raise ValueError(f"q contains zero quaternions (norm < 1e-12), shape {tuple(q.shape)}")
    w, x, y, z = (q / norm).unbind(-1)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def quat_multiply(p: Tensor, q: Tensor) -> Tensor:
    """Hamilton product ``p ⊗ q`` (paper Eq. 4), so that ``R(p ⊗ q) = R(p) R(q)``.

    Args:
        p, q: ``(..., 4)`` ``(w, x, y, z)``, broadcastable.
    Returns:
        ``(..., 4)``.
    """
    p = check_last_dims(p, (4,), "p")
    q = check_last_dims(q, (4,), "q")
    pw, px, py, pz = p.unbind(-1)
    qw, qx, qy, qz = q.unbind(-1)
    return torch.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        dim=-1,
    )


def quat_conjugate(q: Tensor) -> Tensor:
    """``(w, x, y, z) -> (w, -x, -y, -z)``, the inverse of a unit quaternion; ``(..., 4)``."""
    q = check_last_dims(q, (4,), "q")
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def rotvec_to_rotmat(v: Tensor) -> Tensor:
    """Rotation vector (axis * angle, paper Eq. 7) to rotation matrix (Rodrigues).

    Args:
        v: ``(..., 3)`` radians.
    Returns:
        ``(..., 3, 3)``.

    Near ``|v| = 0`` the coefficients ``sin(t)/t`` and ``(1 - cos t)/t^2`` use their Taylor series
    (below ``t^2 < 1e-6``, error < 1e-13), so the map and its gradient are exact at zero.
    """
    v = check_last_dims(v, (3,), "v")
    t2 = (v * v).sum(-1)
    small = t2 < 1e-6
    t2_safe = torch.where(small, torch.ones_like(t2), t2)
    t = torch.sqrt(t2_safe)
    a = torch.where(small, 1 - t2 / 6 + t2 * t2 / 120, torch.sin(t) / t)
    b = torch.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - torch.cos(t)) / t2_safe)
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack(
        [torch.stack(r, -1) for r in ([zero, -z, y], [z, zero, -x], [-y, x, zero])], dim=-2
    )
    eye = torch.eye(3, dtype=v.dtype, device=v.device).expand_as(K)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def rotmat_to_rotvec(R: Tensor) -> Tensor:
    """Rotation matrix to rotation vector with angle in [0, pi].

    Goes through the canonical quaternion (``w >= 0``): ``angle = 2 atan2(|xyz|, w)`` is accurate at
    both ends, unlike ``arccos((tr R - 1) / 2)``. Near zero angle the factor ``angle / |xyz|`` uses
    its series ``2/w (1 - n^2/(3 w^2))``. At exactly pi, ``v`` and ``-v`` are the same rotation; the
    sign returned is the one of the quaternion's pivot.

    Args:
        R: ``(..., 3, 3)``.
    Returns:
        ``(..., 3)``.
    """
    q = rotmat_to_quat(R)
    w, xyz = q[..., :1], q[..., 1:]
    n2 = (xyz * xyz).sum(-1, keepdim=True)
    small = n2 < 1e-8
    n = torch.sqrt(torch.where(small, torch.ones_like(n2), n2))
    factor = torch.where(small, 2.0 / w * (1 - n2 / (3 * w * w)), 2.0 * torch.atan2(n, w) / n)
    return factor * xyz


def relative_rotation(R_uav_n: Tensor, R_sat_n: Tensor) -> Tensor:
    """Paper Eq. 2: ``R_uav^sat = R_uav^n (R_sat^n)^T``; the attitude label of a pair.

    Args:
        R_uav_n: ``(..., 3, 3)`` UAV attitude; R_sat_n: ``(..., 3, 3)`` satellite camera attitude
        (usually :data:`SAT_R_N`), broadcastable.
    Returns:
        ``(..., 3, 3)``. Inverse: ``R_uav^n = R_uav^sat R_sat^n``.
    """
    R_uav_n = check_last_dims(R_uav_n, (3, 3), "R_uav_n")
    R_sat_n = check_last_dims(R_sat_n, (3, 3), "R_sat_n")
    return R_uav_n @ R_sat_n.transpose(-1, -2)


# Eq. 5: the satellite camera looks straight down (pitch -90 deg) with heading 0, so the top of its
# image is north. R = Rx(-90 deg).
SAT_R_N: Tensor = torch.tensor(
    [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], dtype=torch.float64
)
# The paper prints Q_sat^n = [-0.7071, 0.7071, 0, 0]; that is the same rotation with the opposite
# sign. We store the canonical w >= 0 form.
SAT_Q_N: Tensor = torch.tensor([math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0], dtype=torch.float64)
