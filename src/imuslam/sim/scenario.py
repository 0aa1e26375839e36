"""Ready-made simulated robots with ground truth, written as a ROS 2 MCAP bag, TUM truth and an .npz.

room      seed 000: differential-drive robot in the 8 m x 8 m room; IMU 100 Hz (BWT901CL-class errors),
          RPLIDAR-A2-like 2D scans 10 Hz, wheel encoders 50 Hz
street    seed 001: car on a street loop around a block; IMU 200 Hz (optionally on a 10 Hz rotating
          platform), VLP-16 10 Hz, RTK 10 Hz
corridor  robot in a long corridor; IMU 100 Hz, 2D scans, wheel encoders (degenerate for scan matching)
handheld  device in the room; IMU 200 Hz, stereo feature observations 20 Hz
gimbal    the IMU on a 2-axis gimbal turned through 40 static poses (calibration log; its length is
          set by the poses, about 300 s, not by the duration)
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from imuslam.geometry import quat_from_matrix
from imuslam.io.atomic import write_atomic
from imuslam.sim import export
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.lidar import (
    Lidar2dConfig,
    Lidar3dConfig,
    simulate_lidar2d_scan,
    simulate_lidar3d_scan,
)
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg
from imuslam.sim.odometry import WheelConfig, simulate_rtk, simulate_wheels
from imuslam.sim.stereo import R_B_C_FORWARD, StereoConfig, observe
from imuslam.sim.trajectory import (
    CarLoop,
    CorridorDrive,
    DiffDriveFigureEight,
    EulerTrajectory,
    Handheld,
)
from imuslam.sim.world import World, corridor, room_8x8, sample_surface_points, urban_block

FloatArray = NDArray[np.float64]
ScenarioName = Literal["room", "street", "corridor", "handheld", "gimbal"]
SCENARIOS = ("room", "street", "corridor", "handheld", "gimbal")
T0_NS = 1_700_000_000_000_000_000  # stamps start at a plausible epoch


@dataclass
class SimulationResult:
    """What a scenario produced (paths) and counts per topic."""

    out_dir: Path
    files: list[Path]
    counts: dict[str, int] = field(default_factory=dict)


def _pose_fn(traj: EulerTrajectory, R_b_s: FloatArray, p_b_s: FloatArray):  # type: ignore[no-untyped-def]
    def pose(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        st = traj.state(t)
        return st.R_w_b @ R_b_s, st.p_w + st.R_w_b @ p_b_s

    return pose


def run_scenario(
    name: str,
    duration_s: float,
    out_dir: str | Path,
    seed: int = 0,
    rotating_platform: bool = False,
    progress: bool = True,
) -> SimulationResult:
    """Simulate ``name`` for ``duration_s`` seconds into ``out_dir`` (bag/, ground_truth.tum, sim.npz)."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario '{name}'; expected one of {', '.join(SCENARIOS)}")
    if not duration_s > 0:
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    out = Path(out_dir)
    rng = np.random.default_rng(seed)
    arrays: dict[str, Any] = {}
    streams: list[Iterator[export.Message]] = []
    t0 = T0_NS
    world: World | None = None

    if name == "gimbal":
        sim = simulate_multipose(sphere_plan_deg(40, rng), rng)
        log = sim.log
        log.t_ns = log.t_ns + t0
        streams.append(export.imu_messages(log))
        arrays.update(imu_t_ns=log.t_ns, imu_accel=log.accel, imu_gyro=log.gyro, truth_angles_deg=sim.truth.angles_deg,
                      truth_static=sim.truth.static, truth_accel_i=sim.truth.accel_i, truth_omega_i=sim.truth.omega_i)  # fmt: skip
        gt_t, gt_R, gt_p = sim.truth.t_s, sim.truth.R_w_i, np.zeros((len(sim.truth.t_s), 3))
    else:
        traj: EulerTrajectory
        if name == "room":
            traj, world, imu_rate = DiffDriveFigureEight(), room_8x8(), 100.0
        elif name == "street":
            traj, world, imu_rate = CarLoop(), urban_block(), 200.0
        elif name == "corridor":
            traj, world, imu_rate = CorridorDrive(), corridor(), 100.0
        else:
            traj, world, imu_rate = Handheld(), room_8x8(), 200.0
        log, truth = simulate_imu(
            traj, duration_s, rng, ImuErrorSpec.bwt901cl(), imu_rate, t0_ns=t0,
            rotating_platform_hz=10.0 if (rotating_platform and name == "street") else 0.0,
        )  # fmt: skip
        streams.append(export.imu_messages(log))
        arrays.update(imu_t_ns=log.t_ns, imu_accel=log.accel, imu_gyro=log.gyro, truth_accel_i=truth.accel_i,
                      truth_omega_i=truth.omega_i, truth_accel_bias=truth.accel_bias, truth_gyro_bias=truth.gyro_bias,
                      truth_R_b_i=truth.R_b_i)  # fmt: skip
        gt_t = np.arange(0.0, duration_s + 1e-9, 0.01)
        st = traj.state(gt_t)
        gt_R, gt_p = st.R_w_b, st.p_w
        if name in ("room", "corridor"):
            wc = WheelConfig()
            wo = simulate_wheels(traj, duration_s, rng, wc)
            wt = t0 + wo.t_ns
            streams.append(export.odometry_messages(wt, wo.pose_xy_yaw))
            arrays.update(wheel_t_ns=wt, wheel_ticks=wo.ticks, wheel_odom_xy_yaw=wo.pose_xy_yaw)
            cfg2 = Lidar2dConfig()
            pose2 = _pose_fn(traj, np.eye(3), np.array([0.0, 0.0, 0.3]))
            n2 = int(duration_s * cfg2.rate_hz)
            scans = [
                simulate_lidar2d_scan(world, pose2, k / cfg2.rate_hz, cfg2, rng) for k in range(n2)
            ]
            for s in scans:
                s.t0_ns += t0
            streams.append(iter([(s.t0_ns, "/scan", export.laserscan_message(s)) for s in scans]))
            arrays.update(scan_t_ns=np.array([s.t0_ns for s in scans]), scan_ranges=np.array([s.ranges for s in scans]),
                          scan_angle_min=scans[0].angle_min if scans else 0.0, scan_angle_increment=scans[0].angle_increment if scans else 0.0)  # fmt: skip
        if name == "street":
            rt, rp = simulate_rtk(traj, duration_s, rng)
            rt_ns = t0 + np.round(rt * 1e9).astype(np.int64)
            streams.append(export.point_messages(rt_ns, rp, "/rtk"))
            arrays.update(rtk_t_ns=rt_ns, rtk_p_w=rp)
            cfg3 = Lidar3dConfig()
            pose3 = _pose_fn(traj, np.eye(3), np.array([0.0, 0.0, 0.2]))
            n3 = int(duration_s * cfg3.rate_hz)

            def lidar_stream() -> Iterator[export.Message]:
                for k in tqdm(range(n3), desc="3D LiDAR", unit="scan", disable=not progress):
                    scan = simulate_lidar3d_scan(world, pose3, k / cfg3.rate_hz, cfg3, rng)  # type: ignore[arg-type]
                    scan.t0_ns += t0
                    t, msg = export.pointcloud_message(scan)
                    yield t, "/points", msg

            streams.append(lidar_stream())
        if name == "handheld":
            sc = StereoConfig()
            lm, _ = sample_surface_points(world, 4000, rng)
            ft = np.arange(0.0, duration_s + 1e-9, 0.05)
            sst = traj.state(ft)
            frames = [
                observe(
                    lm,
                    sst.R_w_b[i] @ R_B_C_FORWARD,
                    sst.p_w[i],
                    world,
                    sc,
                    rng,
                    int(t0 + round(ft[i] * 1e9)),
                )
                for i in range(len(ft))
            ]
            arrays.update(
                landmarks_w=lm, stereo_frame_t_ns=np.array([f.t_ns for f in frames]),
                stereo_frame=np.concatenate([np.full(len(f.ids), i) for i, f in enumerate(frames)]),
                stereo_ids=np.concatenate([f.ids for f in frames]), stereo_uv_left=np.concatenate([f.uv_left for f in frames]),
                stereo_uv_right=np.concatenate([f.uv_right for f in frames]), R_b_c=R_B_C_FORWARD,
                stereo_intrinsics=np.array([sc.fx, sc.fy, sc.cx, sc.cy, sc.baseline]),
            )  # fmt: skip
    gt_ns = t0 + np.round(gt_t * 1e9).astype(np.int64)
    q = quat_from_matrix(gt_R)
    streams.append(export.pose_messages(gt_ns, gt_p, q, "/ground_truth"))
    arrays.update(gt_t_ns=gt_ns, gt_p_w=gt_p, gt_R_w_b=gt_R)
    counts: dict[str, int] = {}

    def count(_: int) -> None:
        counts["messages"] = counts.get("messages", 0) + 1

    export.write_bag(out / "bag", streams, count)
    rows = np.column_stack([gt_ns * 1e-9, gt_p, q[:, 1:], q[:, :1]])
    write_atomic(out / "ground_truth.tum", "# t x y z qx qy qz qw\n" + "\n".join(
        f"{r[0]:.9f} " + " ".join(f"{v:.9g}" for v in r[1:]) for r in rows) + "\n")  # fmt: skip
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    write_atomic(out / "sim.npz", buf.getvalue())
    meta = {"scenario": name, "duration_s": duration_s, "seed": seed, "rotating_platform": rotating_platform,
            "t0_ns": t0, "world": world.name if world is not None else None, "topics": export.MSGTYPE}  # fmt: skip
    write_atomic(out / "scenario.json", json.dumps(meta, indent=2) + "\n")
    return SimulationResult(
        out, [out / "bag", out / "ground_truth.tum", out / "sim.npz", out / "scenario.json"], counts
    )
