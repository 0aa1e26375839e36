"""Scan-to-map association: the current scan's points (IMU frame) against the local map's planes and
lines, giving the stacked residuals and Jacobians every registration path (the filter's measurement and
the LiDAR-only Gauss-Newton) uses; and the insertion of a registered scan into the map.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.lio.ivox import IncrementalVoxelMap
from imuslam.lio.residuals import fit_lines, fit_planes, point_to_plane_system
from imuslam.lio.voxelmap import KnnBackend, VoxelMap

FloatArray = NDArray[np.float64]


@dataclass
class MatchParams:
    """k: neighbours per plane / line; max_nbr_dist: farthest neighbour, m; max_plane_res: plane
    thickness, m; line_ratio: eigenvalue ratio of a line; max_residual: gate on |r| before weighting, m
    (``MapConfig.max_residual``); coarse_residual: the wider gate of a registration's first pass from a
    poor prediction (``lidar_only.gauss_newton``), m; huber: robust kernel width, m."""

    k: int = 5
    max_nbr_dist: float = 2.0
    max_plane_res: float = 0.1
    line_ratio: float = 3.0
    max_residual: float = 0.1
    coarse_residual: float = 1.0
    huber: float = 0.2


@dataclass
class Correspondences:
    """p_i (M, 3) scan points in the IMU frame; n (M, 3) unit directions; c (M, 3) anchors (world);
    kind (M,) 0 plane, 1 line; tag (M,) the tag of the nearest map point (the scan that inserted it,
    -1 when unknown)."""

    p_i: FloatArray
    n: FloatArray
    c: FloatArray
    kind: NDArray[np.int8]
    tag: NDArray[np.int32]

    def __len__(self) -> int:
        return int(self.p_i.shape[0])

    def subset(self, keep: NDArray[np.bool_]) -> Correspondences:
        """The rows where ``keep`` is true."""
        return Correspondences(
            self.p_i[keep], self.n[keep], self.c[keep], self.kind[keep], self.tag[keep]
        )

    def system(self, R_w_i: FloatArray, p_w: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Residuals (M,) m and Jacobians (M, 6) w.r.t. [dp, dtheta] at the pose (R_w_i, p_w)."""
        return point_to_plane_system(
            self.p_i, self.n, self.c, np.ascontiguousarray(R_w_i), np.ascontiguousarray(p_w),
            np.ones(len(self.p_i)),
        )  # fmt: skip


class LocalMap:
    """Planes (and, in feature mode, lines) of the surroundings in the world frame."""

    def __init__(
        self,
        voxel_size: float = 0.5,
        max_range: float = 100.0,
        max_per_voxel: int = 1,
        backend: KnnBackend | Literal["ivox"] = "ivox",
        params: MatchParams | None = None,
    ) -> None:
        self.surf: VoxelMap | IncrementalVoxelMap
        self.edge: VoxelMap | IncrementalVoxelMap
        if backend == "ivox":
            # edges are sparse: cells of 4 voxels a side so the 27 cells reach 1 m around a query
            self.surf = IncrementalVoxelMap(voxel_size, max_per_voxel, max_range, nsub=2)
            # at most 16 of a cell's 64 voxels: edge points lie on lines (a line crosses at most 10
            # voxels of a cell), and 64 slots a cell made the table 4x larger, mostly empty
            self.edge = IncrementalVoxelMap(voxel_size * 0.5, max_per_voxel, max_range, nsub=4,
                                            slots=16 * max_per_voxel)  # fmt: skip
        else:
            self.surf = VoxelMap(voxel_size, max_per_voxel, max_range, backend)
            self.edge = VoxelMap(voxel_size * 0.5, max_per_voxel, max_range, backend)
        self.params = params or MatchParams()

    def __len__(self) -> int:
        return len(self.surf) + len(self.edge)

    def associate(
        self, surf_i: FloatArray, edge_i: FloatArray, R_w_i: FloatArray, p_w: FloatArray,
        max_residual: float | None = None,
    ) -> Correspondences:  # fmt: skip
        """Planes for ``surf_i`` (N, 3) and lines for ``edge_i`` (E, 3), IMU-frame points, at the pose;
        rows whose |residual| exceeds ``max_residual`` (default ``params.max_residual``) are dropped."""
        pr = self.params
        gate = pr.max_residual if max_residual is None else max_residual
        out_p, out_n, out_c, out_k, out_t = [], [], [], [], []
        for pts, vmap, kind in ((surf_i, self.surf, 0), (edge_i, self.edge, 1)):
            if len(pts) == 0 or len(vmap) < pr.k:
                continue
            q = pts @ R_w_i.T + p_w
            thr = pr.max_plane_res if kind == 0 else pr.line_ratio
            if isinstance(vmap, IncrementalVoxelMap):  # search, fit and gate in one compiled pass
                p_ok, n, c, tag = vmap.knn_fit(
                    q, pts, pr.k, kind == 1, pr.max_nbr_dist**2, thr, gate
                )
            else:
                nbr, d2 = vmap.knn(q, pr.k)
                fit = fit_planes if kind == 0 else fit_lines
                n, c, ok = fit(q, nbr, d2, vmap.storage, pr.max_nbr_dist**2, thr)
                ok &= np.abs(np.einsum("mk,mk->m", n, q - c)) < gate
                p_ok, n, c, tag = pts[ok], n[ok], c[ok], vmap.ids[nbr[ok, 0]]
            out_p.append(p_ok)
            out_n.append(n)
            out_c.append(c)
            out_k.append(np.full(len(p_ok), kind, np.int8))
            out_t.append(tag)
        if not out_p:
            z = np.zeros((0, 3))
            return Correspondences(z, z, z, np.zeros(0, np.int8), np.zeros(0, np.int32))
        if len(out_p) == 1:  # one kind (the direct front end): no copies
            return Correspondences(out_p[0], out_n[0], out_c[0], out_k[0], out_t[0])
        return Correspondences(
            np.concatenate(out_p),
            np.concatenate(out_n),
            np.concatenate(out_c),
            np.concatenate(out_k),
            np.concatenate(out_t),
        )

    def insert(
        self, surf_i: FloatArray, edge_i: FloatArray, R_w_i: FloatArray, p_w: FloatArray,
        tag: int = -1,
    ) -> None:  # fmt: skip
        """Add the registered scan's points, tagged ``tag`` (see ``Correspondences.tag``)."""
        self.surf.add(surf_i @ R_w_i.T + p_w, tag)
        if len(edge_i):
            self.edge.add(edge_i @ R_w_i.T + p_w, tag)

    def transform(self, R: FloatArray, t: FloatArray) -> None:
        """Express the map in another world frame: ``x -> R x + t``."""
        self.surf.transform(R, t)
        self.edge.transform(R, t)

    def prune(self, centre_w: FloatArray) -> None:
        self.surf.prune(centre_w)
        self.edge.prune(centre_w)

    @property
    def nbytes(self) -> int:
        return self.surf.nbytes + self.edge.nbytes


def huber_weights(r: FloatArray, delta: float) -> FloatArray:
    """IRLS weights (M,) of the Huber kernel of width ``delta`` (1 inside, delta/|r| outside)."""
    a = np.abs(r)
    return np.where(a <= delta, 1.0, delta / np.maximum(a, 1e-12))
