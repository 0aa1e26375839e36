"""``imuslam score``: how well one or more calibrations predict the static poses of a log."""

from __future__ import annotations

from pathlib import Path

import typer

from imuslam.cli import validate


def register(app: typer.Typer) -> None:
    @app.command("score")
    def score_cmd(
        log_path: Path = typer.Argument(
            ..., metavar="LOG", help="IMU log (bag, EuRoC, CSV, or imu_tk accelerometer text)"
        ),
        calibs: list[Path] = typer.Argument(
            ...,
            metavar="CALIB...",
            help="calibration.yaml files and/or imu_tk .calib pairs (accelerometer, then gyroscope)",
        ),
        gyro: Path | None = typer.Option(
            None, "--gyro", help="gyroscope file of an imu_tk two-file text log"
        ),
        g: float | None = typer.Option(
            None,
            "--g",
            help="local gravity, m/s^2 (default: the first YAML's, else 9.80665)",
            callback=validate.gravity(),
        ),
        t_init: float = typer.Option(
            50.0,
            "--t-init",
            help="initial still period of the log, s",
            callback=validate.positive("s"),
        ),
        fmt: str = typer.Option(
            "auto", "--format", help="input format: auto, imutk, euroc, csv, bag or matlab (v7.3)"
        ),
        topic: str | None = typer.Option(None, help="IMU topic of a bag"),
        accel_unit: str | None = typer.Option(None, help="m/s^2, g or counts (guessed if absent)"),
        gyro_unit: str | None = typer.Option(
            None, help="rad/s, deg/s or counts (guessed if absent)"
        ),
        out: Path | None = typer.Option(
            None, "--out", help="results folder (scores.csv, poses.csv, pairs.csv, score.png)"
        ),
    ) -> None:
        """Score calibrations on a log: gravity-norm error per static pose, gyro-predicted gravity-direction
        error per pair of poses (RMS and worst), on poses found without any calibration."""
        from imuslam.cli.common import (
            check_log_options,
            check_out_against_inputs,
            console,
            friendly_errors,
            load_log,
            table,
        )
        from imuslam.imu.score import load_calibrations, score_calibrations, write_scores

        @friendly_errors
        def run() -> None:
            check_out_against_inputs(
                {"out": out, "log_path": log_path, "calibs": calibs, "gyro": gyro}
            )
            check_log_options(fmt, accel_unit, gyro_unit)
            _check_calib_files(calibs)  # before the log, which can take seconds to load
            log = load_log(log_path, gyro, fmt, topic, accel_unit, gyro_unit, None)
            # imu_tk .calib files carry neither units nor g: they are taken as the log's.
            cals, g_yaml = load_calibrations(calibs, log.accel_unit, log.gyro_unit)
            g_used = g if g is not None else (g_yaml if g_yaml is not None else 9.80665)
            res = score_calibrations(log, cals, g_used, t_init)
            rows = [
                [s.name, f"{s.norm_rms:.5f}", f"{s.norm_worst:.5f}",
                 f"{s.direction_rms_deg:.3f}", f"{s.direction_worst_deg:.3f}"]
                for s in res.scores
            ]  # fmt: skip
            console.print(
                table(
                    f"Score on {len(res.poses)} static poses, {len(res.poses) - 1} pairs (g = {g_used:g})",
                    ["calibration", "norm RMS [m/s^2]", "norm worst [m/s^2]",
                     "direction RMS [deg]", "direction worst [deg]"],
                    rows,
                )
            )  # fmt: skip
            if out is not None:
                write_scores(res, out)
                console.print(f"wrote {out}/scores.csv, poses.csv, pairs.csv, score.png")

        run()


def _check_calib_files(calibs: list[Path]) -> None:
    """Every CALIB argument an existing file, else one line naming it."""
    from imuslam.errors import InputError

    for c in calibs:
        if not c.exists():
            raise InputError(f"{c}: no such file (CALIB: a calibration.yaml or an imu_tk .calib)")
        if not c.is_file():
            raise InputError(f"{c}: a folder; CALIB is a calibration.yaml or an imu_tk .calib file")
