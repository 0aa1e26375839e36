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

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import splu

from imuslam.lio.matcher import Correspondences, LocalMap
from imuslam.lio.residuals import fit_lines, fit_planes

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


def _unit(v: FloatArray) -> FloatArray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def associate_shared(
    local_map: LocalMap, surf_i: FloatArray, edge_i: FloatArray, R_w_i: FloatArray, p_w: FloatArray,
    gate: float, origin_w: FloatArray, origins: SensorOrigins, range_std: float,
) -> tuple[Correspondences, FloatArray, sp.csr_matrix]:  # fmt: skip
    """``LocalMap.associate``'s rows (the same gates) with their noise model: the rows' own range-noise
    standard deviation along the normal s (M,), m, and G (M, N) sparse, the map points' shared noise
    (module doc). ``origin_w`` (3,): the LiDAR's origin at this scan (world); a map point without a
    recorded origin takes it (the query's beam)."""
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
        X = storage[nb]  # (M, k, 3)
        E = X - ck[:, None, :]
        u = qk - ck
        k = nb.shape[1]
        S = np.einsum("mki,mkj->mij", E, E)
        # eigenvalues ascending: a plane's normal first, a line's direction last
        lam, V = np.linalg.eigh(S)
        if kind == 0:
            a_j = np.einsum("mki,mil->mkl", E, V[:, :, 1:])  # in-plane coordinates (M, k, 2)
            a_q = np.einsum("mi,mil->ml", u, V[:, :, 1:])
            g = 1.0 / k + np.einsum("ml,mkl->mk", a_q / np.maximum(lam[:, 1:], 1e-12), a_j)
        else:
            t_j = np.einsum("mki,mi->mk", E, V[:, :, 2])
            t_q = np.einsum("mi,mi->m", u, V[:, :, 2])
            g = 1.0 / k + (t_q / np.maximum(lam[:, 2], 1e-12))[:, None] * t_j
        o = origins.origins(vmap.ids[nb])  # (M, k, 3)
        o = np.where(np.isnan(o), origin_w[None, None, :], o)
        b_j = _unit(X - o)
        b_q = _unit(qk - origin_w)
        s = range_std * np.abs(np.einsum("mi,mi->m", nk, b_q))
        Gv = g * range_std * np.abs(np.einsum("mki,mi->mk", b_j, nk))
        corr = Correspondences(pts[ok], nk, ck, np.full(len(nk), kind, np.int8),
                               vmap.ids[nb[:, 0]])  # fmt: skip
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
    cols = np.concatenate([p[3] for p in parts])
    uniq, inv = np.unique(cols, return_inverse=True)
    M, k = Gv.shape
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
) -> tuple[FloatArray, FloatArray, int, int, FloatArray]:  # fmt: skip
    """``lidar_only.gauss_newton`` (the same two passes, coarse gate then tight; ``coarse=False``: the
    tight pass alone) with the rows' noise model of this module and Tukey weights on the normalised
    residuals. ``p_s`` (3,): the sensor's origin in the scan frame (default its origin). Returns R, p,
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
        corr, s, G = associate_shared(local_map, surf, edge, R, p, gate, origin, origins, range_std)
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
