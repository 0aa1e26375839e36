"""k-nearest-neighbour libraries on a LiDAR local map: build and query time (ms) per scan.

    PYTHONPATH=src python bench/knn.py [--scans 30]

Builds the street drive's local map from ground-truth poses (direct mode, 0.5 m voxels), then for each
library times building the k-d tree over the map and querying one scan's points (k = 5), with the same
queries for all, and checks the three return the same neighbours; then the incremental voxel-hash map
(``lio.ivox``, the default of ``imuslam lio``: nothing to build, a 27-cell search) on the same queries,
with the share of queries whose 5 neighbours equal the k-d tree's. Times are CPU time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from imuslam.lio.features import voxel_downsample
from imuslam.lio.ivox import IncrementalVoxelMap
from imuslam.lio.voxelmap import KnnIndex, VoxelMap
from imuslam.sim.drive import simulate_lidar_drive
from imuslam.threads import configure_process


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scans", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    d = simulate_lidar_drive("street", args.scans / 10.0, seed=3)
    vmap = VoxelMap(0.5, 1, 100.0)
    queries = np.zeros((0, 3))
    for s in d.scans:
        i = np.searchsorted(d.gt_t_ns, s.t_ns)
        R, p = d.gt_R_w_b[i], d.gt_p_w[i] + d.gt_R_w_b[i] @ d.T_i_l[:3, 3]
        pts = s.points_l.astype(float)
        pts = pts[voxel_downsample(pts, 0.5)]
        queries = pts @ R.T + p
        vmap.add(queries)
    print(f"map {len(vmap)} points, {len(queries)} queries, k = 5")
    print(f"{'library':12s} {'build ms':>9s} {'query ms':>9s} {'total ms':>9s}   (CPU time)")
    ref = None
    for lib in ("pykdtree", "small_gicp", "scipy"):
        tb, tq = [], []
        for _ in range(args.repeat):
            t0 = time.process_time()
            idx = KnnIndex(vmap.points, lib)  # type: ignore[arg-type]
            t1 = time.process_time()
            nbr, d2 = idx.query(queries, 5)
            t2 = time.process_time()
            tb.append(t1 - t0)
            tq.append(t2 - t1)
        if ref is None:
            ref = d2
        elif not np.allclose(np.sort(d2, axis=1), np.sort(ref, axis=1), atol=1e-9):
            raise SystemExit(f"{lib} returned other neighbours than pykdtree")
        b, q = 1e3 * np.median(tb), 1e3 * np.median(tq)
        print(f"{lib:12s} {b:9.2f} {q:9.2f} {b + q:9.2f}")
    # the incremental voxel-hash map: no build (points are hashed as they are inserted); exact where
    # the k nearest lie within one 1 m cell, approximate beyond
    iv = IncrementalVoxelMap(0.5, 1, 100.0)
    iv.add(vmap.points)
    iv.knn(queries[:10], 5)  # compile
    tq = []
    for _ in range(args.repeat):
        t1 = time.process_time()
        nbr, d2 = iv.knn(queries, 5)
        tq.append(time.process_time() - t1)
    assert ref is not None
    same = np.isclose(d2, ref, atol=1e-9).all(axis=1)
    q = 1e3 * np.median(tq)
    print(
        f"{'ivox':12s} {0.0:9.2f} {q:9.2f} {q:9.2f}   same 5 neighbours as the k-d tree for {same.mean():.1%} of queries"
    )


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
