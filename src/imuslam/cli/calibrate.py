"""``imuslam calibrate``: multi-position calibration of a log, with report."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from imuslam.cli import validate
from imuslam.cli.common import (
    FORMAT_HELP,
    AccelUnitChoice,
    BiasSign,
    GyroUnitChoice,
    ImuFormatChoice,
    console,
    friendly_errors,
    load_log,
    prefetch_log,
    print_warnings,
    table,
    value,
)


class CalibMethod(StrEnum):
    joint = "joint"
    tedaldi = "tedaldi"


if (
    TYPE_CHECKING
):  # numba, scipy, pydantic and matplotlib load when the command runs, not at start-up
    import numpy as np

    from imuslam.imu.calibrate import CalibrationResult
    from imuslam.imu.crossval import CrossValidation
    from imuslam.interfaces.imu import ImuLog


def print_result(
    res: CalibrationResult, truth_a: np.ndarray | None = None, truth_g: np.ndarray | None = None
) -> None:
    """Rich tables of the parameters (with units) and the fit quality."""
    import numpy as np

    from imuslam.imu.model import ACCEL_PARAM_NAMES, GYRO_PARAM_NAMES

    c = res.calibration
    au, gu = c.accel_unit, c.gyro_unit
    units_a = ["rad"] * 3 + (["1"] if au == "m/s^2" else [f"m/s^2 per {au}"]) * 3 + [au] * 3
    units_g = ["rad"] * 6 + (["1"] if gu == "rad/s" else [f"rad/s per {gu}"]) * 3
    cols = ["parameter", "estimate", "1-sigma", "unit"] + (
        ["truth", "error/sigma"] if truth_a is not None else []
    )
    for title, names, est, std, units, truth in (
        ("Accelerometer", ACCEL_PARAM_NAMES, c.accel_params, res.std_accel, units_a, truth_a),
        ("Gyroscope", GYRO_PARAM_NAMES, c.gyro_params, res.std_gyro, units_g, truth_g),
    ):
        rows = []
        for i, n in enumerate(names):
            r = [n, f"{est[i]:.8g}", f"{std[i]:.2g}", units[i]]
            if truth is not None:
                r += [f"{truth[i]:.8g}", f"{(est[i] - truth[i]) / std[i]:+.2f}"]
            rows.append(r)
        console.print(table(title, cols, rows))
    console.print(
        table(
            "Fit",
            ["quantity", "value", "unit"],
            [
                ["threshold multiple k (lowest residual of the sweep)", f"{res.k:g}", ""],
                ["static intervals the fit used (detected at k)", str(len(res.intervals)), "count"],
                ["|a| - g, RMS over every static sample", f"{res.accel_rms:.5f}", "m/s^2"],
                [
                    "gravity direction error, RMS per pair of intervals",
                    f"{res.gyro_rms_deg:.3f}",
                    "deg",
                ],
                ["gyro bias", np.array2string(c.gyro.b, precision=6), gu],
                ["time", f"{1e3 * res.timings_s['total']:.0f}", "ms"],
            ],
        )
    )
    console.print(observability_line(res), markup=False, highlight=False)
    print_warnings(w for w in res.warnings if not w.startswith("poorly determined"))


def observability_line(res: CalibrationResult) -> str:
    """The verdict on every parameter: determined within its limit by these poses, or which are not
    (limits: angles 1 mrad accelerometer / 2 mrad gyro, scales 0.1 % / 0.5 %, accelerometer bias
    0.02 m/s^2, as 1-sigma)."""
    limits = "1-sigma within 1 / 2 mrad, 0.1 / 0.5 % scale, 0.02 m/s^2 bias"
    if not res.poorly_determined:
        return f"observability: every parameter determined by these poses ({limits})"
    return (
        f"observability: poorly determined: {', '.join(res.poorly_determined)} ({limits} not met); "
        "add poses that turn about the axes these parameters involve"
    )


def print_cv(res: CalibrationResult, cv: CrossValidation) -> None:
    """The cross-validated score beside the fit residual."""
    console.print(
        table(
            f"{cv.k_folds}-fold cross-validation ({cv.method}) over {len(cv.poses)} static poses "
            "(found by the score's fixed detector, not the fit's k)",
            ["quantity", "fit on all poses", "held out RMS", "held out worst", "unit"],
            [
                ["|a| - g of each pose's mean", f"{cv.fit_norm_rms:.5f}", f"{cv.norm_rms:.5f}",
                 f"{cv.norm_worst:.5f}", "m/s^2"],
                ["gravity direction error per pair", f"{cv.fit_direction_rms_deg:.3f}",
                 f"{cv.direction_rms_deg:.3f}", f"{cv.direction_worst_deg:.3f}", "deg"],
            ],
        )
    )  # fmt: skip


def write_outputs(
    res: CalibrationResult,
    log: ImuLog,
    out: Path,
    cv: CrossValidation | None = None,
    plots: bool = True,
    extra_html: str = "",
    **truth: np.ndarray | None,
) -> None:
    from imuslam.config import dump_config
    from imuslam.imu.report import write_report

    c = res.calibration
    c.save_yaml(out / "calibration.yaml")
    c.export_imutk(out / "acc.calib", out / "gyro.calib")
    dump_config(res.config, out / "config.yaml")
    if plots:
        write_report(
            res,
            log,
            out,
            truth.get("truth_accel"),
            truth.get("truth_gyro"),
            cv=cv,
            extra_html=extra_html,
        )


def register(app: typer.Typer) -> None:
    @app.command("calibrate")
    @friendly_errors
    def calibrate_cmd(
        acc: Path = typer.Argument(
            ..., help="accelerometer file (or the whole log: bag, EuRoC, 7-column text)"
        ),
        gyro: Path | None = typer.Argument(
            None, help="gyroscope file, for imu_tk text in two files"
        ),
        fmt: ImuFormatChoice = typer.Option(ImuFormatChoice.auto, "--format", help=FORMAT_HELP),
        topic: str | None = typer.Option(None, help="IMU topic of a bag"),
        g: float | None = typer.Option(
            None, "--g", help="local gravity, m/s^2 (default 9.80665)", callback=validate.gravity()
        ),
        t_init: float | None = typer.Option(
            None,
            "--t-init",
            help="initial still period, s (default 50)",
            callback=validate.positive("s"),
        ),
        bias_sign: BiasSign | None = typer.Option(
            None, help="plus: T K (x + b) (default); minus: T K (x - b) (imu_tk)"
        ),
        accel_unit: AccelUnitChoice | None = typer.Option(
            None, help="m/s^2, g or counts (guessed if absent)"
        ),
        gyro_unit: GyroUnitChoice | None = typer.Option(
            None, help="rad/s, deg/s or counts (guessed if absent)"
        ),
        columns: str | None = typer.Option(
            None, help="CSV column mapping: t=..,ax=..,ay=..,az=..,gx=..,gy=..,gz=.."
        ),
        config: Path | None = typer.Option(None, help="YAML with CalibrationConfig fields"),
        method: CalibMethod | None = typer.Option(
            None, help="joint (default): accelerometer and gyro fitted together; tedaldi: imu_tk's"
        ),
        cv_folds: int = typer.Option(
            5,
            "--cv-folds",
            help="folds of the cross-validation over static poses (0: none)",
            callback=validate.integer(2, 100, also=(0,)),
        ),
        out: Path = typer.Option(
            Path("calib_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
        plots: bool = typer.Option(
            True, "--plots/--no-plots", help="write the PNG plots and report.html (about 1 s)"
        ),
    ) -> None:
        """Calibrate accelerometer and gyroscope from a log of static poses: a joint fit of both (default)
        or imu_tk's two steps (--method tedaldi, Tedaldi 2014)."""
        prefetch_log(acc, gyro, fmt.value)  # parsed beside the imports below
        from imuslam.config import load_config
        from imuslam.imu.calibrate import CalibrationConfig
        from imuslam.imu.pipeline import CalibrateOutput, CalibratePipeline

        cfg = load_config(config, CalibrationConfig) if config else CalibrationConfig()
        upd = {
            k: v
            for k, v in {
                "g": g,
                "t_init_s": t_init,
                "bias_sign": value(bias_sign),
                "method": value(method),
            }.items()
            if v is not None
        }
        cfg = CalibrationConfig.model_validate({**cfg.model_dump(), **upd})
        log = load_log(acc, gyro, fmt.value, topic, value(accel_unit), value(gyro_unit), columns)
        pipeline = CalibratePipeline(log, cfg, cv_folds)
        res = pipeline.calibrate()
        print_result(res)  # the result first; the cross-validation's refits and the report after
        cv = pipeline.cross_validate(res)
        if cv is not None:
            print_cv(res, cv)
        pipeline.save(CalibrateOutput(res, cv), out, plots)
        extra = ", plots, report.html" if plots else ""
        console.print(
            f"wrote {out}/calibration.yaml, acc.calib, gyro.calib, config.yaml, metrics.json{extra}"
        )
