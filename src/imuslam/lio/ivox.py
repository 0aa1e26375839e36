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

from imuslam.lio.residuals import line_row, plane_row

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


# the occupancy bitmap: one bit per cell, the cell indices taken modulo 2^7, 2^7, 2^5 (a 64 KB table
# that stays in cache, where the hash table does not): a cell whose bit is clear is not probed; a set
# bit may be another cell's (the indices wrap), then the probe decides
_BX, _BY, _BZ = 7, 7, 5


@numba.njit(cache=True, inline="always")
def _bit(cx: int, cy: int, cz: int) -> int:  # pragma: no cover - compiled
    return (
        ((cx & ((1 << _BX) - 1)) << (_BY + _BZ))
        | ((cy & ((1 << _BY) - 1)) << _BZ)
        | (cz & ((1 << _BZ) - 1))
    )


@numba.njit(cache=True, inline="always")
def _probe(tab: IntArray, key: int, h: int) -> int:  # pragma: no cover - compiled
    """Slot of ``key`` in the table ``tab`` (S, 2) of [key, cell row], or -1 - (the free slot where
    it would go)."""
    mask = tab.shape[0] - 1
    s = h & mask
    while True:
        kk = tab[s, 0]
        if kk == key:
            return s
        if kk == _EMPTY:
            return -1 - s
        s = (s + 1) & mask


@numba.njit(cache=True)
def _insert(tab: IntArray, bits: NDArray[np.uint8], ckey: IntArray, cnt: NDArray[np.int32], sub: NDArray[np.int32],
            pts: FloatArray, ids: NDArray[np.int32], n_cells: int, new: FloatArray, new_ids: NDArray[np.int32],
            voxel: float, nsub: int, mpv: int) -> tuple[int, int]:  # pragma: no cover - compiled  # fmt: skip
    """Insert ``new`` (N, 3) with their tags ``new_ids`` (N,) where their voxel has room; a new cell
    takes the next free row ``n_cells`` of the cell arrays; returns (points admitted, cells in use)."""
    n_ok = 0
    cap_pts = pts.shape[1]
    for i in range(new.shape[0]):
        vx = int(np.floor(new[i, 0] / voxel))
        vy = int(np.floor(new[i, 1] / voxel))
        vz = int(np.floor(new[i, 2] / voxel))
        cx, cy, cz = vx // nsub, vy // nsub, vz // nsub
        si = ((vx - cx * nsub) * nsub + (vy - cy * nsub)) * nsub + (vz - cz * nsub)
        key, h = _key(cx, cy, cz)
        s = _probe(tab, key, h)
        if s < 0:
            s = -1 - s
            tab[s, 0] = key
            tab[s, 1] = n_cells
            b = _bit(cx, cy, cz)
            bits[b >> 3] |= np.uint8(1 << (b & 7))
            c = n_cells
            ckey[c] = key
            cnt[c] = 0
            sub[c, :] = 0
            n_cells += 1
        else:
            c = tab[s, 1]
        if sub[c, si] >= mpv or cnt[c] >= cap_pts:
            continue
        sub[c, si] += 1
        j = cnt[c]
        pts[c, j, 0], pts[c, j, 1], pts[c, j, 2] = new[i, 0], new[i, 1], new[i, 2]
        ids[c, j] = new_ids[i]
        cnt[c] = j + 1
        n_ok += 1
    return n_ok, n_cells


@numba.njit(cache=True)
def _rehash(tab: IntArray, bits: NDArray[np.uint8], ckey: IntArray, n_cells: int) -> None:  # pragma: no cover - compiled  # fmt: skip
    """Fill the emptied hash table ``tab`` and the bitmap ``bits`` with the cells 0..n_cells-1 (their
    keys ``ckey``)."""
    for c in range(n_cells):
        key = ckey[c]
        # the cell indices back from the packed key (21 bits per axis, offset by 2^20)
        cz = (key & ((1 << 21) - 1)) - (1 << 20)
        cy = ((key >> 21) & ((1 << 21) - 1)) - (1 << 20)
        cx = (key >> 42) - (1 << 20)
        _, h = _key(cx, cy, cz)
        s = -1 - _probe(tab, key, h)
        tab[s, 0] = key
        tab[s, 1] = c
        b = _bit(cx, cy, cz)
        bits[b >> 3] |= np.uint8(1 << (b & 7))


@numba.njit(cache=True)
def _prune(ckey: IntArray, cnt: NDArray[np.int32], sub: NDArray[np.int32], pts: FloatArray,
           ids: NDArray[np.int32], n_cells: int, centre: FloatArray, r2: float, voxel: float,
           nsub: int) -> tuple[int, int]:  # pragma: no cover - compiled  # fmt: skip
    """Drop the points farther than sqrt(r2) from ``centre`` in place: each cell keeps its remaining
    points in their order, emptied cells are removed and the others keep their order; returns (points
    dropped, cells left). The voxel counts ``sub`` are recounted from the points kept."""
    n_drop = 0
    w = 0
    for c in range(n_cells):
        kept = 0
        for j in range(cnt[c]):
            ex = pts[c, j, 0] - centre[0]
            ey = pts[c, j, 1] - centre[1]
            ez = pts[c, j, 2] - centre[2]
            if ex * ex + ey * ey + ez * ez <= r2:
                pts[w, kept, :] = pts[c, j, :]
                ids[w, kept] = ids[c, j]
                kept += 1
            else:
                n_drop += 1
        if kept == 0:
            continue
        ckey[w] = ckey[c]
        cnt[w] = kept
        sub[w, :] = 0
        for j in range(kept):
            vx = int(np.floor(pts[w, j, 0] / voxel))
            vy = int(np.floor(pts[w, j, 1] / voxel))
            vz = int(np.floor(pts[w, j, 2] / voxel))
            cx, cy, cz = vx // nsub, vy // nsub, vz // nsub
            sub[w, ((vx - cx * nsub) * nsub + (vy - cy * nsub)) * nsub + (vz - cz * nsub)] += 1
        w += 1
    return n_drop, w


@numba.njit(cache=True, inline="always")
def _knn_row(tab: IntArray, bits: NDArray[np.uint8], cnt: NDArray[np.int32], pts: FloatArray, qx: float, qy: float, qz: float,
             voxel: float, nsub: int, bi: IntArray, bd: FloatArray) -> None:  # pragma: no cover - compiled  # fmt: skip
    """The k = bi.size nearest stored points of the query (qx, qy, qz) among the 27 cells around
    it into bi (k,) (flat indices into ``pts.reshape(-1, 3)``) and bd (k,) (squared distances), ascending;
    -1 / inf where fewer were found."""
    k = bi.size
    C = pts.shape[1]
    cell = voxel * nsub
    for a in range(k):
        bi[a] = -1
        bd[a] = np.inf
    worst = np.inf  # bd[k - 1], kept in a register
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
        if bound >= worst:
            continue  # no point of that cell can be among the k nearest (exact pruning)
        b = _bit(cx + dx, cy + dy, cz + dz)
        if not (bits[b >> 3] >> (b & 7)) & 1:
            continue  # no such cell
        key, h = _key(cx + dx, cy + dy, cz + dz)
        s = _probe(tab, key, h)
        if s < 0:
            continue
        c = tab[s, 1]
        row = pts[c]  # the cell's points as a view: j below is non-negative, no index check
        for j in range(cnt[c]):
            ex = row[j, 0] - qx
            ey = row[j, 1] - qy
            ez = row[j, 2] - qz
            d = ex * ex + ey * ey + ez * ez
            if d >= worst:
                continue
            a = k - 1  # insertion into the sorted k best
            while a > 0 and bd[a - 1] > d:
                bd[a] = bd[a - 1]
                bi[a] = bi[a - 1]
                a -= 1
            bd[a] = d
            bi[a] = c * C + j
            worst = bd[k - 1]


@numba.njit(cache=True)
def _knn(tab: IntArray, bits: NDArray[np.uint8], cnt: NDArray[np.int32], pts: FloatArray, q: FloatArray, k: int,
         voxel: float, nsub: int) -> tuple[IntArray, FloatArray]:  # pragma: no cover - compiled  # fmt: skip
    """k nearest stored points of each query among the 27 cells around it: flat indices (M, k) into
    ``pts.reshape(-1, 3)`` and squared distances (M, k), ascending; -1 / inf where fewer were found."""
    M = q.shape[0]
    idx = np.empty((M, k), np.int64)
    dist = np.empty((M, k))
    bi = np.empty(k, np.int64)
    bd = np.empty(k)
    for m in range(M):
        _knn_row(tab, bits, cnt, pts, q[m, 0], q[m, 1], q[m, 2], voxel, nsub, bi, bd)
        idx[m] = bi
        dist[m] = bd
    return idx, dist


@numba.njit(cache=True)
def _knn_fit(tab: IntArray, bits: NDArray[np.uint8], cnt: NDArray[np.int32], pts: FloatArray,
             ids: NDArray[np.int32], q: FloatArray, p_in: FloatArray, k: int, voxel: float, nsub: int,
             lines: bool, max_d2: float, thr: float, gate: float) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int32]]:  # pragma: no cover - compiled  # fmt: skip
    """The search, the plane (``lines``: line) fit and the residual gate of each query in one pass,
    while its neighbours are in cache: the rows of ``p_in`` (M, 3) whose query ``q`` (M, 3) has a
    valid fit (:func:`imuslam.lio.residuals.fit_planes` / ``fit_lines`` on :func:`_knn`'s neighbours,
    ``thr`` their ``max_plane_res`` / ``min_ratio``) with |n . (q - c)| < ``gate``, with the fit's n
    and c (K, 3) and the tag in ``ids`` of the nearest neighbour (K,)."""
    M = q.shape[0]
    p_out = np.empty((M, 3))
    n_out = np.empty((M, 3))
    c_out = np.empty((M, 3))
    t_out = np.empty(M, np.int32)
    flat = pts.reshape(-1, 3)
    flat_ids = ids.reshape(-1)
    bi2 = np.empty((1, k), np.int64)  # the neighbours as row 0 of an (M, k) table, for the fits
    bd2 = np.empty((1, k))
    bi, bd = bi2[0], bd2[0]
    c = np.empty(3)
    d = np.empty(3)
    n = np.empty(3)
    K = 0
    for m in range(M):
        qx, qy, qz = q[m, 0], q[m, 1], q[m, 2]
        _knn_row(tab, bits, cnt, pts, qx, qy, qz, voxel, nsub, bi, bd)
        if lines:
            good = line_row(qx, qy, qz, bi2, bd2, flat, 0, max_d2, thr, c, d, n)
        else:
            good = plane_row(bi2, bd2, flat, 0, max_d2, thr, c, n)
        if not good:
            continue
        r = n[0] * (qx - c[0]) + n[1] * (qy - c[1]) + n[2] * (qz - c[2])
        if not abs(r) < gate:
            continue
        p_out[K, 0], p_out[K, 1], p_out[K, 2] = p_in[m, 0], p_in[m, 1], p_in[m, 2]
        n_out[K, 0], n_out[K, 1], n_out[K, 2] = n[0], n[1], n[2]
        c_out[K, 0], c_out[K, 1], c_out[K, 2] = c[0], c[1], c[2]
        t_out[K] = flat_ids[bi[0]]
        K += 1
    return p_out[:K], n_out[:K], c_out[:K], t_out[:K]


@numba.njit(cache=True)
def _gather(cnt: NDArray[np.int32], pts: FloatArray, ids: NDArray[np.int32], n_cells: int) -> tuple[FloatArray, NDArray[np.int32]]:  # pragma: no cover - compiled  # fmt: skip
    n = 0
    for c in range(n_cells):
        n += cnt[c]
    out = np.empty((n, 3))
    out_ids = np.empty(n, np.int32)
    i = 0
    for c in range(n_cells):
        for j in range(cnt[c]):
            out[i, :] = pts[c, j, :]
            out_ids[i] = ids[c, j]
            i += 1
    return out, out_ids


class IncrementalVoxelMap:
    """Points in the world frame, at most ``max_per_voxel`` per voxel of ``voxel_size`` m, hashed by
    cells of ``nsub`` voxels a side, within ``max_range`` m of the last pruning centre. Same interface
    as :class:`~imuslam.lio.voxelmap.VoxelMap` (``add``, ``prune``, ``transform``, ``knn``).

    The hash table holds only each cell's key and its row in the cell arrays, which are dense (the
    cells in use are rows 0..n_cells-1, in the order they were created): the points of a few
    thousand cells are not spread over a table kept at most half full, so a search touches less
    memory, and pruning compacts the rows in place without re-inserting the points."""

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
        self._ckey: IntArray
        self._cnt: NDArray[np.int32]
        self._sub: NDArray[np.int32]
        self._pts: FloatArray
        self._ids: NDArray[np.int32]
        self._bits = np.zeros(1 << (_BX + _BY + _BZ - 3), np.uint8)
        self._alloc_table(capacity)
        self._alloc_cells(max(capacity // 2, 8))

    def _alloc_table(self, capacity: int) -> None:
        cap = 1 << max(int(np.ceil(np.log2(max(capacity, 16)))), 4)
        # [key, cell row] side by side: a probe that finds its cell reads one cache line
        self._tab = np.full((cap, 2), _EMPTY, np.int64)

    def _alloc_cells(self, rows: int) -> None:
        """Cell arrays of ``rows`` rows, the rows in use copied over."""
        n, n3 = self.n_cells, self.nsub**3
        ckey, cnt = np.zeros(rows, np.int64), np.zeros(rows, np.int32)
        sub = np.zeros((rows, n3), np.int32)
        pts, ids = np.zeros((rows, self.slots, 3)), np.zeros((rows, self.slots), np.int32)
        if n:
            ckey[:n], cnt[:n], sub[:n] = self._ckey[:n], self._cnt[:n], self._sub[:n]
            pts[:n], ids[:n] = self._pts[:n], self._ids[:n]
        self._ckey, self._cnt, self._sub, self._pts, self._ids = ckey, cnt, sub, pts, ids

    def __len__(self) -> int:
        return self.n_points

    @property
    def points(self) -> FloatArray:
        """The stored points (N, 3), a copy."""
        return _gather(self._cnt, self._pts, self._ids, self.n_cells)[0]  # type: ignore[no-any-return]

    @property
    def ids(self) -> NDArray[np.int32]:
        """The tag of each slot of ``storage`` (what ``add`` was given with the point)."""
        return self._ids.reshape(-1)

    @property
    def storage(self) -> FloatArray:
        """The flat point storage that ``knn``'s indices index (a view)."""
        return self._pts.reshape(-1, 3)

    def _clear(self) -> None:
        self._tab.fill(_EMPTY)
        self._bits.fill(0)
        self.n_points = 0
        self.n_cells = 0

    def _add(self, p: FloatArray, ids: NDArray[np.int32]) -> int:
        need = self.n_cells + len(p)  # every point may open a cell
        if 2 * need > len(self._tab):  # keep the load factor below 1/2
            self._alloc_table(2 * need + 1)
            _rehash(self._tab, self._bits, self._ckey, self.n_cells)
        if need > len(self._cnt):
            self._alloc_cells(max(need, 2 * len(self._cnt)))
        n_ok, self.n_cells = _insert(self._tab, self._bits, self._ckey, self._cnt, self._sub, self._pts,
                                     self._ids, self.n_cells, p, ids, self.voxel_size, self.nsub,
                                     self.max_per_voxel)  # fmt: skip
        self.n_points += n_ok
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
        centre = np.ascontiguousarray(centre_w, dtype=np.float64)
        n_drop, n_cells = _prune(self._ckey, self._cnt, self._sub, self._pts, self._ids, self.n_cells,
                                 centre, self.max_range**2, self.voxel_size, self.nsub)  # fmt: skip
        if n_drop:
            self._tab.fill(_EMPTY)
            self._bits.fill(0)
            self.n_cells = int(n_cells)
            self.n_points -= int(n_drop)
            _rehash(self._tab, self._bits, self._ckey, self.n_cells)
        return int(n_drop)

    def transform(self, R: FloatArray, t: FloatArray) -> None:
        """Move every point by ``x -> R x + t`` (a change of world frame) and re-hash the cells."""
        p, ids = _gather(self._cnt, self._pts, self._ids, self.n_cells)
        self._clear()
        self._add(np.ascontiguousarray(p @ np.asarray(R).T + np.asarray(t)), ids)

    def knn(self, q_w: FloatArray, k: int) -> tuple[IntArray, FloatArray]:
        """k nearest map points (within the 27 cells) of each query (M, 3): indices into ``storage``
        (M, k) and squared distances (M, k)."""
        q = np.ascontiguousarray(q_w, dtype=np.float64)
        return _knn(
            self._tab, self._bits, self._cnt, self._pts, q, int(k), self.voxel_size, self.nsub
        )  # type: ignore[no-any-return]

    def knn_fit(self, q_w: FloatArray, p: FloatArray, k: int, lines: bool, max_d2: float, thr: float,
                gate: float) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int32]]:  # fmt: skip
        """Each query's (M, 3) plane (``lines``: line) through its k nearest map points, fitted in the
        same compiled pass as the search (as :func:`~imuslam.lio.residuals.fit_planes` / ``fit_lines``
        with ``max_d2`` and ``thr``, the plane thickness, m / the line's eigenvalue ratio), kept where
        the query is within ``gate`` m of it: the kept rows of ``p`` (M, 3) (the queries' points in
        another frame), the normals n and anchors c (K, 3), and the tag of each one's nearest map
        point (K,) (see ``add``)."""
        q = np.ascontiguousarray(q_w, dtype=np.float64)
        return _knn_fit(self._tab, self._bits, self._cnt, self._pts, self._ids, q,  # type: ignore[no-any-return]
                        np.ascontiguousarray(p, dtype=np.float64), int(k), self.voxel_size, self.nsub,
                        bool(lines), float(max_d2), float(thr), float(gate))  # fmt: skip

    @property
    def nbytes(self) -> int:
        return int(self._tab.nbytes + self._bits.nbytes + self._ckey.nbytes + self._cnt.nbytes
                   + self._sub.nbytes + self._pts.nbytes + self._ids.nbytes)  # fmt: skip
