"""A simulated 2D-mapping robot (seed 000): a differential drive with an RPLIDAR-like scanner, wheel
encoders and an IMU on a trajectory in a world, returned as the :class:`LaserLog` the 2D SLAM reads, with
the true pose of every scan."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces.imu import ImuLog
from imuslam.io.laserlog import LaserLog, clean_ranges
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.lidar import Lidar2dConfig, simulate_lidar2d_scan
from imuslam.sim.odometry import WheelConfig, simulate_wheels
from imuslam.sim.trajectory import EulerTrajectory
from imuslam.sim.world import World, room_8x8

FloatArray = NDArray[np.float64]
LIDAR_HEIGHT_B = 0.3  # the scanner above the body origin, m


@dataclass
class Robot2dSim:
    """The log (scans, wheel odometry at each scan, raw IMU) and the truth: truth_xy_yaw (N, 3) body pose
    at each scan's start, the world, the scanner's height above the floor (m)."""

    log: LaserLog
    truth_xy_yaw: FloatArray
    world: World
    scan_height: float


def planar(traj: EulerTrajectory, t_s: FloatArray) -> FloatArray:
    st = traj.state(t_s)
    return np.column_stack([st.p_w[:, :2], np.arctan2(st.R_w_b[:, 1, 0], st.R_w_b[:, 0, 0])])


def simulate_robot2d(
    traj: EulerTrajectory,
    duration_s: float,
    rng: np.random.Generator,
    imu_errors: ImuErrorSpec | None = None,
    world: World | None = None,
    lidar: Lidar2dConfig | None = None,
    wheels: WheelConfig | None = None,
    t0_ns: int = 1_700_000_000_000_000_000,
) -> Robot2dSim:
    """Simulate every sensor of the robot for ``duration_s``."""
    world = world or room_8x8()
    lc = lidar or Lidar2dConfig()
    R_b_l, p_b_l = np.eye(3), np.array([0.0, 0.0, LIDAR_HEIGHT_B])

    def pose(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        st = traj.state(t)
        return st.R_w_b @ R_b_l, st.p_w + st.R_w_b @ p_b_l

    n = int(duration_s * lc.rate_hz)
    scans = [simulate_lidar2d_scan(world, pose, k / lc.rate_hz, lc, rng) for k in range(n)]
    t_scan = np.arange(n) / lc.rate_hz
    wo = simulate_wheels(traj, duration_s, rng, wheels or WheelConfig())
    odo = np.column_stack([np.interp(t_scan, wo.t_s, wo.pose_xy_yaw[:, i]) for i in range(3)])
    imu, _ = simulate_imu(
        traj, duration_s, rng, imu_errors or ImuErrorSpec.bwt901cl(), 100.0, t0_ns=t0_ns
    )
    warnings: dict[str, int] = {}
    ranges = clean_ranges(
        np.array([s.ranges for s in scans]), lc.min_range, lc.max_range + 1e-6, warnings
    )
    t_ns = t0_ns + np.round(t_scan * 1e9).astype(np.int64)
    log = LaserLog(
        t_ns, ranges, scans[0].angle_min, scans[0].angle_increment, lc.min_range, lc.max_range, odo,
        np.zeros(3), imu, "simulated robot", warnings, scans[0].time_increment,
    )  # fmt: skip
    height = float(traj.state(np.array([0.0])).p_w[0, 2] + LIDAR_HEIGHT_B)
    return Robot2dSim(log, planar(traj, t_scan), world, height)


def with_imu(log: LaserLog, imu: ImuLog | None) -> LaserLog:
    """A new log with the same scans and another IMU (or none); to run the SLAM with another IMU, pass
    it as the pipeline's ``imu=`` instead."""
    return replace(log.slice(0, len(log)), imu_log=imu)
