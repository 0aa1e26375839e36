"""Point-to-plane and point-to-line correspondences, and their residuals and Jacobians (numba).

Each correspondence is a unit direction ``n`` and an anchor ``c`` such that the residual of a world point
``q`` is ``r = n . (q - c)``: for a plane ``n`` is its normal (FAST-LIO2, Xu et al. 2022, eq. 12); for a
line (LOAM's edge residual, Zhang & Singh 2014, eq. 2) ``n`` is the unit vector from the line to the
point, so ``|r|`` is the point-to-line distance and both kinds go through one measurement.
Plane and line come from the eigen-decomposition of the k neighbours' covariance.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@numba.njit(cache=True, inline="always")
def eigvals3(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float) -> tuple[float, float, float]:  # pragma: no cover - compiled  # fmt: skip
    """Eigenvalues (ascending) of a symmetric 3x3 matrix, closed form (Smith, CACM 4(4), 1961)."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    if p1 < 1e-30:
        w0, w1, w2 = sorted((a00, a11, a22))
        return w0, w1, w2
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    det = (
        b00 * (b11 * b22 - a12 * a12)
        - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02)
    )
    r = det / (2.0 * p * p * p)
    r = min(max(r, -1.0), 1.0)
    phi = np.arccos(r) / 3.0
    w2 = q + 2.0 * p * np.cos(phi)
    w0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    return w0, 3.0 * q - w0 - w2, w2


@numba.njit(cache=True, inline="always")
def eigvec3(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float, lam: float, out: FloatArray) -> bool:  # pragma: no cover - compiled  # fmt: skip
    """Unit eigenvector of eigenvalue ``lam`` into ``out``: the longest cross product of two rows of
    ``A - lam I`` (False when the eigenvalue is not simple)."""
    r0x, r0y, r0z = a00 - lam, a01, a02
    r1x, r1y, r1z = a01, a11 - lam, a12
    r2x, r2y, r2z = a02, a12, a22 - lam
    best = -1.0
    for c in range(3):
        if c == 0:
            x, y, z = r0y * r1z - r0z * r1y, r0z * r1x - r0x * r1z, r0x * r1y - r0y * r1x
        elif c == 1:
            x, y, z = r0y * r2z - r0z * r2y, r0z * r2x - r0x * r2z, r0x * r2y - r0y * r2x
        else:
            x, y, z = r1y * r2z - r1z * r2y, r1z * r2x - r1x * r2z, r1x * r2y - r1y * r2x
        d = x * x + y * y + z * z
        if d > best:
            best = d
            out[0], out[1], out[2] = x, y, z
    if best < 1e-30:
        return False
    nrm = np.sqrt(best)
    out[0] /= nrm
    out[1] /= nrm
    out[2] /= nrm
    return True


@numba.njit(cache=True)
def _moments(nbr: IntArray, map_pts: FloatArray, m: int, c: FloatArray) -> tuple[float, float, float, float, float, float]:  # pragma: no cover - compiled  # fmt: skip
    k = nbr.shape[1]
    c[0] = c[1] = c[2] = 0.0
    # each neighbour read through a view of its row: constant indices, checked once (numba checks a
    # possibly negative index at every access)
    for j in range(k):
        p = map_pts[nbr[m, j]]
        for a in range(3):
            c[a] += p[a]
    for a in range(3):
        c[a] /= k
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    for j in range(k):
        p = map_pts[nbr[m, j]]
        ex = p[0] - c[0]
        ey = p[1] - c[1]
        ez = p[2] - c[2]
        s00 += ex * ex
        s01 += ex * ey
        s02 += ex * ez
        s11 += ey * ey
        s12 += ey * ez
        s22 += ez * ez
    return s00 / k, s01 / k, s02 / k, s11 / k, s12 / k, s22 / k


@numba.njit(cache=True, inline="always")
def plane_row(nbr: IntArray, d2: FloatArray, map_pts: FloatArray, m: int, max_d2: float, max_plane_res: float, c: FloatArray, n: FloatArray) -> bool:  # pragma: no cover - compiled  # fmt: skip
    """The plane of row ``m``'s k neighbours into ``n`` (normal) and ``c`` (anchor); False when it is
    not valid (see :func:`fit_planes`)."""
    k = nbr.shape[1]
    if nbr[m, k - 1] < 0 or d2[m, k - 1] > max_d2:
        return False
    s00, s01, s02, s11, s12, s22 = _moments(nbr, map_pts, m, c)
    w0, w1, w2 = eigvals3(s00, s01, s02, s11, s12, s22)
    if not eigvec3(s00, s01, s02, s11, s12, s22, w0, n):
        return False
    for j in range(k):
        p = map_pts[nbr[m, j]]
        e0 = p[0] - c[0]
        e1 = p[1] - c[1]
        e2 = p[2] - c[2]
        if abs(n[0] * e0 + n[1] * e1 + n[2] * e2) > max_plane_res:
            return False
    return True


@numba.njit(cache=True, inline="always")
def line_row(qx: float, qy: float, qz: float, nbr: IntArray, d2: FloatArray, map_pts: FloatArray, m: int, max_d2: float, min_ratio: float, c: FloatArray, d: FloatArray, n: FloatArray) -> bool:  # pragma: no cover - compiled  # fmt: skip
    """The line of row ``m``'s k neighbours: a point on it into ``c``, the unit direction from it to
    the query (qx, qy, qz) into ``n`` (``d``: scratch); False when it is not valid (see
    :func:`fit_lines`)."""
    k = nbr.shape[1]
    if nbr[m, k - 1] < 0 or d2[m, k - 1] > max_d2:
        return False
    s00, s01, s02, s11, s12, s22 = _moments(nbr, map_pts, m, c)
    w0, w1, w2 = eigvals3(s00, s01, s02, s11, s12, s22)
    if w2 < min_ratio * w1 or not eigvec3(s00, s01, s02, s11, s12, s22, w2, d):
        return False
    e0, e1, e2 = qx - c[0], qy - c[1], qz - c[2]
    t = e0 * d[0] + e1 * d[1] + e2 * d[2]
    e0, e1, e2 = e0 - t * d[0], e1 - t * d[1], e2 - t * d[2]
    r = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    if r < 1e-6:
        return False
    n[0], n[1], n[2] = e0 / r, e1 / r, e2 / r
    return True


@numba.njit(cache=True)
def fit_planes(q: FloatArray, nbr: IntArray, d2: FloatArray, map_pts: FloatArray, max_d2: float, max_plane_res: float) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:  # pragma: no cover - compiled  # fmt: skip
    """Plane normal n (M, 3), anchor c (M, 3) and validity (M,) of each query's k neighbours.

    Valid when all k neighbours exist within sqrt(max_d2) and lie within max_plane_res of the plane.
    """
    M = nbr.shape[0]
    n_out = np.zeros((M, 3))
    c_out = np.zeros((M, 3))
    ok = np.zeros(M, dtype=np.bool_)
    c = np.empty(3)
    n = np.empty(3)
    for m in range(M):
        if plane_row(nbr, d2, map_pts, m, max_d2, max_plane_res, c, n):
            n_out[m] = n
            c_out[m] = c
            ok[m] = True
    return n_out, c_out, ok


@numba.njit(cache=True)
def fit_lines(q: FloatArray, nbr: IntArray, d2: FloatArray, map_pts: FloatArray, max_d2: float, min_ratio: float) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:  # pragma: no cover - compiled  # fmt: skip
    """Unit direction from the fitted line to the query n (M, 3), a point on the line c (M, 3), validity.

    Valid when the largest eigenvalue of the neighbours' covariance is ``min_ratio`` times the second
    (LOAM's edge test) and the query is off the line.
    """
    M = nbr.shape[0]
    n_out = np.zeros((M, 3))
    c_out = np.zeros((M, 3))
    ok = np.zeros(M, dtype=np.bool_)
    c = np.empty(3)
    d = np.empty(3)
    n = np.empty(3)
    for m in range(M):
        if line_row(q[m, 0], q[m, 1], q[m, 2], nbr, d2, map_pts, m, max_d2, min_ratio, c, d, n):
            n_out[m] = n
            c_out[m] = c
            ok[m] = True
    return n_out, c_out, ok


@numba.njit(cache=True)
def point_to_plane_system(p_i: FloatArray, n: FloatArray, c: FloatArray, R_w_i: FloatArray, p_w: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled  # fmt: skip
    """Residuals r (M,) = n.(R p_i + p - c) and their Jacobians (M, 6) w.r.t. [dp, dtheta] with the
    right perturbation R Exp(dtheta): dr/dp = n^T, dr/dtheta = -n^T R hat(p_i); weighted by w (M,)."""
    M = p_i.shape[0]
    r = np.empty(M)
    J = np.empty((M, 6))
    for m in range(M):
        x = p_i[m]
        q0 = R_w_i[0, 0] * x[0] + R_w_i[0, 1] * x[1] + R_w_i[0, 2] * x[2] + p_w[0]
        q1 = R_w_i[1, 0] * x[0] + R_w_i[1, 1] * x[1] + R_w_i[1, 2] * x[2] + p_w[1]
        q2 = R_w_i[2, 0] * x[0] + R_w_i[2, 1] * x[1] + R_w_i[2, 2] * x[2] + p_w[2]
        r[m] = w[m] * (
            n[m, 0] * (q0 - c[m, 0]) + n[m, 1] * (q1 - c[m, 1]) + n[m, 2] * (q2 - c[m, 2])
        )
        # a = R^T n; dr/dtheta = -n^T R hat(x) = -a^T hat(x) = (x cross a)^T
        a0 = R_w_i[0, 0] * n[m, 0] + R_w_i[1, 0] * n[m, 1] + R_w_i[2, 0] * n[m, 2]
        a1 = R_w_i[0, 1] * n[m, 0] + R_w_i[1, 1] * n[m, 1] + R_w_i[2, 1] * n[m, 2]
        a2 = R_w_i[0, 2] * n[m, 0] + R_w_i[1, 2] * n[m, 1] + R_w_i[2, 2] * n[m, 2]
        J[m, 0] = w[m] * n[m, 0]
        J[m, 1] = w[m] * n[m, 1]
        J[m, 2] = w[m] * n[m, 2]
        J[m, 3] = w[m] * (x[1] * a2 - x[2] * a1)
        J[m, 4] = w[m] * (x[2] * a0 - x[0] * a2)
        J[m, 5] = w[m] * (x[0] * a1 - x[1] * a0)
    return r, J


def point_to_plane_reference(
    p_i: FloatArray, n: FloatArray, c: FloatArray, R_w_i: FloatArray, p_w: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Slow reference of :func:`point_to_plane_system` with unit weights (numpy, matrix form)."""
    q = p_i @ R_w_i.T + p_w
    r = np.einsum("mk,mk->m", n, q - c)
    J = np.zeros((len(p_i), 6))
    J[:, :3] = n
    for m in range(len(p_i)):
        x = p_i[m]
        hx = np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])
        J[m, 3:] = -n[m] @ R_w_i @ hx
    return r, J


def fit_planes_reference(nbr: IntArray, map_pts: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Slow reference: normal (M, 3) and centroid (M, 3) from numpy's eigh of each neighbourhood."""
    n = np.zeros((len(nbr), 3))
    c = np.zeros((len(nbr), 3))
    for m in range(len(nbr)):
        P = map_pts[nbr[m]]
        c[m] = P.mean(axis=0)
        _, V = np.linalg.eigh(np.cov((P - c[m]).T, bias=True))
        n[m] = V[:, 0]
    return n, c
