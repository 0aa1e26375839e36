"""Front ends: LOAM edge and plane features per ring, and the direct mode (voxel-downsampled raw points).

LOAM (Zhang & Singh, "LOAM: Lidar Odometry and Mapping in Real-time", RSS 2014), Sec. V-A: the
smoothness of point i on its ring is ``c = || sum_{j in S} (X_j - X_i) || / (|S| ||X_i||)`` (eq. 1) over
5 neighbours on each side; the sharpest points of each sector are edges, the smoothest are planes.
Unreliable points are rejected (Fig. 4): (a) on a surface nearly parallel to the beam (both neighbours
far away relative to the range) and (b) on the far side of an occlusion (a depth jump to a neighbour).
Every loop over points is compiled (numba).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

HALF = 5  # neighbours on each side, LOAM eq. 1


@dataclass
class FeatureParams:
    """edge_threshold / plane_threshold: smoothness limits (eq. 1, dimensionless); max_edges: per sector;
    sectors: per ring; parallel_ratio: a neighbour farther than this fraction of the range on both sides
    marks a surface parallel to the beam; occlusion_ratio: a relative depth jump that marks an occlusion."""

    edge_threshold: float = 0.005
    plane_threshold: float = 0.003
    max_edges: int = 4
    sectors: int = 6
    parallel_ratio: float = 0.05
    occlusion_ratio: float = 0.1


@numba.njit(cache=True)
def _smoothness(pts: FloatArray, ring_start: IntArray, par: float, occ: float) -> tuple[FloatArray, NDArray[np.bool_]]:  # pragma: no cover - compiled  # fmt: skip
    n = pts.shape[0]
    curv = np.full(n, np.inf)
    ok = np.zeros(n, dtype=np.bool_)
    rng = np.sqrt(pts[:, 0] ** 2 + pts[:, 1] ** 2 + pts[:, 2] ** 2)
    for r in range(ring_start.size - 1):
        s, e = ring_start[r], ring_start[r + 1]
        for i in range(s + HALF, e - HALF):
            sx = 0.0
            sy = 0.0
            sz = 0.0
            for j in range(i - HALF, i + HALF + 1):
                sx += pts[j, 0] - pts[i, 0]
                sy += pts[j, 1] - pts[i, 1]
                sz += pts[j, 2] - pts[i, 2]
            curv[i] = np.sqrt(sx * sx + sy * sy + sz * sz) / (2 * HALF * rng[i])
            ok[i] = True
        # reliability (LOAM Fig. 4): gaps, occlusions, beams parallel to the surface
        for i in range(s + HALF, e - HALF):
            dn = np.sqrt(np.sum((pts[i + 1] - pts[i]) ** 2))
            dp = np.sqrt(np.sum((pts[i] - pts[i - 1]) ** 2))
            if dn > par * rng[i] and dp > par * rng[i]:
                ok[i] = False
            if dn > occ * rng[i]:
                if (
                    rng[i] > rng[i + 1]
                ):  # i is the far side: it and the points before it are occluded
                    for j in range(i - HALF, i + 1):
                        ok[j] = False
                else:
                    for j in range(i + 1, i + HALF + 1):
                        ok[j] = False
    return curv, ok


@numba.njit(cache=True)
def _select(curv: FloatArray, ok: NDArray[np.bool_], ring_start: IntArray, sectors: int, edge_thr: float, plane_thr: float, max_edges: int) -> NDArray[np.int8]:  # pragma: no cover - compiled  # fmt: skip
    label = np.zeros(curv.size, dtype=np.int8)  # 1 edge, 2 plane
    taken = np.zeros(curv.size, dtype=np.bool_)
    for r in range(ring_start.size - 1):
        s, e = ring_start[r] + HALF, ring_start[r + 1] - HALF
        if e - s < sectors:
            continue
        for q in range(sectors):
            a = s + (e - s) * q // sectors
            b = s + (e - s) * (q + 1) // sectors
            order = np.argsort(curv[a:b])
            picked = 0
            for m in range(order.size - 1, -1, -1):
                i = a + order[m]
                if picked >= max_edges or curv[i] < edge_thr:
                    break
                if not ok[i] or taken[i]:
                    continue
                label[i] = 1
                picked += 1
                for j in range(max(a, i - HALF), min(b, i + HALF + 1)):
                    taken[j] = True
            for m in range(order.size):
                i = a + order[m]
                if curv[i] > plane_thr:
                    break
                if ok[i] and not taken[i]:
                    label[i] = 2
    return label


def ring_order(ring: NDArray[np.integer], t_s: FloatArray) -> tuple[IntArray, IntArray]:
    """Order (N,) that sorts points by ring, then time (azimuth), and the ring boundaries (R + 1,)."""
    order = np.lexsort((t_s, ring)).astype(np.int64)
    r = np.asarray(ring)[order]
    starts = np.flatnonzero(np.diff(r)) + 1
    return order, np.concatenate([[0], starts, [len(r)]]).astype(np.int64)


def loam_features(
    points_l: FloatArray,
    ring: NDArray[np.integer],
    t_s: FloatArray,
    params: FeatureParams | None = None,
) -> tuple[IntArray, IntArray, FloatArray]:
    """Edge and plane features of one scan.

    points_l: (N, 3) LiDAR frame, m; ring: (N,) beam index; t_s: (N,) point times, s.
    Returns indices into ``points_l`` of edges and of planes, and the smoothness (N,) (inf where unset).
    """
    p = params or FeatureParams()
    order, starts = ring_order(ring, t_s)
    pts = np.ascontiguousarray(points_l[order], dtype=np.float64)
    curv, ok = _smoothness(pts, starts, p.parallel_ratio, p.occlusion_ratio)
    label = _select(curv, ok, starts, p.sectors, p.edge_threshold, p.plane_threshold, p.max_edges)
    c = np.empty(len(order))
    c[order] = curv
    return order[label == 1], order[label == 2], c


def smoothness_reference(points_ring: FloatArray) -> FloatArray:
    """Slow reference of LOAM eq. 1 for the points of one ring in firing order (inf at the ends)."""
    n = len(points_ring)
    out = np.full(n, np.inf)
    for i in range(HALF, n - HALF):
        s = points_ring[i - HALF : i + HALF + 1].sum(axis=0) - (2 * HALF + 1) * points_ring[i]
        out[i] = np.linalg.norm(s) / (2 * HALF * np.linalg.norm(points_ring[i]))
    return out


def voxel_downsample(points: FloatArray, voxel: float) -> IntArray:
    """Indices of one point per occupied voxel of size ``voxel`` (m), the first in input order."""
    _, first = np.unique(voxel_keys(points, voxel), return_index=True)
    return np.sort(first).astype(np.int64)


def voxel_keys(points: FloatArray, voxel: float) -> IntArray:
    """(N,) int64 key of each point's voxel: the three voxel indices packed in 21 bits each (exact
    within +-2^20 voxels of the origin)."""
    k = np.floor(np.asarray(points) / voxel).astype(np.int64) + (1 << 20)
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


# ------------------------------------------------------------------------------------------------
# The front end in one compiled pass: range gate, ring order, smoothness (LOAM eq. 1) and reliability
# (Fig. 4), edge / plane selection per sector and the plane points' voxel downsampling, with no array
# built per point and no sort beyond the few edge candidates of a sector. Checked against the numpy path
# (``imuslam.lio.frontend.select_points_reference``) in the tests.

_HASH_MUL = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing (Knuth, TAOCP vol. 3, 6.4)


@numba.njit(cache=True)
def _first_per_voxel(pts: FloatArray, sel: IntArray, voxel: float) -> IntArray:  # pragma: no cover - compiled  # fmt: skip
    """Of the rows ``sel`` of ``pts`` (in that order), the ones that are first in their voxel: an
    open-addressing hash set of the voxel keys, load factor at most 1/2."""
    n = sel.size
    bits = 4
    while (1 << bits) < 2 * n:
        bits += 1
    size = 1 << bits
    mask = size - 1
    shift = np.uint64(64 - bits)
    table = np.full(size, -1, np.int64)
    out = np.empty(n, np.int64)
    m = 0
    for a in range(n):
        i = sel[a]
        # the voxel key uses x / voxel as voxel_keys does (the same floor at voxel boundaries)
        kx = np.int64(np.floor(pts[i, 0] / voxel)) + (1 << 20)
        ky = np.int64(np.floor(pts[i, 1] / voxel)) + (1 << 20)
        kz = np.int64(np.floor(pts[i, 2] / voxel)) + (1 << 20)
        key = (kx << 42) | (ky << 21) | kz
        s = np.int64((np.uint64(key) * _HASH_MUL) >> shift)
        while True:
            kk = table[s]
            if kk == key:
                break
            if kk == -1:
                table[s] = key
                out[m] = i
                m += 1
                break
            s = (s + 1) & mask
    return out[:m]


@numba.njit(cache=True)
def _ring_sorted(pts_in: FloatArray, t_in: FloatArray, ring_in: IntArray, min_r: float, max_r: float) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled  # fmt: skip
    """Indices of the points within [min_r, max_r] sorted by ring, then time (stable: as
    ``np.lexsort((t, ring))``), and the ring boundaries (R + 2,) (empty rings included)."""
    n = pts_in.shape[0]
    max_ring = -1
    keep = np.zeros(n, np.bool_)
    for i in range(n):
        r = np.sqrt(pts_in[i, 0] ** 2 + pts_in[i, 1] ** 2 + pts_in[i, 2] ** 2)
        if r >= min_r and r <= max_r:
            keep[i] = True
            if ring_in[i] > max_ring:
                max_ring = ring_in[i]
    starts = np.zeros(max_ring + 2, np.int64)
    for i in range(n):
        if keep[i]:
            starts[ring_in[i] + 1] += 1
    for r in range(max_ring + 1):
        starts[r + 1] += starts[r]
    pos = starts[:-1].copy()
    order = np.empty(starts[-1], np.int64)
    for i in range(n):  # a stable counting sort by ring
        if keep[i]:
            order[pos[ring_in[i]]] = i
            pos[ring_in[i]] += 1
    for r in range(
        max_ring + 1
    ):  # then by time within a ring, where the input was not in time order
        s, e = starts[r], starts[r + 1]
        for j in range(s + 1, e):
            if t_in[order[j]] < t_in[order[j - 1]]:
                seg = order[s:e].copy()
                o = np.argsort(t_in[seg], kind="mergesort")
                for a in range(e - s):
                    order[s + a] = seg[o[a]]
                break
    return order, starts


@numba.njit(cache=True)
def features_pass(pts_in: FloatArray, t_in: FloatArray, ring_in: IntArray, min_r: float, max_r: float, edge_thr: float, plane_thr: float, max_edges: int, sectors: int, par: float, occ: float, voxel: float) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled  # fmt: skip
    """Indices into ``pts_in`` of the plane points (voxel-downsampled, one per ``voxel``, ring order)
    and of the edge points of one scan (LOAM, Sec. V-A): the same selection as :func:`loam_features`
    over the points within [min_r, max_r]."""
    order, starts = _ring_sorted(pts_in, t_in, ring_in, min_r, max_r)
    n = order.size
    px = np.empty(n)
    py = np.empty(n)
    pz = np.empty(n)
    rg = np.empty(n)
    for a in range(n):
        i = order[a]
        px[a], py[a], pz[a] = pts_in[i, 0], pts_in[i, 1], pts_in[i, 2]
        rg[a] = np.sqrt(px[a] ** 2 + py[a] ** 2 + pz[a] ** 2)
    curv = np.full(n, np.inf)
    ok = np.zeros(n, np.bool_)
    label = np.zeros(n, np.int8)  # 1 edge, 2 plane
    taken = np.zeros(n, np.bool_)
    cand = np.empty(n, np.int64)
    cand_c = np.empty(n)
    for r in range(starts.size - 1):
        s, e = starts[r], starts[r + 1]
        if e - s <= 2 * HALF:
            continue
        for i in range(s + HALF, e - HALF):  # smoothness, eq. 1
            cx = cy = cz = 0.0
            # the window as views indexed from 0: constant non-negative indices, which numba compiles
            # without the negative-index check of px[j] (a fifth of the pass); the same sums in the
            # same order
            wx, wy, wz = px[i - HALF :], py[i - HALF :], pz[i - HALF :]
            for j in range(2 * HALF + 1):
                cx += wx[j] - wx[HALF]
                cy += wy[j] - wy[HALF]
                cz += wz[j] - wz[HALF]
            curv[i] = np.sqrt(cx * cx + cy * cy + cz * cz) / (2 * HALF * rg[i])
            ok[i] = True
        # reliability (Fig. 4): beams parallel to the surface, occlusions
        for i in range(s + HALF, e - HALF):
            wx, wy, wz = px[i - 1 :], py[i - 1 :], pz[i - 1 :]  # [i - 1, i, i + 1] (as above)
            dn = np.sqrt((wx[2] - wx[1]) ** 2 + (wy[2] - wy[1]) ** 2 + (wz[2] - wz[1]) ** 2)
            dp = np.sqrt((wx[1] - wx[0]) ** 2 + (wy[1] - wy[0]) ** 2 + (wz[1] - wz[0]) ** 2)
            if dn > par * rg[i] and dp > par * rg[i]:
                ok[i] = False
            if dn > occ * rg[i]:
                if rg[i] > rg[i + 1]:
                    for j in range(i - HALF, i + 1):
                        ok[j] = False
                else:
                    for j in range(i + 1, i + HALF + 1):
                        ok[j] = False
        # selection per sector: the sharpest reliable points above edge_thr (at most max_edges, none
        # within HALF of another), then every reliable smooth point below plane_thr
        s2, e2 = s + HALF, e - HALF
        if e2 - s2 < sectors:
            continue
        for q in range(sectors):
            a = s2 + (e2 - s2) * q // sectors
            b = s2 + (e2 - s2) * (q + 1) // sectors
            nc = 0
            for i in range(a, b):
                if curv[i] >= edge_thr:
                    cand[nc] = i
                    cand_c[nc] = -curv[i]
                    nc += 1
            picked = 0
            if nc:
                o = np.argsort(cand_c[:nc])
                for m in range(nc):
                    if picked >= max_edges:
                        break
                    i = cand[o[m]]
                    if not ok[i] or taken[i]:
                        continue
                    label[i] = 1
                    picked += 1
                    for j in range(max(a, i - HALF), min(b, i + HALF + 1)):
                        taken[j] = True
            for i in range(a, b):
                if curv[i] <= plane_thr and ok[i] and not taken[i]:
                    label[i] = 2
    n_e = 0
    n_p = 0
    for a in range(n):
        if label[a] == 1:
            n_e += 1
        elif label[a] == 2:
            n_p += 1
    esel = np.empty(n_e, np.int64)
    psel = np.empty(n_p, np.int64)
    n_e = 0
    n_p = 0
    for a in range(n):
        if label[a] == 1:
            esel[n_e] = order[a]
            n_e += 1
        elif label[a] == 2:
            psel[n_p] = order[a]
            n_p += 1
    return _first_per_voxel(pts_in, psel, voxel), esel


@numba.njit(cache=True)
def direct_pass(pts_in: FloatArray, min_r: float, max_r: float, voxel: float) -> IntArray:  # pragma: no cover - compiled  # fmt: skip
    """Indices of the points within [min_r, max_r], one per voxel (the first in input order)."""
    n = pts_in.shape[0]
    sel = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        r = np.sqrt(pts_in[i, 0] ** 2 + pts_in[i, 1] ** 2 + pts_in[i, 2] ** 2)
        if r >= min_r and r <= max_r:
            sel[m] = i
            m += 1
    return _first_per_voxel(pts_in, sel[:m], voxel)


def voxel_downsample_fast(points: FloatArray, voxel: float) -> IntArray:
    """As :func:`voxel_downsample` (indices of the first point of each voxel, ascending), compiled."""
    p = np.ascontiguousarray(points, dtype=np.float64)
    return _first_per_voxel(p, np.arange(len(p), dtype=np.int64), float(voxel))  # type: ignore[no-any-return]
