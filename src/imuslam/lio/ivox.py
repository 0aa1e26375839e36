"""An incremental voxel-hash map whose nearest-neighbour search visits the 27 cells around a query
(Faster-LIO's iVox, Bai et al., RA-L 2022, Sec. III: a hash of voxels, each holding a few points, and a
k-nearest search over the NEARBY26 neighbourhood), in numba, so the map is never rebuilt for a query.

The hash is open addressing with linear probing over spatial-hash indices (Teschner et al., "Optimized
spatial hashing for collision detection", VMV 2003: the three cell indices times three large primes,
xor-ed). A cell of ``nsub * voxel`` m holds at most ``max_per_voxel`` points in each of its ``nsub^3``
voxels, so admission is the same one-point-per-voxel rule as :class:`~imuslam.lio.voxelmap.VoxelMap`.
The search is exact for neighbours within one cell size of the query (the 27 cells cover at least that
much around it) and approximate beyond (farther points of the same plane may be missed, then the plane
fit sees fewer than k neighbours and the point is not used).

Points live in ``storage`` (C * capacity, 3): the indices ``knn`` returns index it, as
:func:`imuslam.lio.residuals.fit_planes` expects.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_EMPTY = -1
_P1, _P2, _P3 = 73856093, 19349663, 83492791  # Teschner et al. 2003
# the 27 cells around a query, its own first, then faces, edges, corners: the nearest found early
# lets the distance bound skip most of the farther cells
_ORDER = np.array(
    sorted(
        [(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)],
        key=lambda o: abs(o[0]) + abs(o[1]) + abs(o[2]),
    ),
    dtype=np.int64,
)


@numba.njit(cache=True, inline="always")
def _key(cx: int, cy: int, cz: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """Packed key (21 bits per axis, non-negative) and spatial hash of a cell."""
    key = ((cx + (1 << 20)) << 42) | ((cy + (1 << 20)) << 21) | (cz + (1 << 20))
    h = (cx * _P1) ^ (cy * _P2) ^ (cz * _P3)
    return key, h


@numba.njit(cache=True, inline="always")
def _probe(keys: IntArray, key: int, h: int) -> int:  # pragma: no cover - compiled
    """Slot of ``key``, or -1 - (the free slot where it would go)."""
    mask = keys.size - 1
    s = h & mask
    while True:
        kk = keys[s]
        if kk == key:
            return s
        if kk == _EMPTY:
            return -1 - s
        s = (s + 1) & mask


@numba.njit(cache=True)
def _insert(keys: IntArray, cnt: NDArray[np.int32], sub: NDArray[np.int32], pts: FloatArray,
            ids: NDArray[np.int32], new: FloatArray, new_ids: NDArray[np.int32], voxel: float, nsub: int,
            mpv: int) -> tuple[int, int]:  # pragma: no cover - compiled  # fmt: skip
    """Insert ``new`` (N, 3) with their tags ``new_ids`` (N,) where their voxel has room; returns
    (points admitted, cells created)."""
    n_ok = 0
    n_new_cells = 0
    cap_pts = pts.shape[1]
    for i in range(new.shape[0]):
        vx = int(np.floor(new[i, 0] / voxel))
        vy = int(np.floor(new[i, 1] / voxel))
        vz = int(np.floor(new[i, 2] / voxel))
        cx, cy, cz = vx // nsub, vy // nsub, vz // nsub
        si = ((vx - cx * nsub) * nsub + (vy - cy * nsub)) * nsub + (vz - cz * nsub)
        key, h = _key(cx, cy, cz)
        s = _probe(keys, key, h)
        if s < 0:
            s = -1 - s
            keys[s] = key
            cnt[s] = 0
            sub[s, :] = 0
            n_new_cells += 1
        if sub[s, si] >= mpv or cnt[s] >= cap_pts:
            continue
        sub[s, si] += 1
        j = cnt[s]
        pts[s, j, 0], pts[s, j, 1], pts[s, j, 2] = new[i, 0], new[i, 1], new[i, 2]
        ids[s, j] = new_ids[i]
        cnt[s] = j + 1
        n_ok += 1
    return n_ok, n_new_cells


@numba.njit(cache=True)
def _knn(keys: IntArray, cnt: NDArray[np.int32], pts: FloatArray, q: FloatArray, k: int,
         voxel: float, nsub: int) -> tuple[IntArray, FloatArray]:  # pragma: no cover - compiled  # fmt: skip
    """k nearest stored points of each query among the 27 cells around it: flat indices (M, k) into
    ``pts.reshape(-1, 3)`` and squared distances (M, k), ascending; -1 / inf where fewer were found."""
    M = q.shape[0]
    C = pts.shape[1]
    cell = voxel * nsub
    idx = np.full((M, k), -1, np.int64)
    dist = np.full((M, k), np.inf)
    for m in range(M):
        qx, qy, qz = q[m, 0], q[m, 1], q[m, 2]
        cx = int(np.floor(qx / voxel)) // nsub
        cy = int(np.floor(qy / voxel)) // nsub
        cz = int(np.floor(qz / voxel)) // nsub
        # distances from the query to the faces of its cell, for the lower bound of each neighbour
        lx, ly, lz = qx - cx * cell, qy - cy * cell, qz - cz * cell
        hx, hy, hz = cell - lx, cell - ly, cell - lz
        for o in range(27):
            dx, dy, dz = _ORDER[o, 0], _ORDER[o, 1], _ORDER[o, 2]
            bound = 0.0
            if dx < 0:
                bound += lx * lx
            elif dx > 0:
                bound += hx * hx
            if dy < 0:
                bound += ly * ly
            elif dy > 0:
                bound += hy * hy
            if dz < 0:
                bound += lz * lz
            elif dz > 0:
                bound += hz * hz
            if bound >= dist[m, k - 1]:
                continue  # no point of that cell can be among the k nearest (exact pruning)
            key, h = _key(cx + dx, cy + dy, cz + dz)
            s = _probe(keys, key, h)
            if s < 0:
                continue
            for j in range(cnt[s]):
                ex = pts[s, j, 0] - qx
                ey = pts[s, j, 1] - qy
                ez = pts[s, j, 2] - qz
                d = ex * ex + ey * ey + ez * ez
                if d >= dist[m, k - 1]:
                    continue
                a = k - 1  # insertion into the sorted k best
                while a > 0 and dist[m, a - 1] > d:
                    dist[m, a] = dist[m, a - 1]
                    idx[m, a] = idx[m, a - 1]
                    a -= 1
                dist[m, a] = d
                idx[m, a] = s * C + j
    return idx, dist


@numba.njit(cache=True)
def _gather(keys: IntArray, cnt: NDArray[np.int32], pts: FloatArray, ids: NDArray[np.int32]) -> tuple[FloatArray, NDArray[np.int32]]:  # pragma: no cover - compiled  # fmt: skip
    n = 0
    for s in range(keys.size):
        if keys[s] != _EMPTY:
            n += cnt[s]
    out = np.empty((n, 3))
    out_ids = np.empty(n, np.int32)
    i = 0
    for s in range(keys.size):
        if keys[s] != _EMPTY:
            for j in range(cnt[s]):
                out[i, :] = pts[s, j, :]
                out_ids[i] = ids[s, j]
                i += 1
    return out, out_ids


class IncrementalVoxelMap:
    """Points in the world frame, at most ``max_per_voxel`` per voxel of ``voxel_size`` m, hashed by
    cells of ``nsub`` voxels a side, within ``max_range`` m of the last pruning centre. Same interface
    as :class:`~imuslam.lio.voxelmap.VoxelMap` (``add``, ``prune``, ``transform``, ``knn``)."""

    def __init__(self, voxel_size: float = 0.5, max_per_voxel: int = 1, max_range: float = 100.0,
                 nsub: int = 2, capacity: int = 1 << 10, slots: int | None = None) -> None:  # fmt: skip
        self.voxel_size = float(voxel_size)
        self.max_per_voxel = int(max_per_voxel)
        self.max_range = float(max_range)
        self.nsub = int(nsub)
        # points a cell can hold: every voxel full by default; fewer for sparse points (edges on lines),
        # whose cells would otherwise be mostly empty slots
        self.slots = int(slots) if slots is not None else self.nsub**3 * self.max_per_voxel
        self.n_points = 0
        self.n_cells = 0
        self._alloc(capacity)

    def _alloc(self, capacity: int) -> None:
        cap = 1 << max(int(np.ceil(np.log2(max(capacity, 16)))), 4)
        n3 = self.nsub**3
        self._keys = np.full(cap, _EMPTY, np.int64)
        self._cnt = np.zeros(cap, np.int32)
        self._sub = np.zeros((cap, n3), np.int32)
        self._pts = np.zeros((cap, self.slots, 3))
        self._ids = np.zeros((cap, self.slots), np.int32)
        self.n_points = 0
        self.n_cells = 0

    def __len__(self) -> int:
        return self.n_points

    @property
    def points(self) -> FloatArray:
        """The stored points (N, 3), a copy."""
        return _gather(self._keys, self._cnt, self._pts, self._ids)[0]  # type: ignore[no-any-return]

    @property
    def ids(self) -> NDArray[np.int32]:
        """The tag of each slot of ``storage`` (what ``add`` was given with the point)."""
        return self._ids.reshape(-1)

    @property
    def storage(self) -> FloatArray:
        """The flat point storage that ``knn``'s indices index (a view)."""
        return self._pts.reshape(-1, 3)

    def _rebuild(self, points: FloatArray, ids: NDArray[np.int32], capacity: int) -> None:
        if capacity == self._keys.size:
            # the same table emptied in place: a new cell's counts are zeroed when it is created, so
            # only the keys need clearing (allocating and touching a fresh table costs more than the
            # points it holds)
            self._keys.fill(_EMPTY)
            self.n_points = 0
            self.n_cells = 0
        else:
            self._alloc(capacity)
        self._add(points, ids)

    def _add(self, p: FloatArray, ids: NDArray[np.int32]) -> int:
        if 2 * (self.n_cells + len(p)) > self._keys.size:  # keep the load factor below 1/2
            old, old_ids = _gather(self._keys, self._cnt, self._pts, self._ids)
            self._alloc(2 * (self.n_cells + len(p)) + 1)
            self._add(old, old_ids)
        n_ok, n_cells = _insert(self._keys, self._cnt, self._sub, self._pts, self._ids, p, ids,
                                self.voxel_size, self.nsub, self.max_per_voxel)  # fmt: skip
        self.n_points += n_ok
        self.n_cells += n_cells
        return int(n_ok)

    def add(self, points_w: FloatArray, tag: int = -1) -> int:
        """Insert points (N, 3) where their voxel has room, each tagged ``tag`` (e.g. the scan that
        inserted it, see ``ids``); returns how many were kept."""
        if len(points_w) == 0:
            return 0
        return self._add(np.ascontiguousarray(points_w, dtype=np.float64),
                         np.full(len(points_w), tag, np.int32))  # fmt: skip

    def prune(self, centre_w: FloatArray) -> int:
        """Drop points farther than ``max_range`` from ``centre_w`` (3,); returns how many were dropped."""
        p, ids = _gather(self._keys, self._cnt, self._pts, self._ids)
        keep = np.sum((p - np.asarray(centre_w)[None]) ** 2, axis=1) <= self.max_range**2
        n_drop = int(len(keep) - keep.sum())
        if n_drop:
            self._rebuild(np.ascontiguousarray(p[keep]), ids[keep], self._keys.size)
        return n_drop

    def transform(self, R: FloatArray, t: FloatArray) -> None:
        """Move every point by ``x -> R x + t`` (a change of world frame) and re-hash the cells."""
        p, ids = _gather(self._keys, self._cnt, self._pts, self._ids)
        self._rebuild(
            np.ascontiguousarray(p @ np.asarray(R).T + np.asarray(t)), ids, self._keys.size
        )

    def knn(self, q_w: FloatArray, k: int) -> tuple[IntArray, FloatArray]:
        """k nearest map points (within the 27 cells) of each query (M, 3): indices into ``storage``
        (M, k) and squared distances (M, k)."""
        q = np.ascontiguousarray(q_w, dtype=np.float64)
        return _knn(self._keys, self._cnt, self._pts, q, int(k), self.voxel_size, self.nsub)  # type: ignore[no-any-return]

    @property
    def nbytes(self) -> int:
        return int(self._keys.nbytes + self._cnt.nbytes + self._sub.nbytes + self._pts.nbytes
                   + self._ids.nbytes)  # fmt: skip
