"""Pure maths: SO(3), SE(3), SE(2), Euler angles, Hamilton quaternions, pose interpolation, compiled
SO(3) kernels. No I/O, no imports of ours.

Modules: ``so3`` (functions re-exported here), ``se3``, ``se2`` (``from imuslam.geometry import se3``),
``euler``, ``interp``, ``quaternion``, ``so3_nb`` (numba kernels for inner loops).

Conventions, stated once for the whole package:
- ``R_a_b`` (3, 3) maps a vector from frame b into frame a; ``T_a_b`` (4, 4) likewise for points.
- Quaternions are Hamilton, scalar first: ``quat_wxyz`` (..., 4); ``quat_wxyz`` and ``-quat_wxyz`` are
  the same rotation, and functions returning quaternions return the one with w >= 0 only where stated.
- Tangent order, for SE(3) and SE(2) and every error state built on them: ROTATION FIRST, then
  translation: ``xi = [theta, rho]`` (6,) for SE(3), ``[theta, rho_x, rho_y]`` (3,) for SE(2).
- Perturbations are on the right: ``R ⊞ theta = R @ exp(theta)`` (``rplus``), ``rminus(R1, R2) =
  log(R2^T R1)``; likewise ``T exp(xi)`` for SE(3) / SE(2). The inertial error state uses the same
  convention (``R_true = R exp(dtheta)``, :mod:`imuslam.ins.core`).
Every function accepts a single element or a stack with leading batch dimensions.
"""

from imuslam.geometry.quaternion import (
    quat_conj,
    quat_from_matrix,
    quat_from_rotvec,
    quat_mul,
    quat_normalize,
    quat_to_matrix,
    quat_to_rotvec,
)
from imuslam.geometry.so3 import (
    exp,
    hat,
    left_jacobian,
    log,
    right_jacobian,
    rminus,
    rplus,
    vee,
)

__all__ = [
    "exp",
    "hat",
    "left_jacobian",
    "log",
    "quat_conj",
    "quat_from_matrix",
    "quat_from_rotvec",
    "quat_mul",
    "quat_normalize",
    "quat_to_matrix",
    "quat_to_rotvec",
    "right_jacobian",
    "rminus",
    "rplus",
    "vee",
]
