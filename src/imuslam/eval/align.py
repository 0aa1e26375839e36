"""Trajectory alignment: SE(3) / Sim(3) Umeyama, yaw-only 4-DoF, and first-pose.

Each returns ``(s, R, t)`` with ``p_ref ~= s R p_est + t``; :func:`apply` maps an estimate with it.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import EstimatorError
from imuslam.interfaces.trajectory import Trajectory

FloatArray = NDArray[np.float64]
AlignMethod = Literal["se3", "sim3", "yaw", "first", "none"]
ALIGN_METHODS = ("se3", "sim3", "yaw", "first", "none")


def umeyama(x: FloatArray, y: FloatArray, with_scale: bool) -> tuple[float, FloatArray, FloatArray]:
    """Least-squares ``y ~= s R x + t`` for point sets x, y (N, 3) (Umeyama 1991, eqs. 34-43)."""
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    n = x.shape[0]
    cov = yc.T @ xc / n  # eq. 38
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:  # eq. 39
        S[2, 2] = -1.0
    R = U @ S @ Vt  # eq. 40
    s = float(np.trace(np.diag(D) @ S) / (np.sum(xc * xc) / n)) if with_scale else 1.0  # eq. 42
    t = my - s * R @ mx  # eq. 41
    return s, R, t


def yaw_only(x: FloatArray, y: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """Least-squares rotation about z (gravity) and translation: ``y ~= Rz(psi) x + t``.

    With centred points, the optimal yaw maximises sum(yc . Rz xc), giving
    ``psi = atan2(sum(xc_x yc_y - xc_y yc_x), sum(xc_x yc_x + xc_y yc_y))`` (closed form).
    """
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    num = np.sum(xc[:, 0] * yc[:, 1] - xc[:, 1] * yc[:, 0])
    den = np.sum(xc[:, 0] * yc[:, 0] + xc[:, 1] * yc[:, 1])
    psi = float(np.arctan2(num, den))
    c, s_ = np.cos(psi), np.sin(psi)
    R = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    return 1.0, R, my - R @ mx


def first_pose(ref: Trajectory, est: Trajectory) -> tuple[float, FloatArray, FloatArray]:
    """The transform that puts the first estimated pose on the first reference pose."""
    R = ref.R_w_b[0] @ est.R_w_b[0].T
    return 1.0, R, ref.p_w[0] - R @ est.p_w[0]


def align(
    ref: Trajectory, est: Trajectory, method: AlignMethod
) -> tuple[float, FloatArray, FloatArray]:
    """``(s, R, t)`` aligning associated ``est`` onto ``ref`` by ``method``."""
    if method == "se3":
        return umeyama(est.p_w, ref.p_w, False)
    if method == "sim3":
        for tr in (est, ref):
            spread = float(np.sqrt(np.mean(np.sum((tr.p_w - tr.p_w.mean(axis=0)) ** 2, axis=1))))
            if not spread > 1e-9 * max(1.0, float(np.abs(tr.p_w).max())):
                raise EstimatorError(
                    f"{tr.source}: the positions do not move (RMS spread {spread:.3g} m over {len(tr)} "
                    "poses), so a Sim(3) scale is undefined; align with se3 instead"
                )
        return umeyama(est.p_w, ref.p_w, True)
    if method == "yaw":
        return yaw_only(est.p_w, ref.p_w)
    if method == "first":
        return first_pose(ref, est)
    return 1.0, np.eye(3), np.zeros(3)


def apply(est: Trajectory, s: float, R: FloatArray, t: FloatArray) -> Trajectory:
    """``est`` mapped by ``p -> s R p + t``, ``R_w_b -> R R_w_b``."""
    return Trajectory(est.t_ns, s * est.p_w @ R.T + t, R @ est.R_w_b, est.source)
