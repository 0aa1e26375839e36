"""The compiled RK4 integration of corrected gyro rates over many segments and parameter sets.

Kept apart from ``imu.rk4`` so that importing numba (and loading the cached kernel, about 0.6 s of a
whole process) is paid only by the callers that integrate often (the joint fit, its cross-validation,
the pose planner); ``imu.rk4.integrate_segments_numpy`` is the same integration in numpy.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@numba.njit(cache=True, inline="always")
def qdot(
    qw: float, qx: float, qy: float, qz: float, wx: float, wy: float, wz: float
) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """``0.5 q (x) [0, w]``."""
    return (
        0.5 * (-qx * wx - qy * wy - qz * wz),
        0.5 * (qw * wx + qy * wz - qz * wy),
        0.5 * (qw * wy - qx * wz + qz * wx),
        0.5 * (qw * wz + qx * wy - qy * wx),
    )


@numba.njit(cache=True, parallel=True)
def rk4_segments(
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    Ms: FloatArray,
    offs: FloatArray,
    Gs: FloatArray,
    f: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled
    """Integrated rotations R_start_end (P, S, 3, 3) of ``M_p (w - o_p) - G_p f`` over each segment [a, b].

    RK4 on the quaternion with the rate at the step midpoint taken as the mean of its ends
    (Tedaldi 2014, eq. 14); the slow reference is ``tests/imu/rk4_reference.py``.
    """
    P = Ms.shape[0]
    S = segs.shape[0]
    out = np.empty((P, S, 3, 3))
    for ps in numba.prange(P * S):  # every (parameter set, segment) pair is independent
        p = ps // S
        s = ps % S
        M = Ms[p]
        G = Gs[p]
        o0, o1, o2 = offs[p, 0], offs[p, 1], offs[p, 2]
        a, b = segs[s, 0], segs[s, 1]
        qw, qx, qy, qz = 1.0, 0.0, 0.0, 0.0
        v0, v1, v2 = w[a, 0] - o0, w[a, 1] - o1, w[a, 2] - o2
        f0, f1, f2 = f[a, 0], f[a, 1], f[a, 2]
        x0 = (
            M[0, 0] * v0
            + M[0, 1] * v1
            + M[0, 2] * v2
            - (G[0, 0] * f0 + G[0, 1] * f1 + G[0, 2] * f2)
        )
        y0 = (
            M[1, 0] * v0
            + M[1, 1] * v1
            + M[1, 2] * v2
            - (G[1, 0] * f0 + G[1, 1] * f1 + G[1, 2] * f2)
        )
        z0 = (
            M[2, 0] * v0
            + M[2, 1] * v1
            + M[2, 2] * v2
            - (G[2, 0] * f0 + G[2, 1] * f1 + G[2, 2] * f2)
        )
        for k in range(a, b):
            v0, v1, v2 = w[k + 1, 0] - o0, w[k + 1, 1] - o1, w[k + 1, 2] - o2
            f0, f1, f2 = f[k + 1, 0], f[k + 1, 1], f[k + 1, 2]
            x1 = (
                M[0, 0] * v0
                + M[0, 1] * v1
                + M[0, 2] * v2
                - (G[0, 0] * f0 + G[0, 1] * f1 + G[0, 2] * f2)
            )
            y1 = (
                M[1, 0] * v0
                + M[1, 1] * v1
                + M[1, 2] * v2
                - (G[1, 0] * f0 + G[1, 1] * f1 + G[1, 2] * f2)
            )
            z1 = (
                M[2, 0] * v0
                + M[2, 1] * v1
                + M[2, 2] * v2
                - (G[2, 0] * f0 + G[2, 1] * f1 + G[2, 2] * f2)
            )
            h = t_s[k + 1] - t_s[k]
            xm, ym, zm = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1)
            a1 = qdot(qw, qx, qy, qz, x0, y0, z0)
            a2 = qdot(
                qw + 0.5 * h * a1[0],
                qx + 0.5 * h * a1[1],
                qy + 0.5 * h * a1[2],
                qz + 0.5 * h * a1[3],
                xm,
                ym,
                zm,
            )
            a3 = qdot(
                qw + 0.5 * h * a2[0],
                qx + 0.5 * h * a2[1],
                qy + 0.5 * h * a2[2],
                qz + 0.5 * h * a2[3],
                xm,
                ym,
                zm,
            )
            a4 = qdot(qw + h * a3[0], qx + h * a3[1], qy + h * a3[2], qz + h * a3[3], x1, y1, z1)
            c = h / 6.0
            qw = qw + c * (a1[0] + 2.0 * a2[0] + 2.0 * a3[0] + a4[0])
            qx = qx + c * (a1[1] + 2.0 * a2[1] + 2.0 * a3[1] + a4[1])
            qy = qy + c * (a1[2] + 2.0 * a2[2] + 2.0 * a3[2] + a4[2])
            qz = qz + c * (a1[3] + 2.0 * a2[3] + 2.0 * a3[3] + a4[3])
            nrm = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw / nrm, qx / nrm, qy / nrm, qz / nrm
            x0, y0, z0 = x1, y1, z1
        out[p, s, 0, 0] = 1 - 2 * (qy * qy + qz * qz)
        out[p, s, 0, 1] = 2 * (qx * qy - qw * qz)
        out[p, s, 0, 2] = 2 * (qx * qz + qw * qy)
        out[p, s, 1, 0] = 2 * (qx * qy + qw * qz)
        out[p, s, 1, 1] = 1 - 2 * (qx * qx + qz * qz)
        out[p, s, 1, 2] = 2 * (qy * qz - qw * qx)
        out[p, s, 2, 0] = 2 * (qx * qz - qw * qy)
        out[p, s, 2, 1] = 2 * (qy * qz + qw * qx)
        out[p, s, 2, 2] = 1 - 2 * (qx * qx + qy * qy)
    return out
