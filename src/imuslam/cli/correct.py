"""``imuslam correct``: apply a calibration to a log and write it in the input's format."""

from __future__ import annotations

from pathlib import Path

import typer

from imuslam.cli import validate
from imuslam.cli.common import (
    FORMAT_HELP,
    AccelUnitChoice,
    GyroUnitChoice,
    ImuFormatChoice,
    console,
    friendly_errors,
    load_log,
    value,
)


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
            ...,
            "--out",
            help="output: a file, a bag, or a folder for two text files",
            callback=validate.out_any(),
        ),
        fmt: ImuFormatChoice = typer.Option(ImuFormatChoice.auto, "--format", help=FORMAT_HELP),
        topic: str | None = typer.Option(None, help="IMU topic of a bag (replaced in the copy)"),
        accel_unit: AccelUnitChoice | None = typer.Option(None, help="m/s^2, g or counts"),
        gyro_unit: GyroUnitChoice | None = typer.Option(None, help="rad/s, deg/s or counts"),
        columns: str | None = typer.Option(None, help="CSV column mapping"),
    ) -> None:
        """Write the corrected IMU (m/s^2, rad/s, body frame); a bag keeps every other message untouched."""
        from imuslam.imu.model import ImuCalibration
        from imuslam.io.load import detect_format, write_imu
        from imuslam.io.results import check_out_dir, results_file, results_folder

        check_out_dir(out, "folder" if gyro is not None else "file")
        cal = ImuCalibration.load_yaml(calib)
        log = load_log(
            log_path,
            gyro,
            fmt.value,
            topic,
            value(accel_unit) or cal.accel_unit,
            value(gyro_unit) or cal.gyro_unit,
            columns,
        )
        corrected = cal.correct(log)
        cal.check_magnitudes(corrected)
        f = detect_format(log_path) if fmt.value == "auto" else fmt.value
        what = f"{len(log)} samples"
        if f == "bag":
            t = topic or log.source.rsplit(":", 1)[-1]
            with results_file(out) as tmp:
                write_imu(corrected, tmp, "bag", template=log_path, topic=t)
            written = [out]
            what = (f"{len(log)} samples of {t} (sensor_msgs/Imu; every other topic copied as it is, "
                    "the bag's compression kept)")  # fmt: skip
        elif f == "matlab":  # written as EuRoC csv: imuslam writes no MATLAB files
            with results_file(out) as tmp:
                write_imu(corrected, tmp, "euroc")
            written = [out]
            what += " (MATLAB in, EuRoC csv out)"
        elif gyro is not None:
            with results_folder(out) as tmp:
                names = write_imu(corrected, tmp, f, two_files=True)  # type: ignore[arg-type]
            written = [out / n.name for n in names]
        else:
            with results_file(out) as tmp:
                write_imu(corrected, tmp, f)  # type: ignore[arg-type]
            written = [out]
        console.print(f"corrected {what} -> {', '.join(map(str, written))}")
