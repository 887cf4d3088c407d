"""The geometry core shared by the simulator, the heads and the metrics.

Torch, batched over leading dimensions, float32 and float64, differentiable. Conventions are in
DEVELOPERS.md: ENU navigation frame, body x right / y forward / z up,
``R_b^n = Rz(yaw) Rx(pitch) Ry(roll)``, quaternions ``(w, x, y, z)``, radians.
"""

from benchmark.geometry.rotations import (
    SAT_Q_N,
    SAT_R_N,
    euler_to_rotmat,
    quat_conjugate,
    quat_multiply,
    quat_to_rotmat,
    relative_rotation,
    rotmat_to_euler,
    rotmat_to_quat,
    rotmat_to_quat_paper,
    rotmat_to_rotvec,
    rotvec_to_rotmat,
)
from benchmark.geometry.so3 import (
    angle_difference,
    geodesic_distance,
    gram_schmidt,
    special_orthogonalize,
)
from benchmark.geometry.sphere import (
    discrete_vmf,
    fibonacci_sphere,
    spherical_mean,
    super_fibonacci,
    vmf_density,
    vmf_log_density,
)

__all__ = [
    "SAT_Q_N",
    "SAT_R_N",
    "angle_difference",
    "discrete_vmf",
    "euler_to_rotmat",
    "fibonacci_sphere",
    "geodesic_distance",
    "gram_schmidt",
    "quat_conjugate",
    "quat_multiply",
    "quat_to_rotmat",
    "relative_rotation",
    "rotmat_to_euler",
    "rotmat_to_quat",
    "rotmat_to_quat_paper",
    "rotmat_to_rotvec",
    "rotvec_to_rotmat",
    "special_orthogonalize",
    "spherical_mean",
    "super_fibonacci",
    "vmf_density",
    "vmf_log_density",
]
