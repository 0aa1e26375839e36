"""``imuslam online``: calibration on the robot (gimbal + WitMotion IMU), or on a simulated robot."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import typer

from imuslam.cli import validate
from imuslam.cli.common import console, friendly_errors, table
from imuslam.errors import HardwareError, InputError
from imuslam.imu.calibrate import CalibrationConfig
from imuslam.imu.history import CalibrationHistory
from imuslam.imu.model import ACCEL_PARAM_NAMES, GYRO_PARAM_NAMES
from imuslam.imu.online import OnlineConfig
from imuslam.imu.online_sim import Drift, run_simulated_robot
from imuslam.imu.poseplan import PlanModel, optimise_order
from imuslam.interfaces.imu import ImuLog
from imuslam.io.rosbag import write_imu_bag
from imuslam.sim.multipose import sphere_plan_deg

SEED_POSES = 40  # seed 000's pose count
SEED_T_INIT_S = 50.0  # seed 000's initial still period, s


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


def _print_predicted(model: PlanModel, plan: np.ndarray) -> None:
    """Predicted 1-sigma of a shorter plan against seed 000's 40 poses, ordered as the default plan is."""
    sa, sg = model.predicted_std(plan)
    sa40, sg40 = model.predicted_std(
        optimise_order(model, sphere_plan_deg(SEED_POSES), iterations=1000)
    )
    rows = [
        [n, f"{s:.2e}", f"{s40:.2e}", f"{s / s40:.2f}"]
        for n, s, s40 in zip(
            ACCEL_PARAM_NAMES + GYRO_PARAM_NAMES,
            np.concatenate([sa, sg]),
            np.concatenate([sa40, sg40]),
            strict=True,
        )
    ]
    console.print(
        table(
            f"Predicted 1-sigma with {len(plan)} poses (seed 000 uses {SEED_POSES})",
            ["parameter", f"{len(plan)} poses", f"{SEED_POSES} poses", "ratio"],
            rows,
        )
    )


_NO_HW = "--imu-port needs the hardware extra ({} is missing): pip install 'imuslam[hw]'"


def register(app: typer.Typer) -> None:
    @app.command("online")
    @friendly_errors
    def online_cmd(
        sim: bool = typer.Option(
            False, "--sim", help="run on a simulated robot, faster than real time"
        ),
        duration_h: float = typer.Option(
            1.0,
            help="--sim: hours of operation (at most 168)",
            callback=validate.positive("h", hi=168),
        ),
        drift_accel: float = typer.Option(
            0.05,
            help="--sim: z accelerometer bias drift, m/s^2 per hour",
            callback=validate.number(-1, 1, unit="m/s^2 per hour"),
        ),
        drift_gyro: float = typer.Option(
            0.001,
            help="--sim: gyro bias drift per axis, rad/s per hour",
            callback=validate.number(-0.1, 0.1, unit="rad/s per hour"),
        ),
        poses: int = typer.Option(
            SEED_POSES,
            help="gimbal poses per session, 12..200 (seed 000: 40); with fewer than 40 the predicted "
            "1-sigma is printed",
            callback=validate.integer(12, 200),
        ),
        t_init: float = typer.Option(
            SEED_T_INIT_S,
            "--t-init",
            help="initial still period of a session, s (seed 000: 50)",
            callback=validate.positive("s", hi=600),
        ),
        imu_port: str | None = typer.Option(
            None, help="serial port of a WitMotion IMU, e.g. /dev/ttyUSB0"
        ),
        gimbal: str = typer.Option(
            "pca9685", help="gimbal driver: pca9685", callback=validate.choice(("pca9685",))
        ),
        rate: float = typer.Option(
            100.0, help="IMU output rate, Hz", callback=validate.positive("Hz", hi=1000)
        ),
        seed: int = typer.Option(
            0, help="--sim: random seed (>= 0)", callback=validate.integer(lo=0)
        ),
        out: Path = typer.Option(
            Path("online_out"),
            "--out",
            help="folder of the calibration history",
            callback=validate.out_folder(),
        ),
    ) -> None:
        """Calibrate with the gimbal, publish, watch for drift in still moments, recalibrate."""
        cfg = OnlineConfig(calibration=CalibrationConfig(t_init_s=t_init))
        hist = CalibrationHistory(out / "history")
        rng = np.random.default_rng(seed)
        model = PlanModel.seed000()
        if not sim:
            if imu_port is None:
                raise InputError("give --sim, or --imu-port for a WitMotion IMU on the robot")
            if gimbal != "pca9685":
                raise InputError(f"--gimbal: '{gimbal}'; supported: pca9685")
            from imuslam.hw.gimbal import Pca9685Gimbal, ServoSpec

            try:  # the drivers import smbus2 and pyserial (the hw extra) when they open a device
                g = Pca9685Gimbal(ServoSpec(0), ServoSpec(1, min_deg=-180, max_deg=180))
            except ImportError as exc:
                raise InputError(_NO_HW.format(exc.name)) from None
            except OSError as exc:
                raise HardwareError(f"--gimbal {gimbal}: cannot open its I2C bus ({exc})") from None
            model = replace(model, resolution_deg=g.resolution_deg)
            console.print(
                f"gimbal: PCA9685 hobby servos, {g.resolution_deg:.2f} deg per PWM count "
                "(seed 000's gimbal: 0.088 deg); plans are predicted at the reachable angles"
            )
        plan = optimise_order(model, sphere_plan_deg(poses), iterations=1000)
        if poses < SEED_POSES:
            _print_predicted(model, plan)
        if sim:
            drift = Drift(np.array([0.0, 0.0, drift_accel]), np.full(3, drift_gyro))
            run = run_simulated_robot(plan, duration_h * 3600.0, drift, rng, cfg, hist)
            for e in run.calibrator.events:
                if e.kind != "command":
                    console.print(f"{e.t_ns * 1e-9:8.1f} s  {e.kind:<13} {e.detail}")
            _print_history(hist)
            return
        from imuslam.hw.session import run_online
        from imuslam.hw.witmotion import WitMotionImu
        from imuslam.imu.online import Event

        assert imu_port is not None  # checked before the plan is built
        try:
            imu = WitMotionImu(imu_port)
        except ImportError as exc:
            raise InputError(_NO_HW.format(exc.name)) from None
        except OSError as exc:
            raise HardwareError(f"--imu-port {imu_port}: cannot open ({exc})") from None
        imu.configure(rate)

        buf_t: list[int] = []
        buf: list[np.ndarray] = []

        def keep(t: int, a: np.ndarray, w: np.ndarray) -> None:
            buf_t.append(t)
            buf.append(np.concatenate([a, w]))

        def show(e: Event) -> None:
            console.print(f"{e.kind}: {e.detail}")

        try:
            run_online(imu, g, plan, cfg, hist, rate, on_event=show, on_corrected=keep)
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
