"""The LiDAR rows' noise with the frozen map's point noise shared between them (``filter.lidar_model:
plane``).

A scan point's residual against a plane (line) fitted to k frozen map points has two errors: the
point's own range noise along the normal, sigma_r |n . b| (b the beam direction), independent per row,
and the fit's error at the query point, a linear function of the k map points' own range noise. To
first order the total least-squares plane's error in its normal direction (offset and tilt) is that of
the ordinary regression of the normal coordinate on the two in-plane ones (Kanatani, Statistical
Optimization for Geometric Computation, 1996, ch. 7; Pathak et al., IEEE T-RO 26(3), 2010, eq. 10 for
the plane parameters' covariance), so the fit's error at the query's in-plane offset u (from the
neighbours' centroid) is

    sum_j g_j eta_j,   g_j = 1/k + u^T S^-1 u_j,   S = sum_j u_j u_j^T   (2 x 2),

eta_j the normal component of map point j's error (sigma_r |n . b_j|, b_j the beam that measured it).
For a line fitted to k points the same with the along-line coordinate (S a scalar). Rows that share
map points share their eta_j: the rows' covariance is R = D + G G^T with D the rows' own variances
(diagonal, Huber-inflated) and G (M x N, sparse, N the distinct map points matched) with
G_mj = g_mj |n_m . b_j| sigma_r. The update needs only H^T R^-1 H and H^T R^-1 r, through Woodbury's
identity R^-1 = D^-1 - D^-1 G (I + G^T D^-1 G)^-1 G^T D^-1 with a sparse factorisation of the N x N
matrix; they are handed to the filter as an equivalent whitened measurement of the pose's dimension
(U^T U = H^T R^-1 H, z = U^-T H^T R^-1 r, R = I), the same posterior as the M correlated rows.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import splu

from imuslam.lio.matcher import Correspondences, LocalMap
from imuslam.lio.residuals import eigvals3, eigvec3, fit_lines, fit_planes

FloatArray = NDArray[np.float64]


class SensorOrigins:
    """The LiDAR origin (world) of each map record, by tag (a ring as ``MapCovariance``'s): the beam
    direction of a stored map point is its position minus the origin of the scan that inserted it."""

    def __init__(self, slots: int = 4096) -> None:
        self._o = np.full((slots, 3), np.nan)

    def _slot(self, tag: NDArray[np.int64]) -> NDArray[np.int64]:
        return np.asarray(np.where(tag < 0, 0, 1 + tag % (len(self._o) - 1)), np.int64)

    def record(self, tag: int, origin_w: FloatArray) -> None:
        self._o[int(self._slot(np.array([tag]))[0])] = origin_w

    def origins(self, tag: NDArray[np.int32]) -> FloatArray:
        """Origins (M, 3) of the records ``tag``; NaN where unknown (the start's points, tag -1)."""
        return self._o[self._slot(np.asarray(tag, np.int64))]


def tukey_weights(z: FloatArray, c: float = 4.685) -> FloatArray:
    """Tukey's biweight, the square root of the IRLS weight (M,), of residuals ``z`` (M,) in units of
    their predicted sigma, with the scale taken as max(1, 1.4826 median |z|) so an iterate far from the
    optimum (all residuals wide) keeps its rows; c = 4.685, 95 % efficiency at the normal (Holland &
    Welsch, Commun. Stat. 6(9), 1977)."""
    if len(z) == 0:
        return np.ones(0)
    scale = max(1.0, 1.4826 * float(np.median(np.abs(z))))
    return np.asarray(np.clip(1.0 - (z / (c * scale)) ** 2, 0.0, None))


@numba.njit(cache=True)
def _row_noise(q: FloatArray, n: FloatArray, c: FloatArray, X: FloatArray, o: FloatArray,
               origin_w: FloatArray, kind: int, range_std: float) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled  # fmt: skip
    """Per row m of the queries q (M, 3) with normal n (M, 3), anchor (centroid) c (M, 3), the k
    neighbours X (M, k, 3) and the LiDAR origins o (M, k, 3) that measured them: the row's own
    range-noise sigma along the normal s (M,) and G's entries (M, k), g_j sigma_r |n . b_j| with
    g_j = 1/k + u^T S^-1 u_j in the plane's two in-plane coordinates (kind 0) or the line's
    along-line one (kind 1) (module doc). Basis-free: the in-plane basis is any orthonormal pair
    normal to n (S's own eigenvectors for a plane fitted by ``fit_planes``), the line's direction
    S's largest eigenvector."""
    M, k = X.shape[0], X.shape[1]
    s = np.zeros(M)
    G = np.zeros((M, k))
    e1, e2, d = np.empty(3), np.empty(3), np.empty(3)
    for m in range(M):
        s00 = s01 = s02 = s11 = s12 = s22 = 0.0
        for j in range(k):
            a, b, cc = X[m, j, 0] - c[m, 0], X[m, j, 1] - c[m, 1], X[m, j, 2] - c[m, 2]
            s00 += a * a
            s01 += a * b
            s02 += a * cc
            s11 += b * b
            s12 += b * cc
            s22 += cc * cc
        u0, u1, u2 = q[m, 0] - c[m, 0], q[m, 1] - c[m, 1], q[m, 2] - c[m, 2]
        n0, n1, n2 = n[m, 0], n[m, 1], n[m, 2]
        if kind == 0:
            # e1 normal to n from the axis least along it, e2 = n x e1
            if abs(n0) <= abs(n1) and abs(n0) <= abs(n2):
                x, y, z = 0.0, n2, -n1
            elif abs(n1) <= abs(n2):
                x, y, z = -n2, 0.0, n0
            else:
                x, y, z = n1, -n0, 0.0
            r = np.sqrt(x * x + y * y + z * z)
            e1[0], e1[1], e1[2] = x / r, y / r, z / r
            e2[0], e2[1], e2[2] = (
                n1 * e1[2] - n2 * e1[1],
                n2 * e1[0] - n0 * e1[2],
                n0 * e1[1] - n1 * e1[0],
            )
            # A = B^T S B (2 x 2), B = [e1 e2]
            Se1 = (
                s00 * e1[0] + s01 * e1[1] + s02 * e1[2],
                s01 * e1[0] + s11 * e1[1] + s12 * e1[2],
                s02 * e1[0] + s12 * e1[1] + s22 * e1[2],
            )
            Se2 = (
                s00 * e2[0] + s01 * e2[1] + s02 * e2[2],
                s01 * e2[0] + s11 * e2[1] + s12 * e2[2],
                s02 * e2[0] + s12 * e2[1] + s22 * e2[2],
            )
            A11 = e1[0] * Se1[0] + e1[1] * Se1[1] + e1[2] * Se1[2]
            A12 = e1[0] * Se2[0] + e1[1] * Se2[1] + e1[2] * Se2[2]
            A22 = e2[0] * Se2[0] + e2[1] * Se2[1] + e2[2] * Se2[2]
            det = max(A11 * A22 - A12 * A12, 1e-24)
            aq1 = u0 * e1[0] + u1 * e1[1] + u2 * e1[2]
            aq2 = u0 * e2[0] + u1 * e2[1] + u2 * e2[2]
            w1 = (A22 * aq1 - A12 * aq2) / det  # A^-1 a_q
            w2 = (A11 * aq2 - A12 * aq1) / det
            for j in range(k):
                a, b, cc = X[m, j, 0] - c[m, 0], X[m, j, 1] - c[m, 1], X[m, j, 2] - c[m, 2]
                G[m, j] = (
                    1.0 / k
                    + w1 * (a * e1[0] + b * e1[1] + cc * e1[2])
                    + w2 * (a * e2[0] + b * e2[1] + cc * e2[2])
                )
        else:
            lam0, lam1, lam2 = eigvals3(s00, s01, s02, s11, s12, s22)
            if not eigvec3(s00, s01, s02, s11, s12, s22, lam2, d):
                d[0], d[1], d[2] = 0.0, 0.0, 0.0
            tq = (u0 * d[0] + u1 * d[1] + u2 * d[2]) / max(lam2, 1e-12)
            for j in range(k):
                a, b, cc = X[m, j, 0] - c[m, 0], X[m, j, 1] - c[m, 1], X[m, j, 2] - c[m, 2]
                G[m, j] = 1.0 / k + tq * (a * d[0] + b * d[1] + cc * d[2])
        # beams: the query's from this scan's origin, each neighbour's from its inserting scan's
        bx, by, bz = q[m, 0] - origin_w[0], q[m, 1] - origin_w[1], q[m, 2] - origin_w[2]
        r = max(np.sqrt(bx * bx + by * by + bz * bz), 1e-12)
        s[m] = range_std * abs(n0 * bx + n1 * by + n2 * bz) / r
        for j in range(k):
            bx, by, bz = X[m, j, 0] - o[m, j, 0], X[m, j, 1] - o[m, j, 1], X[m, j, 2] - o[m, j, 2]
            r = max(np.sqrt(bx * bx + by * by + bz * bz), 1e-12)
            G[m, j] *= range_std * abs(n0 * bx + n1 * by + n2 * bz) / r
    return s, G


def associate_shared(
    local_map: LocalMap, surf_i: FloatArray, edge_i: FloatArray, R_w_i: FloatArray, p_w: FloatArray,
    gate: float, origin_w: FloatArray, origins: SensorOrigins, range_std: float,
    diagonal: bool = False,
) -> tuple[Correspondences, FloatArray, sp.csr_matrix]:  # fmt: skip
    """``LocalMap.associate``'s rows (the same gates) with their noise model: the rows' own range-noise
    standard deviation along the normal s (M,), m, and G (M, N) sparse, the map points' shared noise
    (module doc). ``origin_w`` (3,): the LiDAR's origin at this scan (world); a map point without a
    recorded origin takes it (the query's beam). ``diagonal`` (``filter.lidar_model: plane_diag``):
    the map points' noise kept on each row's own variance only, s^2 = max(s, s_min)^2 + (G G^T)_mm
    with s_min a tenth of the range noise, and G empty (M, 0): the rows taken as independent, no
    sparse factorisation (the sharing between rows dropped)."""
    pr = local_map.params
    parts: list[tuple[Correspondences, FloatArray, FloatArray, NDArray[np.int64]]] = []
    offset = 0
    for pts, vmap, kind in ((surf_i, local_map.surf, 0), (edge_i, local_map.edge, 1)):
        storage = vmap.storage
        if len(pts) == 0 or len(vmap) < pr.k:
            offset += len(storage)
            continue
        q = pts @ R_w_i.T + p_w
        nbr, d2 = vmap.knn(q, pr.k)
        if kind == 0:
            n, c, ok = fit_planes(q, nbr, d2, storage, pr.max_nbr_dist**2, pr.max_plane_res)
        else:
            n, c, ok = fit_lines(q, nbr, d2, storage, pr.max_nbr_dist**2, pr.line_ratio)
        r = np.einsum("mk,mk->m", n, q - c)
        ok &= np.abs(r) < gate
        nb, qk, nk, ck = nbr[ok], q[ok], n[ok], c[ok]
        o = origins.origins(vmap.ids[nb])  # (M, k, 3)
        o = np.where(np.isnan(o), origin_w[None, None, :], o)
        s, Gv = _row_noise(qk, nk, ck, storage[nb], o, np.asarray(origin_w, float), kind, range_std)
        corr = Correspondences(pts[ok], nk, ck, np.full(len(nk), kind, np.int8),
                               vmap.ids[nb[:, 0]])  # fmt: skip
        if diagonal:
            s = np.sqrt(np.maximum(s, 0.1 * range_std) ** 2 + np.einsum("mk,mk->m", Gv, Gv))
            Gv = Gv[:, :0]
        parts.append((corr, s, Gv, nb.astype(np.int64) + offset))
        offset += len(storage)
    if not parts:
        z = np.zeros((0, 3))
        empty = Correspondences(z, z, z, np.zeros(0, np.int8), np.zeros(0, np.int32))
        return empty, np.zeros(0), sp.csr_matrix((0, 0))
    corr = Correspondences(*(np.concatenate([getattr(p[0], f) for p in parts])
                             for f in ("p_i", "n", "c", "kind", "tag")))  # fmt: skip
    s = np.concatenate([p[1] for p in parts])
    Gv = np.concatenate([p[2] for p in parts])
    M, k = Gv.shape
    if k == 0:  # diagonal
        return corr, s, sp.csr_matrix((M, 0))
    cols = np.concatenate([p[3] for p in parts])
    uniq, inv = np.unique(cols, return_inverse=True)
    G = sp.csr_matrix((Gv.ravel(), inv.ravel(), np.arange(0, M * k + 1, k)), shape=(M, len(uniq)))
    G.sum_duplicates()
    return corr, s, G


def whitened_system(
    r: FloatArray, J: FloatArray, D: FloatArray, G: sp.csr_matrix
) -> tuple[FloatArray, FloatArray]:
    """The rows r (M,), J (M, 6) with covariance diag(D) + G G^T as an equivalent 6-row system
    (U (6, 6), z (6,)) with unit noise: U^T U = J^T R^-1 J and U^T z = J^T R^-1 r (module doc)."""
    Dinv = 1.0 / D
    A = np.column_stack([J, r]) * Dinv[:, None]  # D^-1 [J r]
    info = np.column_stack([J, r]).T @ A  # [J r]^T D^-1 [J r]
    if G.shape[1]:
        Gt = G.T.tocsr()
        Y = Gt @ A  # (N, 7)
        B = (sp.identity(G.shape[1], format="csc") + Gt @ sp.diags(Dinv) @ G).tocsc()
        X = splu(B, permc_spec="MMD_AT_PLUS_A").solve(np.asarray(Y))
        info = info - Y.T @ X
    Lam, b = info[:6, :6], info[:6, 6]
    Lam = 0.5 * (Lam + Lam.T)
    try:
        U = np.linalg.cholesky(Lam).T  # Lam = U^T U
    except np.linalg.LinAlgError:  # rows too few or down-weighted to fix every direction
        w, V = np.linalg.eigh(Lam)
        U = (V * np.sqrt(np.maximum(w, 1e-12 * max(float(w.max()), 1e-300)))).T
    z = np.linalg.solve(U.T, b)
    return np.asarray(U, np.float64), np.asarray(z, np.float64)


def gauss_newton_rows(
    local_map: LocalMap, surf: FloatArray, edge: FloatArray, R_w_s: FloatArray, p_w: FloatArray,
    range_std: float, origins: SensorOrigins | None = None, max_iterations: int = 10,
    converge: float = 1e-3, coarse: bool = True, p_s: FloatArray | None = None,
    diagonal: bool = False,
) -> tuple[FloatArray, FloatArray, int, int, FloatArray]:  # fmt: skip
    """``lidar_only.gauss_newton`` (the same two passes, coarse gate then tight; ``coarse=False``: the
    tight pass alone) with the rows' noise model of this module and Tukey weights on the normalised
    residuals. ``p_s`` (3,): the sensor's origin in the scan frame (default its origin); ``diagonal``:
    ``associate_shared``'s. Returns R, p,
    iterations, rows, and the pose covariance (6, 6) on [dp, dtheta] (the last iterate's)."""
    from imuslam.geometry import exp

    R, p = R_w_s.copy(), p_w.copy()
    origins = origins or SensorOrigins()
    pr = local_map.params
    gates = [pr.coarse_residual] * max_iterations * coarse + [pr.max_residual] * max_iterations
    fine = len(gates) // 2 if coarse else 0
    it, n_it, n = 0, 0, 0
    cov = np.full((6, 6), np.nan)
    while it < len(gates):
        gate = gates[it]
        it += 1
        n_it += 1
        origin = p.copy() if p_s is None else R @ p_s + p
        corr, s, G = associate_shared(local_map, surf, edge, R, p, gate, origin, origins, range_std,
                                      diagonal)  # fmt: skip
        n = len(corr)
        if n < 6:
            break
        r, J = corr.system(R, p)
        s = np.maximum(s, 0.1 * range_std)
        g2 = np.asarray(G.multiply(G).sum(axis=1)).ravel()
        w = tukey_weights(r / np.sqrt(s * s + g2))
        U, z = whitened_system(r * w, J * w[:, None], s * s, G)
        dx = -np.linalg.solve(U, z)
        cov = np.linalg.inv(U.T @ U)
        p = p + dx[:3]
        R = R @ exp(dx[3:])
        if np.linalg.norm(dx) < converge:
            if it > fine or pr.coarse_residual <= pr.max_residual:
                break
            it = fine
    return R, p, n_it, n, cov
