"""Quality of a 2D map and trajectory against a simulated truth: SE(2) alignment (Umeyama without scale),
ATE, loop error, and map sharpness against the true walls (the fraction of occupied cells farther than
a distance from any surface, and the thickness of the walls)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.sim.world import World, distance_to_surfaces

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def align_se2(est_xy: FloatArray, ref_xy: FloatArray) -> FloatArray:
    """[x, y, theta] that maps ``est_xy`` (N, 2) onto ``ref_xy`` best in least squares (Umeyama 1991,
    no scale)."""
    me, mr = est_xy.mean(axis=0), ref_xy.mean(axis=0)
    H = (est_xy - me).T @ (ref_xy - mr)
    th = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    c, s = np.cos(th), np.sin(th)
    t = mr - np.array([[c, -s], [s, c]]) @ me
    return np.array([t[0], t[1], th])


def transform(T: FloatArray, xy_yaw: FloatArray) -> FloatArray:
    c, s = np.cos(T[2]), np.sin(T[2])
    xy = xy_yaw[:, :2] @ np.array([[c, s], [-s, c]]) + T[:2]
    return np.column_stack([xy, xy_yaw[:, 2] + T[2]])


@dataclass
class MapQuality:
    ate_rmse_m: float
    ate_max_m: float
    loop_error_m: float
    loop_error_deg: float
    occupied_cells: int
    frac_far: float  # occupied cells farther than ``far_m`` from any true surface
    wall_thickness_m: (
        float  # mean over the room's four walls of the 5-95 % spread of occupied cells
    )


@dataclass
class HitSharpness:
    """The scans' hits placed with the aligned poses, against the true walls: no grid, so the score moves
    with the poses and the range noise only, not with which side of a cell border a wall falls.

    rms_m: RMS distance of the hits from the nearest true surface (the seed's "walls sharp").
    wall_width_m: mean over the room's four walls of the 5-95 % spread of the hits across the wall."""

    rms_m: float
    wall_width_m: float
    hits: int


def hit_sharpness(hits_w: FloatArray, world: World, height: float) -> HitSharpness:
    """Score ``hits_w`` (N, 2), the scan endpoints in the world frame, against ``world``'s surfaces at
    the scanner's ``height``."""
    if not len(hits_w):
        return HitSharpness(float("nan"), float("nan"), 0)
    d = distance_to_surfaces(world, np.column_stack([hits_w, np.full(len(hits_w), height)]))
    return HitSharpness(float(np.sqrt(np.mean(d**2))), wall_thickness(hits_w), len(hits_w))


def occupied_centres(prob: FloatArray, known: NDArray[np.bool_], x0: float, y0: float, res: float,
                     thresh: float = 0.65) -> FloatArray:  # fmt: skip
    iy, ix = np.nonzero(known & (prob >= thresh))
    return np.column_stack([x0 + (ix + 0.5) * res, y0 + (iy + 0.5) * res])


def wall_thickness(xy: FloatArray, half: float = 4.0, band: float = 0.3) -> float:
    """Mean over the four walls at |x| = half, |y| = half of the 5-95 % width of the occupied cells
    within ``band`` of the wall's inner face (corners excluded)."""
    widths = []
    for axis in (0, 1):
        other = 1 - axis
        for sign in (-1.0, 1.0):
            d = sign * xy[:, axis] - half
            m = (np.abs(d) < band) & (np.abs(xy[:, other]) < half - band)
            if m.sum() >= 10:
                lo, hi = np.percentile(d[m], [5, 95])
                widths.append(hi - lo)
    return float(np.mean(widths)) if widths else float("nan")


def map_quality(
    est_xy_yaw: FloatArray, truth_xy_yaw: FloatArray, occupied_w: Callable[[FloatArray], FloatArray],
    world: World, height: float, far_m: float = 0.05,
) -> MapQuality:  # fmt: skip
    """Align the estimate to the truth (SE(2), positions), then score the trajectory, and the map that
    ``occupied_w(aligned poses)`` renders (occupied cell centres (M, 2) in the world frame, so that its
    raster is the world's), against the world's surfaces at the scanner's height."""
    T = align_se2(est_xy_yaw[:, :2], truth_xy_yaw[:, :2])
    al = transform(T, est_xy_yaw)
    e = np.hypot(*(al[:, :2] - truth_xy_yaw[:, :2]).T)
    d_true = truth_xy_yaw[-1] - truth_xy_yaw[0]
    d_est = est_xy_yaw[-1] - est_xy_yaw[0]
    loop_m = float(np.hypot(*(d_est[:2] - d_true[:2])))
    loop_deg = float(np.rad2deg(abs(np.angle(np.exp(1j * (d_est[2] - d_true[2]))))))
    occ = occupied_w(al)
    if len(occ):
        dist = distance_to_surfaces(world, np.column_stack([occ, np.full(len(occ), height)]))
        far = float(np.mean(dist > far_m))
    else:
        far = float("nan")
    return MapQuality(float(np.sqrt(np.mean(e**2))), float(e.max()), loop_m, loop_deg, len(occ), far,
                      wall_thickness(occ))  # fmt: skip


# ---------------------------------------------------------------------------------------------
# without ground truth: how crisp the map of a recorded log is


@dataclass
class PointMapQuality:
    """Sharpness of a point map (2D or 3D) without ground truth (Razlaw et al., "Evaluation of
    registration methods for sparse 3D laser scans", ECMR 2015): around each query point, the covariance
    S of the map's points within ``radius_m``.

    map_entropy: mean map entropy, the mean over the queries of ``0.5 ln det(2 pi e S)`` (nats; lower is
        crisper; comparable only between maps of the same log, radius and dimension).
    plane_variance_m2: mean plane variance, the mean of the smallest eigenvalue of S (m^2): in 3D the
        spread of the points about their local plane, in 2D about their local line (a wall's cut).
    wall_spread_cm: its square root in cm, the RMS distance of the points from their local wall.
    queries: neighbourhoods used (those with at least ``min_points`` points).
    """

    map_entropy: float
    plane_variance_m2: float
    wall_spread_cm: float
    queries: int
    points: int


def point_map_quality(
    points: FloatArray, radius_m: float = 0.2, min_points: int = 10, max_queries: int = 5000,
    seed: int = 0, queries: FloatArray | None = None,
) -> PointMapQuality:  # fmt: skip
    """:class:`PointMapQuality` of ``points`` (N, 2) or (N, 3), world frame, m. The queries are
    ``max_queries`` of the points drawn with ``seed`` (all of them when there are fewer), so two maps of
    the same log are scored on the same number of neighbourhoods; or the given ``queries`` (Q, dim)."""
    p = np.asarray(points, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    dim = p.shape[1]
    if len(p) < min_points:
        return PointMapQuality(float("nan"), float("nan"), float("nan"), 0, len(p))
    rng = np.random.default_rng(seed)
    if queries is not None:
        q = np.asarray(queries, dtype=float)
    else:
        q = p if len(p) <= max_queries else p[rng.choice(len(p), max_queries, replace=False)]
    # S of every neighbourhood of at least min_points points, in query order
    covs = []
    nbs = BallNeighbours(p, radius_m)
    for b0 in range(0, len(q), _QUERY_BLOCK):
        start, idx = nbs.query(q[b0 : b0 + _QUERY_BLOCK])
        xc = _centred(p, start, idx)
        for j in np.flatnonzero(np.diff(start) >= min_points):
            a, b = start[j], start[j + 1]
            if b - a < 2:  # no spread to estimate: numpy's warning and its value
                covs.append(np.cov(p[idx[a:b]], rowvar=False))
                continue
            # np.cov(p[idx[a:b]], rowvar=False): the centred points' outer products over n - 1
            x = xc[a:b]
            S = np.dot(x.T, x)
            S *= np.true_divide(1, b - a - 1)
            covs.append(S)
    if not covs:
        return PointMapQuality(float("nan"), float("nan"), float("nan"), 0, len(p))
    ev = np.linalg.eigvalsh(np.stack(covs))  # (M, dim), ascending
    ev = ev[~(ev[:, 0] <= 0)]  # a degenerate neighbourhood (collinear in 2D, coplanar in 3D)
    if not len(ev):
        return PointMapQuality(float("nan"), float("nan"), float("nan"), 0, len(p))
    # entropy of a Gaussian with covariance S: 0.5 ln det(2 pi e S) = 0.5 (dim ln(2 pi e) + sum ln ev)
    ent = 0.5 * (dim * np.log(2 * np.pi * np.e) + np.sum(np.log(ev), axis=1))
    lam = ev[:, 0]
    mpv = float(np.mean(lam))
    return PointMapQuality(float(np.mean(ent)), mpv, 100 * float(np.sqrt(mpv)), len(lam), len(p))


_QUERY_BLOCK = 1024  # queries whose neighbour lists are held at once
# a grid of more cells than this (a radius tiny against the extent) gives way to a tree
_MAX_CELLS = 2**62


class BallNeighbours:
    """The points of ``p`` (N, dim) within a radius of a query, as
    ``scipy.spatial.cKDTree.query_ball_point`` finds them (squared distance, summed axis by axis, at
    most ``radius_m**2``), each query's indices ascending. A uniform grid of cells one radius wide: a
    point within the radius lies in the query's cell or a neighbouring one."""

    def __init__(self, p: FloatArray, radius_m: float) -> None:
        self.p = np.ascontiguousarray(p, dtype=float)
        self.r = float(radius_m)
        self.grid = False
        if len(p) and self.r > 0 and np.isfinite(self.r):
            self.lo = self.p.min(axis=0)
            # wider than r: rounding never puts a neighbour two cells away
            self.cell = self.r * (1.0 + 1e-9)
            extent = np.floor((self.p.max(axis=0) - self.lo) / self.cell) + 1.0
            self.grid = float(np.prod(extent)) < _MAX_CELLS
        if self.grid:
            self.n_cells = extent.astype(np.int64)
            c = np.floor((self.p - self.lo) / self.cell).astype(np.int64)
            key = np.zeros(len(p), np.int64)  # the cell's index, the first axis fastest
            for k in range(self.p.shape[1] - 1, -1, -1):
                key = key * self.n_cells[k] + c[:, k]
            self.order = np.argsort(key, kind="stable")
            self.key_sorted = key[self.order]
            self.p_sorted = self.p[self.order]
        else:
            from scipy.spatial import cKDTree

            self.tree = cKDTree(self.p)

    def query(self, q: FloatArray) -> tuple[IntArray, IntArray]:
        """(start (Q + 1,), idx): the neighbours of query j of ``q`` (Q, dim) are
        ``idx[start[j]:start[j + 1]]``."""
        q = np.ascontiguousarray(q, dtype=float).reshape(-1, self.p.shape[1])
        if not np.all(np.isfinite(q)):
            raise ValueError("the queries must be finite")
        start = np.zeros(len(q) + 1, np.int64)
        if not self.grid:
            nbs = self.tree.query_ball_point(q, self.r, workers=1, return_sorted=True)
            np.cumsum([len(nb) for nb in nbs], out=start[1:])
            return start, np.concatenate(
                [np.zeros(0, np.int64), *(np.asarray(nb, np.int64) for nb in nbs)]
            )
        grid = (self.lo, self.cell, self.n_cells, self.key_sorted, self.order)
        args = (self.p_sorted, q, self.r, *grid)
        _ball_scan(*args, start[1:], start, False)
        np.cumsum(start, out=start)
        idx = np.empty(int(start[-1]), np.int64)
        _ball_scan(*args, start, idx, True)
        return start, idx


@numba.njit(cache=True)
def _ball_scan(
    p_sorted: FloatArray, q: FloatArray, r: float, lo: FloatArray, cell: float, n_cells: IntArray,
    key_sorted: IntArray, order: IntArray, start: IntArray, idx: IntArray, fill: bool,
) -> None:  # pragma: no cover - compiled  # fmt: skip
    """For each query j, the points of the (up to) 3^dim cells about it within ``r``: their number
    into ``start[j]`` (``fill`` false), or their indices, ascending, into ``idx[start[j]:start[j + 1]]``
    (``fill``). ``order`` (N,) the points by cell index, ``key_sorted`` (N,) and ``p_sorted`` (N, dim)
    their cell indices and coordinates in that order."""
    dim = p_sorted.shape[1]
    r2 = r * r
    lo_c = np.empty(dim, np.int64)
    hi_c = np.empty(dim, np.int64)
    cur = np.empty(dim, np.int64)
    for j in range(q.shape[0]):
        ok = True
        for k in range(dim):
            # the query's cell, clamped to one cell beyond the grid (a query farther out has none)
            f = min(max(np.floor((q[j, k] - lo[k]) / cell), -2.0), float(n_cells[k] + 1))
            lo_c[k] = max(int(f) - 1, 0)
            hi_c[k] = min(int(f) + 1, n_cells[k] - 1)
            if lo_c[k] > hi_c[k]:
                ok = False
        m = 0
        base = start[j] if fill else 0
        if ok:
            for k in range(1, dim):
                cur[k] = lo_c[k]
            while True:
                # the cells along the first axis are consecutive keys: one range of the sorted points
                row = np.int64(0)
                for k in range(dim - 1, 0, -1):
                    row = row * n_cells[k] + cur[k]
                a = np.searchsorted(key_sorted, row * n_cells[0] + lo_c[0], side="left")
                b = np.searchsorted(key_sorted, row * n_cells[0] + hi_c[0], side="right")
                for s in range(a, b):
                    d2 = 0.0
                    for k in range(dim):
                        d = p_sorted[s, k] - q[j, k]
                        d2 += d * d
                    if d2 <= r2:
                        if fill:
                            idx[base + m] = order[s]
                        m += 1
                # the next row of cells over axes 1 .. dim - 1
                k = 1
                while k < dim:
                    if cur[k] < hi_c[k]:
                        cur[k] += 1
                        break
                    cur[k] = lo_c[k]
                    k += 1
                if k >= dim:
                    break
        if fill:
            idx[base : base + m] = np.sort(idx[base : base + m])  # index order, as cKDTree
        else:
            start[j] = m


@numba.njit(cache=True)
def _centred(p: FloatArray, start: IntArray, idx: IntArray) -> FloatArray:  # pragma: no cover
    """(len(idx), dim) the neighbours ``p[idx]`` less the mean of their neighbourhood
    ``idx[start[j]:start[j + 1]]``, the mean summed in index order as ``numpy.mean`` does."""
    dim = p.shape[1]
    out = np.empty((len(idx), dim))
    mean = np.empty(dim)
    for j in range(len(start) - 1):
        a, b = start[j], start[j + 1]
        if b <= a:
            continue
        for k in range(dim):
            mean[k] = p[idx[a], k]
        for s in range(a + 1, b):
            for k in range(dim):
                mean[k] += p[idx[s], k]
        for k in range(dim):
            mean[k] /= b - a
        for s in range(a, b):
            for k in range(dim):
                out[s, k] = p[idx[s], k] - mean[k]
    return out
