"""Hamilton quaternions, scalar first (``quat_wxyz``); ``q`` rotates body vectors into the reference frame
(``R_w_b``). The gyro integration by RK4 is ``imuslam.imu.rk4`` (Sola, "Quaternion kinematics for the
error-state Kalman filter", 2017, eq. 211).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def quat_mul(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product ``p ⊗ q``, (..., 4) x (..., 4) -> (..., 4)."""
    a = np.asarray(p, dtype=float)
    b = np.asarray(q, dtype=float)
    pw, px, py, pz = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    qw, qx, qy, qz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conj(q: ArrayLike) -> FloatArray:
    """Conjugate (inverse of a unit quaternion)."""
    out = np.array(q, dtype=float, copy=True)
    out[..., 1:] *= -1.0
    return out


def quat_normalize(q: ArrayLike) -> FloatArray:
    """Unit quaternion with the same direction."""
    a = np.asarray(q, dtype=float)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def quat_from_rotvec(theta: ArrayLike) -> FloatArray:
    """Rotation vector (..., 3), rad -> unit quaternion (..., 4)."""
    th = np.asarray(theta, dtype=float)
    angle = np.linalg.norm(th, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    s = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half), s * th], axis=-1)


def quat_to_rotvec(q: ArrayLike) -> FloatArray:
    """Unit quaternion (..., 4) -> rotation vector (..., 3), angle in [0, pi]."""
    a = np.asarray(q, dtype=float)
    a = np.where(a[..., :1] < 0.0, -a, a)
    vnorm = np.linalg.norm(a[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(vnorm, a[..., :1])
    small = vnorm < 1e-12
    w = np.where(small, 1.0, a[..., :1])
    scale = np.where(small, 2.0 / w, angle / np.where(small, 1.0, vnorm))
    return scale * a[..., 1:]


def quat_to_matrix(q: ArrayLike) -> FloatArray:
    """Unit quaternion (..., 4) -> rotation matrix (..., 3, 3)."""
    a = quat_normalize(q)
    w, x, y, z = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    R = np.empty(a.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quat_from_matrix(R: ArrayLike) -> FloatArray:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4) with w >= 0 (Shepperd's method)."""
    M = np.asarray(R, dtype=float)
    m00, m11, m22 = M[..., 0, 0], M[..., 1, 1], M[..., 2, 2]
    tr = m00 + m11 + m22
    cands = np.stack(
        [
            np.stack(
                [
                    1 + tr,
                    M[..., 2, 1] - M[..., 1, 2],
                    M[..., 0, 2] - M[..., 2, 0],
                    M[..., 1, 0] - M[..., 0, 1],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    M[..., 2, 1] - M[..., 1, 2],
                    1 + m00 - m11 - m22,
                    M[..., 0, 1] + M[..., 1, 0],
                    M[..., 0, 2] + M[..., 2, 0],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    M[..., 0, 2] - M[..., 2, 0],
                    M[..., 0, 1] + M[..., 1, 0],
                    1 - m00 + m11 - m22,
                    M[..., 1, 2] + M[..., 2, 1],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    M[..., 1, 0] - M[..., 0, 1],
                    M[..., 0, 2] + M[..., 2, 0],
                    M[..., 1, 2] + M[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                axis=-1,
            ),
        ],
        axis=-2,
    )
    pick = np.argmax(np.stack([tr, m00, m11, m22], axis=-1), axis=-1)
    q = np.take_along_axis(cands, pick[..., None, None], axis=-2)[..., 0, :]
    q = quat_normalize(q)
    return np.where(q[..., :1] < 0.0, -q, q)
