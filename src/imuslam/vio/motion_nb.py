"""Compiled terms of the front end's weighted motion fit (:meth:`imuslam.vio.frontend.StereoVO._refine`).

The fit is Gauss-Newton on ``T = (R, t)`` mapping previous-frame points ``X`` to current pixels
``uv``, with the left perturbation ``[dtheta, dt]``. Per point, at ``Y = R X + t``:

- projection ``p = f Y_xy / Y_z + c``, residual ``r = uv - p``, its Jacobian ``Jp = d p / d Y`` (2, 3);
- covariance ``C = s2 I + (Jp R) covX (Jp R)^T``: the tracking noise plus the point's triangulation
  covariance carried through the projection;
- ``Jd = [-Jp hat(Y), Jp]`` (2, 6), the Jacobian in the perturbation (``d Y = -hat(Y) dtheta + dt``).

:func:`normal_terms` sums ``A = sum Jd^T C^-1 Jd`` and ``g = sum Jd^T C^-1 r`` and returns each point's
``q = r^T C^-1 r``; :func:`snooped_q` tests each residual against what the fit leaves of its covariance,
``C - Jd A^-1 Jd^T`` (Baarda 1968); :func:`huber_terms` weighs each point's terms by Huber's weight
(Huber 1964, "Robust estimation of a location parameter") for the iteratively reweighted fit.
``tests/vio/test_vio_frontend.py`` checks them against numpy.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@numba.njit(cache=True)
def normal_terms(
    X: FloatArray,
    covX: FloatArray,
    uv: FloatArray,
    R: FloatArray,
    t: FloatArray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    s2: float,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
]:  # pragma: no cover
    """Gauss-Newton terms at (R, t) of the points X (n, 3) with covariances covX (n, 3, 3) seen at uv
    (n, 2): ``A`` (6, 6), ``g`` (6,), ``q`` (n,), and per point ``C`` (n, 2, 2), ``Jd`` (n, 2, 6) and
    the residual ``r`` (n, 2)."""
    n = X.shape[0]
    A = np.zeros((6, 6))
    g = np.zeros(6)
    q = np.empty(n)
    C = np.empty((n, 2, 2))
    Jd = np.zeros((n, 2, 6))
    res = np.empty((n, 2))
    Y = np.empty(3)
    Jp = np.zeros((2, 3))
    JR = np.empty((2, 3))
    M = np.empty((2, 3))
    JtW = np.empty((6, 2))
    for k in range(n):
        for a in range(3):
            Y[a] = R[a, 0] * X[k, 0] + R[a, 1] * X[k, 1] + R[a, 2] * X[k, 2] + t[a]
        z = Y[2]
        res[k, 0] = uv[k, 0] - (fx * Y[0] / z + cx)
        res[k, 1] = uv[k, 1] - (fy * Y[1] / z + cy)
        Jp[0, 0] = fx / z
        Jp[0, 2] = -fx * Y[0] / (z * z)
        Jp[1, 1] = fy / z
        Jp[1, 2] = -fy * Y[1] / (z * z)
        for i in range(2):
            for j in range(3):
                JR[i, j] = Jp[i, 0] * R[0, j] + Jp[i, 1] * R[1, j] + Jp[i, 2] * R[2, j]
        for i in range(2):
            for j in range(3):
                M[i, j] = (
                    JR[i, 0] * covX[k, 0, j] + JR[i, 1] * covX[k, 1, j] + JR[i, 2] * covX[k, 2, j]
                )
        for i in range(2):
            for j in range(2):
                C[k, i, j] = M[i, 0] * JR[j, 0] + M[i, 1] * JR[j, 1] + M[i, 2] * JR[j, 2]
            C[k, i, i] += s2
        c00, c01, c10, c11 = C[k, 0, 0], C[k, 0, 1], C[k, 1, 0], C[k, 1, 1]
        det = c00 * c11 - c01 * c10
        w00, w01, w10, w11 = c11 / det, -c01 / det, -c10 / det, c00 / det
        # -Jp hat(Y): the columns of hat(Y) are Y x e_j = [0, Y2, -Y1], [-Y2, 0, Y0], [Y1, -Y0, 0]
        for i in range(2):
            Jd[k, i, 0] = -(Jp[i, 1] * Y[2] - Jp[i, 2] * Y[1])
            Jd[k, i, 1] = -(Jp[i, 2] * Y[0] - Jp[i, 0] * Y[2])
            Jd[k, i, 2] = -(Jp[i, 0] * Y[1] - Jp[i, 1] * Y[0])
            for j in range(3):
                Jd[k, i, 3 + j] = Jp[i, j]
        for a in range(6):
            JtW[a, 0] = Jd[k, 0, a] * w00 + Jd[k, 1, a] * w10
            JtW[a, 1] = Jd[k, 0, a] * w01 + Jd[k, 1, a] * w11
        for a in range(6):
            for b in range(6):
                A[a, b] += JtW[a, 0] * Jd[k, 0, b] + JtW[a, 1] * Jd[k, 1, b]
            g[a] += JtW[a, 0] * res[k, 0] + JtW[a, 1] * res[k, 1]
        r0, r1 = res[k, 0], res[k, 1]
        q[k] = r0 * (w00 * r0 + w01 * r1) + r1 * (w10 * r0 + w11 * r1)
    return A, g, q, C, Jd, res


@numba.njit(cache=True)
def snooped_q(
    C: FloatArray, Jd: FloatArray, res: FloatArray, cov: FloatArray
) -> FloatArray:  # pragma: no cover - compiled
    """Each residual's chi-square (2 dof) under ``Qv = C - Jd cov Jd^T``; under ``C`` where the fit
    leaves the point (almost) nothing to test (``det Qv <= 1e-4 det C``)."""
    n = C.shape[0]
    q = np.empty(n)
    JP = np.empty((2, 6))
    h = np.empty((2, 2))
    for k in range(n):
        for i in range(2):
            for b in range(6):
                s = 0.0
                for a in range(6):
                    s += Jd[k, i, a] * cov[a, b]
                JP[i, b] = s
        for i in range(2):
            for j in range(2):
                s = 0.0
                for b in range(6):
                    s += JP[i, b] * Jd[k, j, b]
                h[i, j] = C[k, i, j] - s
        detq = h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0]
        detc = C[k, 0, 0] * C[k, 1, 1] - C[k, 0, 1] * C[k, 1, 0]
        if not detq > 1e-4 * detc:
            h[0, 0], h[0, 1], h[1, 0], h[1, 1] = C[k, 0, 0], C[k, 0, 1], C[k, 1, 0], C[k, 1, 1]
            detq = detc
        r0, r1 = res[k, 0], res[k, 1]
        q[k] = (r0 * (h[1, 1] * r0 - h[0, 1] * r1) + r1 * (-h[1, 0] * r0 + h[0, 0] * r1)) / detq
    return q


@numba.njit(cache=True)
def huber_terms(
    C: FloatArray, Jd: FloatArray, res: FloatArray, q: FloatArray, k: float
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Huber-weighted Gauss-Newton terms: with ``w = min(1, k / sqrt(q))`` per point (its residual's
    Mahalanobis norm ``sqrt(q)`` beyond ``k`` weighed down), ``A = sum w Jd^T C^-1 Jd``,
    ``g = sum w Jd^T C^-1 r`` and ``B = sum w^2 Jd^T C^-1 Jd``, so that ``A^-1 B A^-1`` is the
    estimate's covariance under ``C`` (the sandwich of M-estimation, Huber 1967)."""
    n = C.shape[0]
    A = np.zeros((6, 6))
    g = np.zeros(6)
    B = np.zeros((6, 6))
    JtW = np.empty((6, 2))
    for k_ in range(n):
        r = np.sqrt(q[k_])
        w = 1.0 if r <= k else k / r
        c00, c01, c10, c11 = C[k_, 0, 0], C[k_, 0, 1], C[k_, 1, 0], C[k_, 1, 1]
        det = c00 * c11 - c01 * c10
        w00, w01, w10, w11 = c11 / det, -c01 / det, -c10 / det, c00 / det
        for a in range(6):
            JtW[a, 0] = Jd[k_, 0, a] * w00 + Jd[k_, 1, a] * w10
            JtW[a, 1] = Jd[k_, 0, a] * w01 + Jd[k_, 1, a] * w11
        for a in range(6):
            for b in range(6):
                h = JtW[a, 0] * Jd[k_, 0, b] + JtW[a, 1] * Jd[k_, 1, b]
                A[a, b] += w * h
                B[a, b] += w * w * h
            g[a] += w * (JtW[a, 0] * res[k_, 0] + JtW[a, 1] * res[k_, 1])
    return A, g, B
