"""``imuslam demo``: calibrate a simulated BWT901CL on a gimbal and compare with the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from imuslam.cli.calibrate import print_result, write_outputs
from imuslam.cli.common import console, friendly_errors
from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.io.load import write_imu
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg


def register(app: typer.Typer) -> None:
    @app.command("demo")
    @friendly_errors
    def demo_cmd(
        out: Path = typer.Option(Path("demo_out"), "--out", help="results folder"),
        poses: int = typer.Option(40, help="gimbal poses (the first is held for the still start)"),
        seed: int = typer.Option(0, help="random seed"),
    ) -> None:
        """A simulated robot IMU with seed 000's errors, turned through gimbal poses and calibrated."""
        rng = np.random.default_rng(seed)
        sim = simulate_multipose(sphere_plan_deg(poses, rng), rng)
        console.print(
            f"simulated {len(sim.log)} samples ({sim.log.t_s[-1]:.0f} s at 100 Hz): BWT901CL-class noise, "
            f"seed 000 table 2 errors, {poses} gimbal poses"
        )
        res = calibrate(sim.log, CalibrationConfig(g=sim.truth.g))
        a, g = sim.truth.accel, sim.truth.gyro
        truth = ImuCalibration(TriadModel(a.T, a.K, a.b), TriadModel(g.T, g.K, g.b))
        print_result(res, truth.accel_params, truth.gyro_params)
        write_imu(sim.log, out / "raw_imu.mcap", "bag", topic="/imu/data")
        write_imu(
            res.calibration.correct(sim.log), out / "corrected_imu.mcap", "bag", topic="/imu/data"
        )
        write_outputs(
            res, sim.log, out, truth_accel=truth.accel_params, truth_gyro=truth.gyro_params
        )
        console.print(
            f"wrote {out}/report.html, calibration.yaml, acc.calib, gyro.calib, raw and corrected MCAP bags"
        )
