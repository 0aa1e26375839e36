"""``imuslam online``: calibration on the robot (gimbal + WitMotion IMU), or on a simulated robot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from imuslam.cli.common import console, friendly_errors, table
from imuslam.errors import InputError
from imuslam.imu.calibrate import CalibrationConfig
from imuslam.imu.history import CalibrationHistory
from imuslam.imu.online import OnlineCalibrator, OnlineConfig
from imuslam.imu.online_sim import Drift, run_simulated_robot
from imuslam.imu.poseplan import PlanModel, optimise_order
from imuslam.interfaces.imu import ImuLog
from imuslam.io.rosbag import write_imu_bag
from imuslam.sim.multipose import sphere_plan_deg


def _print_history(hist: CalibrationHistory) -> None:
    rows = []
    for v in hist.versions():
        c = hist.load(v)
        rows.append(
            [
                str(v),
                c.date,
                f"{c.accel.K[2]:.5f}",
                f"{c.accel.b[2]:+.4f}",
                np.array2string(c.gyro.b, precision=4),
            ]
        )
    console.print(
        table(
            "Calibration history",
            ["version", "date", "s_az", "b_az [m/s^2]", "gyro bias [rad/s]"],
            rows,
        )
    )


def register(app: typer.Typer) -> None:
    @app.command("online")
    @friendly_errors
    def online_cmd(
        sim: bool = typer.Option(
            False, "--sim", help="run on a simulated robot, faster than real time"
        ),
        duration_h: float = typer.Option(1.0, help="--sim: hours of operation"),
        drift_accel: float = typer.Option(
            0.05, help="--sim: z accelerometer bias drift, m/s^2 per hour"
        ),
        drift_gyro: float = typer.Option(
            0.001, help="--sim: gyro bias drift per axis, rad/s per hour"
        ),
        poses: int = typer.Option(24, help="gimbal poses per session"),
        t_init: float = typer.Option(20.0, "--t-init", help="initial still period of a session, s"),
        imu_port: str | None = typer.Option(
            None, help="serial port of a WitMotion IMU, e.g. /dev/ttyUSB0"
        ),
        gimbal: str = typer.Option("pca9685", help="gimbal driver: pca9685"),
        rate: float = typer.Option(100.0, help="IMU output rate, Hz"),
        seed: int = typer.Option(0, help="--sim: random seed"),
        out: Path = typer.Option(
            Path("online_out"), "--out", help="folder of the calibration history"
        ),
    ) -> None:
        """Calibrate with the gimbal, publish, watch for drift in still moments, recalibrate."""
        cfg = OnlineConfig(calibration=CalibrationConfig(t_init_s=t_init))
        hist = CalibrationHistory(out / "history")
        rng = np.random.default_rng(seed)
        plan = optimise_order(PlanModel.seed000(), sphere_plan_deg(poses), iterations=1000)
        if sim:
            drift = Drift(np.array([0.0, 0.0, drift_accel]), np.full(3, drift_gyro))
            run = run_simulated_robot(plan, duration_h * 3600.0, drift, rng, cfg, hist)
            for e in run.calibrator.events:
                if e.kind != "command":
                    console.print(f"{e.t_ns * 1e-9:8.1f} s  {e.kind:<13} {e.detail}")
            _print_history(hist)
            return
        if imu_port is None:
            raise InputError("give --sim, or --imu-port for a WitMotion IMU on the robot")
        from imuslam.hw.gimbal import Pca9685Gimbal, ServoSpec
        from imuslam.hw.witmotion import WitMotionImu

        if gimbal != "pca9685":
            raise InputError(f"--gimbal: '{gimbal}'; supported: pca9685")
        g = Pca9685Gimbal(ServoSpec(0), ServoSpec(1, min_deg=-180, max_deg=180))
        imu = WitMotionImu(imu_port)
        imu.configure(rate)

        def command(angles: np.ndarray) -> float:
            wait = g.settle_time_s((float(angles[0]), float(angles[1])))
            g.move_to((float(angles[0]), float(angles[1])))
            return wait

        buf_t: list[int] = []
        buf: list[np.ndarray] = []

        def keep(t: int, a: np.ndarray, w: np.ndarray) -> None:
            buf_t.append(t)
            buf.append(np.concatenate([a, w]))

        cal = OnlineCalibrator(
            plan, command, cfg, current=hist.latest(), history=hist, rate_hz=rate, on_corrected=keep
        )
        if cal.current is None:
            cal.start_session(0)
        seen = 0
        try:
            for t, a, w in imu.samples(rate):
                cal.step(t, a, w)
                for e in cal.events[seen:]:
                    console.print(f"{e.kind}: {e.detail}")
                    if e.kind in ("drift", "schedule"):
                        cal.start_session(t)
                seen = len(cal.events)
        except KeyboardInterrupt:
            pass
        finally:
            imu.close()
            if buf:
                x = np.array(buf)
                write_imu_bag(
                    ImuLog(np.array(buf_t), x[:, :3], x[:, 3:]), out / "corrected_imu.mcap"
                )
            _print_history(hist)
