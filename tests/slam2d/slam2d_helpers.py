"""What the 2D SLAM tests share: scans simulated in the 8 m room, maps built from them, CARMEN lines."""

from __future__ import annotations

import numpy as np

from imuslam.sim.lidar import Lidar2dConfig, simulate_lidar2d_scan
from imuslam.sim.world import room_8x8
from imuslam.slam2d import pose2
from imuslam.slam2d.grid import GridParams, ProbabilityGrid

RES = 0.05


def _scan_at(pose_xy_yaw: np.ndarray, rng: np.random.Generator, noise: float = 0.01) -> np.ndarray:
    """Points (P, 2) in the body frame of a simulated RPLIDAR scan of the 8 m room at a static pose."""
    world = room_8x8()
    c, s = np.cos(pose_xy_yaw[2]), np.sin(pose_xy_yaw[2])
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    p = np.array([pose_xy_yaw[0], pose_xy_yaw[1], 0.45])

    def pose_fn(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.broadcast_to(R, (len(t), 3, 3)).copy(), np.broadcast_to(p, (len(t), 3)).copy()

    scan = simulate_lidar2d_scan(world, pose_fn, 0.0, Lidar2dConfig(range_noise_std=noise), rng)
    ang = scan.angle_min + np.arange(len(scan.ranges)) * scan.angle_increment
    ok = np.isfinite(scan.ranges)
    r = scan.ranges[ok].astype(float)
    return np.column_stack([r * np.cos(ang[ok]), r * np.sin(ang[ok])])


def _map_from(poses: list[np.ndarray], rng: np.random.Generator) -> ProbabilityGrid:
    g = ProbabilityGrid(GridParams(resolution=RES), np.zeros(2), 5.0)
    for P in poses:
        for _ in range(3):
            g.insert(P[:2], pose2.act(P, _scan_at(P, rng)))
    return g


def _flaser(t: float, ranges: list[str], odom: tuple[float, float, float]) -> str:
    x, y, th = odom
    return f"FLASER {len(ranges)} {' '.join(ranges)} {x} {y} {th} {x} {y} {th} {t:.3f} h {t:.3f}\n"


def _corridor(rng: np.random.Generator) -> tuple[ProbabilityGrid, np.ndarray]:
    """A submap of a straight corridor (walls at y = +-1 m along x in [-10, 10] m) and a scan of it
    (points within 4 m along the walls) taken at the origin."""
    g = ProbabilityGrid(GridParams(resolution=RES), np.zeros(2), 12.0)
    wall_x = np.arange(-10.0, 10.0, 0.02)
    for _ in range(3):
        for y in (-1.0, 1.0):
            for x0_ in np.arange(-8.0, 8.1, 2.0):
                near = np.abs(wall_x - x0_) < 4.0
                ends = np.column_stack([wall_x[near], np.full(near.sum(), y)])
                g.insert(np.array([x0_, 0.0]), ends + rng.normal(0, 0.01, ends.shape))
    near = np.abs(wall_x) < 4.0
    scan = np.concatenate(
        [np.column_stack([wall_x[near], np.full(near.sum(), y)]) for y in (-1, 1)]
    )
    return g, scan[::2] + rng.normal(0, 0.01, scan[::2].shape)
