"""``imuslam correct``: apply a calibration to a log and write it in the input's format."""

from __future__ import annotations

from pathlib import Path

import typer

from imuslam.cli.common import FORMAT_HELP, console, friendly_errors, load_log
from imuslam.errors import InputError
from imuslam.imu.model import ImuCalibration
from imuslam.io.load import detect_format, write_imu


def register(app: typer.Typer) -> None:
    @app.command("correct")
    @friendly_errors
    def correct_cmd(
        log_path: Path = typer.Argument(
            ..., metavar="LOG", help="IMU log (accelerometer file for two-file text)"
        ),
        gyro: Path | None = typer.Argument(
            None, help="gyroscope file, for imu_tk text in two files"
        ),
        calib: Path = typer.Option(
            ..., "--calib", help="calibration.yaml written by 'imuslam calibrate'"
        ),
        out: Path = typer.Option(
            ..., "--out", help="output: a file, a bag, or a folder for two text files"
        ),
        fmt: str = typer.Option("auto", "--format", help=FORMAT_HELP),
        topic: str | None = typer.Option(None, help="IMU topic of a bag (replaced in the copy)"),
        accel_unit: str | None = typer.Option(None, help="m/s^2, g or counts"),
        gyro_unit: str | None = typer.Option(None, help="rad/s, deg/s or counts"),
        columns: str | None = typer.Option(None, help="CSV column mapping"),
    ) -> None:
        """Write the corrected IMU (m/s^2, rad/s, body frame); a bag keeps every other message untouched."""
        cal = ImuCalibration.load_yaml(calib)
        log = load_log(
            log_path,
            gyro,
            fmt,
            topic,
            accel_unit or cal.accel_unit,
            gyro_unit or cal.gyro_unit,
            columns,
        )
        corrected = cal.correct(log)
        f = detect_format(log_path) if fmt == "auto" else fmt
        if f == "bag":
            t = topic or log.source.rsplit(":", 1)[-1]
            if Path(out).exists():
                raise InputError(f"{out}: exists; choose a new output bag")
            written = write_imu(corrected, out, "bag", template=log_path, topic=t)
        else:
            written = write_imu(corrected, out, f, two_files=gyro is not None)  # type: ignore[arg-type]
        console.print(f"corrected {len(log)} samples -> {', '.join(map(str, written))}")
