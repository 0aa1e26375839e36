"""Seed 000's validation experiment in numbers: the robot driven round the 8 m x 8 m room counter-clockwise,
turned at A, then clockwise back to A; 2D SLAM with {raw, calibrated, ideal} IMU x {wheel odometry on, off}.

The IMU is a simulated BWT901CL with seed 000's table-2 errors (``ImuErrorSpec.bwt901cl``: misalignment,
scale, bias, noise, bias random walk). "calibrated": a 40-pose gimbal log of the same IMU is simulated and
calibrated by ``imuslam.imu.calibrate`` (Tedaldi 2014), the correction applied to the drive's IMU.
"ideal": the same white noise, no systematic error. Scores: ATE (SE(2)-aligned), the loop error (the
estimated displacement between the start and the end at A, against the true one), and the map against the
simulator's true walls: the fraction of occupied cells farther than 5 cm from any surface, and the wall
thickness (5-95 % spread of the occupied cells across each of the four walls).

    python bench/seed000.py             # both matcher set-ups, prints the tables
    python bench/seed000.py --quick     # our default matcher only
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from imuslam.eval.mapquality import map_quality, occupied_centres
from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.io.laserlog import LaserLog
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg
from imuslam.sim.robot2d import simulate_robot2d, with_imu
from imuslam.sim.trajectory import SquareLoopCcwCw
from imuslam.slam2d.config import Slam2dConfig
from imuslam.slam2d.pipeline import render_map, run_slam2d
from imuslam.threads import configure_process


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--png", default="", help="write the maps of the raw / calibrated runs here (PNG)"
    )
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    traj = SquareLoopCcwCw()
    dur = traj.duration_s
    spec = ImuErrorSpec.bwt901cl()
    sim = simulate_robot2d(traj, dur, rng, spec)
    raw = sim.log.imu()
    assert raw is not None
    ideal_spec = ImuErrorSpec(accel_density=spec.accel_density, gyro_density=spec.gyro_density)
    ideal, _ = simulate_imu(
        traj, dur, np.random.default_rng(args.seed + 1), ideal_spec, 100.0, t0_ns=int(raw.t_ns[0])
    )
    gim = simulate_multipose(sphere_plan_deg(40, rng), rng)
    cal = calibrate(gim.log, CalibrationConfig(g=gim.truth.g)).calibration
    imus = {"raw IMU": raw, "calibrated IMU": cal.correct(raw), "ideal IMU": ideal}
    setups = {"default (correlative search + refinement)": Slam2dConfig()}
    if not args.quick:
        cart = Slam2dConfig()
        cart.matcher.use_correlative = (
            False  # Cartographer 2D's default: refinement from the prediction only
        )
        cart.matcher.translation_weight = 10.0  # Cartographer 2D's default weights
        cart.matcher.rotation_weight = 40.0
        setups["Cartographer 2D default (no online correlative search)"] = cart

    def occupied(log_: LaserLog, cfg: Slam2dConfig) -> Callable[[np.ndarray], np.ndarray]:
        def f(poses_w: np.ndarray) -> np.ndarray:
            g = render_map(log_, poses_w, cfg)
            return occupied_centres(g.prob, g.known(), g.x0, g.y0, g.params.resolution)

        return f

    tq = map_quality(
        sim.truth_xy_yaw,
        sim.truth_xy_yaw,
        occupied(sim.log, Slam2dConfig()),
        sim.world,
        sim.scan_height,
    )
    print(f"seed 000 drive: {len(sim.log)} scans, {dur:.0f} s, path "
          f"{np.sum(np.hypot(*np.diff(sim.truth_xy_yaw[:, :2], axis=0).T)):.1f} m; map from the true poses: "
          f"{100 * tq.frac_far:.2f} % of occupied cells > 5 cm from a wall, wall thickness {100 * tq.wall_thickness_m:.1f} cm")  # fmt: skip
    for sname, base in setups.items():
        print(f"\n### {sname}\n")
        print("| IMU | wheel odometry | ATE RMSE [cm] | loop error [cm] | loop error [deg] | occupied > 5 cm from wall [%] | wall thickness [cm] | time [s] |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|")
        for iname, imu in imus.items():
            for odo in (True, False):
                cfg = base.model_copy(deep=True)
                cfg.use_odometry = odo
                log_ = with_imu(sim.log, imu)
                t0 = time.perf_counter()
                res = run_slam2d(log_, cfg)
                el = time.perf_counter() - t0
                q = map_quality(
                    res.pose_xy_yaw,
                    sim.truth_xy_yaw,
                    occupied(log_, cfg),
                    sim.world,
                    sim.scan_height,
                )
                print(f"| {iname} | {'on' if odo else 'off'} | {100 * q.ate_rmse_m:.2f} | {100 * q.loop_error_m:.2f} | "
                      f"{q.loop_error_deg:.2f} | {100 * q.frac_far:.2f} | {100 * q.wall_thickness_m:.1f} | {el:.1f} |",
                      flush=True)  # fmt: skip
        # context: what the matcher has to overcome
    print("\nIMU yaw-rate error over the drive (rad/s, rate about gravity minus the truth):")
    truth_rate = traj.state((raw.t_ns - raw.t_ns[0]) * 1e-9).omega_b[:, 2]
    for iname, imu in imus.items():
        acc = imu.accel / np.linalg.norm(imu.accel, axis=1, keepdims=True)
        r = np.einsum("ij,ij->i", imu.gyro, acc) - truth_rate
        print(f"  {iname}: mean {r.mean():+.5f}, rms {np.sqrt(np.mean(r**2)):.5f}")


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
