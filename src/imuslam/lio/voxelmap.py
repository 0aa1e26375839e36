"""A voxel-hashed local map with k-nearest-neighbour search, bounded by distance pruning.

Points are kept at most ``max_per_voxel`` per voxel (KISS-ICP's voxel hash map, Vizzo et al. 2023,
Sec. III-C); points farther than ``max_range`` from the sensor are dropped, so the map and its memory stay
bounded however long the drive. The k-nearest-neighbour search is a k-d tree from a maintained library,
rebuilt after each insertion (``bench/knn.py`` measured pykdtree, small_gicp and scipy on these maps).
"""

from __future__ import annotations

from typing import Any, Literal

import numba
import numpy as np
from numba import types
from numba.typed import Dict
from numpy.typing import NDArray

from imuslam.lio.features import voxel_keys

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
KnnBackend = Literal["pykdtree", "small_gicp", "scipy"]


@numba.njit(cache=True)
def _admit(keys: IntArray, counts: Dict, cap: int) -> NDArray[np.bool_]:  # type: ignore[type-arg]  # pragma: no cover - compiled  # fmt: skip
    ok = np.zeros(keys.size, dtype=np.bool_)
    for j in range(keys.size):
        c = counts.get(keys[j], 0)
        if c < cap:
            counts[keys[j]] = c + 1
            ok[j] = True
    return ok


def _new_counts() -> Dict:  # type: ignore[type-arg]
    return Dict.empty(key_type=types.int64, value_type=types.int64)


class KnnIndex:
    """k nearest neighbours of query points among fixed points, through one of three libraries."""

    def __init__(self, points: FloatArray, backend: KnnBackend = "pykdtree") -> None:
        self.backend = backend
        self.n = len(points)
        pts = np.ascontiguousarray(points, dtype=np.float64)
        self._tree: Any
        if backend == "pykdtree":
            from pykdtree.kdtree import KDTree

            self._tree = KDTree(pts, leafsize=16)
        elif backend == "small_gicp":
            import small_gicp

            self._tree = small_gicp.KdTree(pts, num_threads=1)
        elif backend == "scipy":
            from scipy.spatial import cKDTree

            self._tree = cKDTree(pts, leafsize=16)
        else:
            raise ValueError(f"unknown kNN backend {backend!r}")

    def query(self, q: FloatArray, k: int) -> tuple[IntArray, FloatArray]:
        """Indices (M, k) int64 and squared distances (M, k) of the k nearest points (index -1 and inf
        where there are fewer than k points)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        if self.n == 0:
            return np.full((len(q), k), -1, np.int64), np.full((len(q), k), np.inf)
        if self.backend == "pykdtree":
            d, i = self._tree.query(q, k=k)
            d, i = d.reshape(len(q), k), i.reshape(len(q), k).astype(np.int64)
            bad = i >= self.n
            i[bad] = -1
            d = np.where(bad, np.inf, d * d)
            return i, d
        if self.backend == "small_gicp":
            i, d = self._tree.batch_knn_search(q, k, num_threads=1)
            i = np.asarray(i).astype(np.int64).reshape(len(q), k)
            d = np.asarray(d).reshape(len(q), k)
            bad = (i < 0) | (i >= self.n)
            i[bad] = -1
            return i, np.where(bad, np.inf, d)
        d, i = self._tree.query(q, k=k)
        d, i = np.asarray(d).reshape(len(q), k), np.asarray(i).reshape(len(q), k).astype(np.int64)
        bad = i >= self.n
        i[bad] = -1
        return i, np.where(bad, np.inf, d * d)


class VoxelMap:
    """Points in the world frame, at most ``max_per_voxel`` per voxel of ``voxel_size`` m, within
    ``max_range`` m of the last pruning centre."""

    def __init__(
        self,
        voxel_size: float = 0.5,
        max_per_voxel: int = 1,
        max_range: float = 100.0,
        backend: KnnBackend = "pykdtree",
    ) -> None:
        self.voxel_size = voxel_size
        self.max_per_voxel = max_per_voxel
        self.max_range = max_range
        self.backend: KnnBackend = backend
        self.points = np.zeros((0, 3))
        self.ids = np.zeros(0, np.int32)  # the tag of each point (``add``)
        self._counts = _new_counts()
        self._index: KnnIndex | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def add(self, points_w: FloatArray, tag: int = -1) -> int:
        """Insert points (N, 3) where their voxel has room, tagged ``tag``; returns how many were kept."""
        if len(points_w) == 0:
            return 0
        ok = _admit(voxel_keys(points_w, self.voxel_size), self._counts, self.max_per_voxel)
        if ok.any():
            self.points = np.concatenate([self.points, np.asarray(points_w, dtype=float)[ok]])
            self.ids = np.concatenate([self.ids, np.full(int(ok.sum()), tag, np.int32)])
            self._index = None
        return int(ok.sum())

    def prune(self, centre_w: FloatArray) -> int:
        """Drop points farther than ``max_range`` from ``centre_w`` (3,); returns how many were dropped."""
        d2 = np.sum((self.points - np.asarray(centre_w)[None]) ** 2, axis=1)
        keep = d2 <= self.max_range**2
        n_drop = int(len(keep) - keep.sum())
        if n_drop:
            self.points = self.points[keep]
            self.ids = self.ids[keep]
            self._counts = _new_counts()
            _admit(voxel_keys(self.points, self.voxel_size), self._counts, 1 << 30)
            self._index = None
        return n_drop

    def transform(self, R: FloatArray, t: FloatArray) -> None:
        """Move every point by ``x -> R x + t`` (a change of world frame) and re-hash the voxels."""
        self.points = self.points @ np.asarray(R).T + np.asarray(t)
        self._counts = _new_counts()
        _admit(voxel_keys(self.points, self.voxel_size), self._counts, 1 << 30)
        self._index = None

    def knn(self, q_w: FloatArray, k: int) -> tuple[IntArray, FloatArray]:
        """k nearest map points of each query (M, 3): indices (M, k) and squared distances (M, k)."""
        if self._index is None:
            self._index = KnnIndex(self.points, self.backend)
        return self._index.query(q_w, k)

    @property
    def storage(self) -> FloatArray:
        """The points that ``knn``'s indices index."""
        return self.points

    @property
    def nbytes(self) -> int:
        return int(self.points.nbytes + self.ids.nbytes) + 16 * len(self._counts)
