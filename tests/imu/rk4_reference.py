"""The slow reference of the RK4 gyro integration (Tedaldi 2014, eq. 14), the truth the product's kernels
(``imuslam.imu.rk4``: compiled and numpy) are tested against. Not part of the package: the product has
no use for it.

Kinematics: ``dq/dt = 0.5 * q (x) [0, omega_b]`` with ``q`` rotating body vectors into the reference
frame (``R_w_b``) and ``omega_b`` the body angular rate (Sola, "Quaternion kinematics for the
error-state Kalman filter", 2017, eq. 211).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imuslam.geometry import quat_normalize

FloatArray = NDArray[np.float64]


def _omega_matrix(w: FloatArray) -> FloatArray:
    """(..., 3) -> (..., 4, 4) matrix with ``Omega(w) @ q == q ⊗ [0, w]``."""
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    zero = np.zeros_like(x)
    return np.stack(
        [
            np.stack([zero, -x, -y, -z], axis=-1),
            np.stack([x, zero, z, -y], axis=-1),
            np.stack([y, -z, zero, x], axis=-1),
            np.stack([z, y, -x, zero], axis=-1),
        ],
        axis=-2,
    )


def rk4_integrate_gyro(
    omega_b: ArrayLike,
    dt_s: ArrayLike,
    quat_wxyz0: ArrayLike | None = None,
) -> FloatArray:
    """Integrate body rates into the attitude by 4th-order Runge-Kutta, many segments at once.

    omega_b: (S, N, 3) angular rate samples, body frame, rad/s, for S independent segments of N
        samples each (pad shorter segments with zero rate and zero dt). A (N, 3) input is one segment.
    dt_s: (S, N - 1) or (N - 1,) sample intervals, s; step k uses samples k and k + 1, the midpoint
        rate being their mean (the RK4 scheme of Tedaldi 2014, eq. 14).
    quat_wxyz0: (S, 4) initial attitude, identity by default.
    Returns (S, 4) or (4,): the attitude ``R_start_end`` after the last sample.
    """
    w = np.asarray(omega_b, dtype=float)
    single = w.ndim == 2
    if single:
        w = w[None]
    S, N, _ = w.shape
    dt = np.broadcast_to(np.asarray(dt_s, dtype=float), (S, max(N - 1, 0)))
    if quat_wxyz0 is None:
        q = np.zeros((S, 4))
        q[:, 0] = 1.0
    else:
        q = np.array(np.broadcast_to(np.asarray(quat_wxyz0, dtype=float), (S, 4)))
    for k in range(N - 1):
        h = dt[:, k, None, None]
        O1 = _omega_matrix(w[:, k])
        O2 = _omega_matrix(0.5 * (w[:, k] + w[:, k + 1]))
        O3 = _omega_matrix(w[:, k + 1])
        qc = q[..., None]
        k1 = 0.5 * O1 @ qc
        k2 = 0.5 * O2 @ (qc + 0.5 * h * k1)
        k3 = 0.5 * O2 @ (qc + 0.5 * h * k2)
        k4 = 0.5 * O3 @ (qc + h * k3)
        q = (qc + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4))[..., 0]
        q = quat_normalize(q)
    return q[0] if single else q
