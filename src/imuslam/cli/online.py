"""``imuslam online``: calibration on the robot (gimbal + WitMotion IMU), or on a simulated robot; a thin
body over :class:`imuslam.imu.online_pipeline.OnlinePipeline`."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from imuslam.cli import validate
from imuslam.cli.common import RRD_HELP, VIEWER_HELP, console, friendly_errors, table
from imuslam.errors import HardwareError, InputError

if TYPE_CHECKING:
    from imuslam.imu.history import CalibrationHistory
    from imuslam.imu.online_pipeline import RobotDevices

SEED_POSES = 40  # seed 000's pose count (imuslam.imu.online_pipeline.SEED_POSES)
SEED_T_INIT_S = 50.0  # seed 000's initial still period, s


class Gimbal(StrEnum):
    pca9685 = "pca9685"


def _print_history(hist: CalibrationHistory) -> None:
    import numpy as np

    rows = []
    for v in hist.versions():
        c = hist.load(v)
        rows.append([str(v), c.date, f"{c.accel.K[2]:.5f}", f"{c.accel.b[2]:+.4f}",
                     np.array2string(c.gyro.b, precision=4)])  # fmt: skip
    console.print(table("Calibration history",
                        ["version", "date", "s_az", "b_az [m/s^2]", "gyro bias [rad/s]"], rows))  # fmt: skip


def _print_predicted(n_poses: int, predicted: Any) -> None:
    """Predicted 1-sigma of a shorter plan against seed 000's 40 poses, ordered as the default plan is."""
    from imuslam.imu.model import ACCEL_PARAM_NAMES, GYRO_PARAM_NAMES

    s, s40 = predicted
    rows = [[n, f"{a:.2e}", f"{b:.2e}", f"{a / b:.2f}"]
            for n, a, b in zip(ACCEL_PARAM_NAMES + GYRO_PARAM_NAMES, s, s40, strict=True)]  # fmt: skip
    console.print(table(f"Predicted 1-sigma with {n_poses} poses (seed 000 uses {SEED_POSES})",
                        ["parameter", f"{n_poses} poses", f"{SEED_POSES} poses", "ratio"], rows))  # fmt: skip


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
        gimbal: Gimbal = typer.Option(Gimbal.pca9685, help="gimbal driver: pca9685"),
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
        rrd: Path | None = typer.Option(None, "--rrd", help=RRD_HELP),
        viewer: bool = typer.Option(False, "--viewer", help=VIEWER_HELP),
    ) -> None:
        """Calibrate with the gimbal, publish, watch for drift in still moments, recalibrate."""
        import numpy as np

        from imuslam.imu.online import Event
        from imuslam.imu.online_pipeline import (
            OnlinePipeline,
            OnlineRunConfig,
            SimulatedRobot,
        )

        cfg = OnlineRunConfig(poses=poses, t_init_s=t_init, rate_hz=rate)
        inputs: dict[str, object] = {"sim": sim}
        dataset: SimulatedRobot | RobotDevices
        imu = None
        if sim:
            dataset = SimulatedRobot(duration_h * 3600.0, np.array([0.0, 0.0, drift_accel]),
                                     np.full(3, drift_gyro), seed)  # fmt: skip
            inputs.update(
                duration_h=duration_h, drift_accel=drift_accel, drift_gyro=drift_gyro, seed=seed
            )
        else:
            if imu_port is None:
                raise InputError("give --sim, or --imu-port for a WitMotion IMU on the robot")
            devices = _open_devices(imu_port, gimbal.value, rate)
            dataset, imu = devices, devices.imu
            inputs.update(imu_port=imu_port, gimbal=gimbal.value)
        pipeline = OnlinePipeline(dataset, cfg, out / "history")

        def show(e: Event) -> None:
            console.print(f"{e.kind}: {e.detail}")

        def plan_ready(plan: Any, predicted: Any) -> None:  # before the first session
            if predicted is not None:
                _print_predicted(poses, predicted)

        try:
            res = pipeline.run(on_event=show, on_plan=plan_ready)
        finally:
            if imu is not None:
                imu.close()
        if sim:
            for e in res.events:
                if e.kind != "command":
                    console.print(f"{e.t_ns * 1e-9:8.1f} s  {e.kind:<13} {e.detail}")
        _print_history(pipeline.history)
        _record(res, pipeline.history, rrd, viewer)
        pipeline.save(res, out, **inputs)


def _record(res: Any, history: Any, rrd: Path | None, viewer: bool) -> None:
    """With --rrd / --viewer: the run's events and calibrations in a recording (:mod:`imuslam.viz.online`)."""
    if rrd is None and not viewer:
        return
    from imuslam.viz.online import log_online
    from imuslam.viz.recording import open_recording

    with open_recording("imuslam online", rrd, viewer) as rec:
        log_online(rec, res, history)


def _open_devices(imu_port: str, gimbal: str, rate: float) -> RobotDevices:
    """The robot's devices: a WitMotion IMU on ``imu_port`` at ``rate`` Hz and the PCA9685 servo
    gimbal; a missing hw extra is bad input (exit 2), a device that does not open a hardware error."""
    from imuslam.hw.gimbal import Pca9685Gimbal, ServoSpec
    from imuslam.hw.witmotion import WitMotionImu
    from imuslam.imu.online_pipeline import RobotDevices

    try:  # the drivers import smbus2 and pyserial (the hw extra) when they open a device
        g = Pca9685Gimbal(ServoSpec(0), ServoSpec(1, min_deg=-180, max_deg=180))
    except ImportError as exc:
        raise InputError(_NO_HW.format(exc.name)) from None
    except OSError as exc:
        raise HardwareError(f"--gimbal {gimbal}: cannot open its I2C bus ({exc})") from None
    console.print(
        f"gimbal: PCA9685 hobby servos, {g.resolution_deg:.2f} deg per PWM count "
        "(seed 000's gimbal: 0.088 deg); plans are predicted at the reachable angles"
    )
    try:
        imu = WitMotionImu(imu_port)
    except ImportError as exc:
        raise InputError(_NO_HW.format(exc.name)) from None
    except OSError as exc:
        raise HardwareError(f"--imu-port {imu_port}: cannot open ({exc})") from None
    imu.configure(rate)
    return RobotDevices(imu, g)
