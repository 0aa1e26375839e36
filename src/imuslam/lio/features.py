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
