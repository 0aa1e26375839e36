"""LiDAR-only registration on real scans: BALM's real-world scans against their given poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imuslam.geometry import exp, log
from imuslam.io.pointcloud import pcd_points
from imuslam.lio.features import voxel_downsample
from imuslam.lio.lidar_only import gauss_newton
from imuslam.lio.matcher import LocalMap


def test_balm_consecutive_registration(shared_data: Path) -> None:
    """Each scan registered against the previous one (placed at its given pose), from a prior 0.3 m and
    2 deg off the given pose: the result must come back to the given pose. The poses are BALM's bundle
    adjustment (mm level); the scans hold 73k points with cm-level range noise, so a few mm and about
    0.1 deg are what registration can agree to; the prior is 30x / 10x farther."""
    d = shared_data / "balm_realworld_scans"
    P = np.loadtxt(d / "alidarPose.csv", delimiter=",", usecols=range(4)).reshape(-1, 4, 4)[:10]
    rng = np.random.default_rng(0)
    et, er = [], []
    for i in range(0, 9, 2):  # five pairs keep the test short
        a, b = pcd_points(d / f"full{i}.pcd"), pcd_points(d / f"full{i + 1}.pcd")
        m = LocalMap(0.2, 200.0, 1)
        a = a[voxel_downsample(a, 0.2)]
        m.surf.add(a @ P[i, :3, :3].T + P[i, :3, 3])
        src = b[voxel_downsample(b, 0.5)]
        u = rng.normal(size=3)
        w = rng.normal(size=3)
        R0 = P[i + 1, :3, :3] @ exp(np.deg2rad(2.0) * w / np.linalg.norm(w))
        p0 = P[i + 1, :3, 3] + 0.3 * u / np.linalg.norm(u)
        reg = gauss_newton(m, src, np.zeros((0, 3)), R0, p0, 30, 1e-6, 0.1)
        et.append(np.linalg.norm(reg.p_w - P[i + 1, :3, 3]))
        er.append(np.degrees(np.linalg.norm(log(P[i + 1, :3, :3].T @ reg.R_w_s))))
    print("translation error per pair, mm:", np.round(np.array(et) * 1e3, 1))
    print("rotation error per pair, deg:", np.round(er, 3))
    assert max(et) < 0.015
    assert max(er) < 0.2
