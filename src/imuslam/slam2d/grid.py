"""Probability grids for 2D mapping, as Cartographer's (Hess et al., "Real-Time Loop Closure in 2D LIDAR
SLAM", ICRA 2016, section IV): each cell holds a hit probability, updated in log-odds by every scan with
``odds(M_new) = odds(M_old) odds(p_hit | p_miss)`` (Hess 2016, eqs. 2-3), clamped, and each cell is updated
at most once per scan (hits first, then the misses along the rays). Unknown cells read as ``p_unknown``.

Cell (ix, iy) covers ``[x0 + ix r, x0 + (ix + 1) r) x [y0 + iy r, ...)``; arrays are indexed ``[iy, ix]``.
The grid grows (re-allocated with a margin) when a scan reaches past its border.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]


@dataclass(frozen=True)
class GridParams:
    """resolution m; hit/miss probabilities of one observation; clamping of the probability."""

    resolution: float = 0.05
    p_hit: float = 0.55
    p_miss: float = 0.49
    p_min: float = 0.12
    p_max: float = 0.97
    p_unknown: float = 0.1  # what the matcher reads in a cell never observed (Cartographer: 0.1)

    @property
    def l_hit(self) -> float:
        return float(np.log(self.p_hit / (1 - self.p_hit)))

    @property
    def l_miss(self) -> float:
        return float(np.log(self.p_miss / (1 - self.p_miss)))

    @property
    def l_min(self) -> float:
        return float(np.log(self.p_min / (1 - self.p_min)))

    @property
    def l_max(self) -> float:
        return float(np.log(self.p_max / (1 - self.p_max)))


@numba.njit(cache=True)
def insert_scan_kernel(
    logodds: F32,
    prob: F32,
    stamp: NDArray[np.int32],
    origin_c: FloatArray,
    ends_c: FloatArray,
    scan_id: int,
    l_hit: float,
    l_miss: float,
    l_min: float,
    l_max: float,
) -> None:  # pragma: no cover - compiled
    """Update the grid with one scan. origin_c (2,) and ends_c (P, 2): sensor origin and hit points in
    continuous cell coordinates (x / r - x0 / r). Hits first (once per cell), then misses along each ray
    (cells already updated by this scan are skipped); rays are walked cell by cell (Amanatides & Woo 1987)."""
    H, W = logodds.shape
    for k in range(ends_c.shape[0]):
        ix = int(np.floor(ends_c[k, 0]))
        iy = int(np.floor(ends_c[k, 1]))
        if 0 <= ix < W and 0 <= iy < H and stamp[iy, ix] != scan_id:
            stamp[iy, ix] = scan_id
            v = logodds[iy, ix] + l_hit
            v = min(max(v, l_min), l_max)
            logodds[iy, ix] = v
            prob[iy, ix] = 1.0 / (1.0 + np.exp(-v))
    ox, oy = origin_c[0], origin_c[1]
    for k in range(ends_c.shape[0]):
        ex, ey = ends_c[k, 0], ends_c[k, 1]
        dx, dy = ex - ox, ey - oy
        ix, iy = int(np.floor(ox)), int(np.floor(oy))
        tx_, ty_ = int(np.floor(ex)), int(np.floor(ey))
        sx = 1 if dx > 0 else -1
        sy = 1 if dy > 0 else -1
        tdx = abs(1.0 / dx) if dx != 0 else 1e30
        tdy = abs(1.0 / dy) if dy != 0 else 1e30
        tmx = ((ix + 1 - ox) if dx > 0 else (ox - ix)) * tdx
        tmy = ((iy + 1 - oy) if dy > 0 else (oy - iy)) * tdy
        n = abs(tx_ - ix) + abs(ty_ - iy)
        for _ in range(n):
            if 0 <= ix < W and 0 <= iy < H and stamp[iy, ix] != scan_id:
                stamp[iy, ix] = scan_id
                v = logodds[iy, ix] + l_miss
                v = min(max(v, l_min), l_max)
                logodds[iy, ix] = v
                prob[iy, ix] = 1.0 / (1.0 + np.exp(-v))
            if tmx < tmy:
                tmx += tdx
                ix += sx
            else:
                tmy += tdy
                iy += sy


class ProbabilityGrid:
    """A growing probability grid: ``prob`` (H, W) float32 (``p_unknown`` where never observed),
    ``logodds`` (H, W) float32, lower-left corner ``x0``, ``y0`` (m)."""

    def __init__(self, params: GridParams, centre_xy: FloatArray, half_size: float = 10.0) -> None:
        self.params = params
        r = params.resolution
        n = int(np.ceil(2 * half_size / r))
        self.x0 = float(np.floor((centre_xy[0] - half_size) / r) * r)
        self.y0 = float(np.floor((centre_xy[1] - half_size) / r) * r)
        self.logodds = np.zeros((n, n), np.float32)
        self.prob = np.full((n, n), params.p_unknown, np.float32)
        self.stamp = np.full((n, n), -1, np.int32)
        self.n_scans = 0

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.prob.shape[0]), int(self.prob.shape[1]))

    def to_cells(self, xy: FloatArray) -> FloatArray:
        """(P, 2) metric -> continuous cell coordinates."""
        r = self.params.resolution
        return np.column_stack([(xy[:, 0] - self.x0) / r, (xy[:, 1] - self.y0) / r])

    def ensure_contains(self, lo: FloatArray, hi: FloatArray, margin: float = 5.0) -> None:
        """Grow the grid (with ``margin`` m to spare) so that the box [lo, hi] (m) lies inside."""
        r = self.params.resolution
        H, W = self.shape
        x1, y1 = self.x0 + W * r, self.y0 + H * r
        if lo[0] >= self.x0 and lo[1] >= self.y0 and hi[0] < x1 and hi[1] < y1:
            return
        nx0 = min(self.x0, np.floor((lo[0] - margin) / r) * r) if lo[0] < self.x0 else self.x0
        ny0 = min(self.y0, np.floor((lo[1] - margin) / r) * r) if lo[1] < self.y0 else self.y0
        nx1 = max(x1, hi[0] + margin) if hi[0] >= x1 else x1
        ny1 = max(y1, hi[1] + margin) if hi[1] >= y1 else y1
        ox, oy = int(round((self.x0 - nx0) / r)), int(round((self.y0 - ny0) / r))
        nW, nH = int(np.ceil((nx1 - nx0) / r)), int(np.ceil((ny1 - ny0) / r))
        nW, nH = max(nW, ox + W), max(nH, oy + H)
        lg = np.zeros((nH, nW), np.float32)
        pr = np.full((nH, nW), self.params.p_unknown, np.float32)
        st = np.full((nH, nW), -1, np.int32)
        lg[oy : oy + H, ox : ox + W] = self.logodds
        pr[oy : oy + H, ox : ox + W] = self.prob
        st[oy : oy + H, ox : ox + W] = self.stamp
        self.logodds, self.prob, self.stamp = lg, pr, st
        self.x0, self.y0 = float(nx0), float(ny0)

    def insert(self, origin_xy: FloatArray, ends_xy: FloatArray) -> None:
        """Insert a scan: sensor origin (2,) and hit points (P, 2), both in the grid's metric frame."""
        if ends_xy.shape[0] == 0:
            return
        lo = np.minimum(ends_xy.min(axis=0), origin_xy)
        hi = np.maximum(ends_xy.max(axis=0), origin_xy)
        self.ensure_contains(lo, hi)
        p = self.params
        insert_scan_kernel(
            self.logodds, self.prob, self.stamp, self.to_cells(origin_xy[None])[0],
            np.ascontiguousarray(self.to_cells(ends_xy)), self.n_scans, p.l_hit, p.l_miss, p.l_min, p.l_max,
        )  # fmt: skip
        self.n_scans += 1

    def known(self) -> NDArray[np.bool_]:
        return self.stamp >= 0

    def cropped_known(self) -> tuple[F32, NDArray[np.bool_], float, float]:
        """The probability and the observed mask of the observed bounding box, and its lower-left corner."""
        k = self.known()
        if not k.any():
            return self.prob[:1, :1].copy(), k[:1, :1].copy(), self.x0, self.y0
        ys, xs = np.flatnonzero(k.any(axis=1)), np.flatnonzero(k.any(axis=0))
        r = self.params.resolution
        win = (slice(ys[0], ys[-1] + 1), slice(xs[0], xs[-1] + 1))
        return self.prob[win].copy(), k[win].copy(), self.x0 + xs[0] * r, self.y0 + ys[0] * r

    def cropped(self) -> tuple[F32, float, float]:
        """The probability of the observed bounding box, and its lower-left corner (m)."""
        k = self.known()
        if not k.any():
            return self.prob[:1, :1].copy(), self.x0, self.y0
        ys, xs = np.flatnonzero(k.any(axis=1)), np.flatnonzero(k.any(axis=0))
        r = self.params.resolution
        sub = self.prob[ys[0] : ys[-1] + 1, xs[0] : xs[-1] + 1].copy()
        return sub, self.x0 + xs[0] * r, self.y0 + ys[0] * r
