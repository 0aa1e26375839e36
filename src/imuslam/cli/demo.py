"""``imuslam demo``: calibrate a simulated BWT901CL on a gimbal, compare with the truth, and show what the
calibration buys an INS."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import typer

from imuslam.cli import validate
from imuslam.cli.calibrate import print_result, write_outputs
from imuslam.cli.common import console, friendly_errors, table, write_json


def register(app: typer.Typer) -> None:
    @app.command("demo")
    @friendly_errors
    def demo_cmd(
        out: Path = typer.Option(
            Path("demo_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
        poses: int = typer.Option(
            40,
            help="gimbal poses, 12..200 (the first is held for the still start)",
            callback=validate.integer(12, 200),
        ),
        seed: int = typer.Option(0, help="random seed (>= 0)", callback=validate.integer(lo=0)),
    ) -> None:
        """A simulated robot IMU with seed 000's errors, turned through gimbal poses and calibrated."""
        import numpy as np

        from imuslam.demo import ins_benefit
        from imuslam.imu.calibrate import CalibrationConfig, calibrate
        from imuslam.imu.model import (
            ImuCalibration,
            TriadModel,
        )
        from imuslam.io.results import results_folder
        from imuslam.sim.imu import ImuErrorSpec
        from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg

        rng = np.random.default_rng(seed)
        console.print(f"simulating a BWT901CL turned through {poses} gimbal poses ...")
        sim = simulate_multipose(sphere_plan_deg(poses, rng), rng)
        console.print(
            f"simulated {len(sim.log)} samples ({sim.log.t_s[-1]:.0f} s at 100 Hz): BWT901CL-class noise, "
            f"seed 000 table 2 errors, {poses} gimbal poses"
        )
        console.print(
            "calibrating (the first run compiles the numerical kernels, about a minute; later runs "
            "reuse them) ..."
        )
        res = calibrate(sim.log, CalibrationConfig(g=sim.truth.g))
        a, g = sim.truth.accel, sim.truth.gyro
        truth = ImuCalibration(TriadModel(a.T, a.K, a.b), TriadModel(g.T, g.K, g.b))
        print_result(res, truth.accel_params, truth.gyro_params)
        console.print("what it buys an INS: five 90 s car runs with a Kalman filter ...")
        runs = ins_benefit(res.calibration, ImuErrorSpec.bwt901cl(), rng, g=sim.truth.g)
        title = "What the calibration buys an INS: a car with RTK fixes for 60 s, then 30 s without"
        cols = ["IMU, start of the free run", "attitude error [deg]", "position error [m]"]
        rows = [[r.name, f"{r.attitude_err_deg:.2f}", f"{r.position_err_m:.2f}"] for r in runs]
        console.print(table(title, cols, rows))
        with results_folder(out) as tmp:
            _save(tmp, sim.log, res, truth, runs, _ins_html(title, cols, rows))
        console.print(
            f"wrote {out}/report.html (calibration and INS), calibration.yaml, acc.calib, gyro.calib, "
            "raw and corrected MCAP bags, ins_benefit.png, ins_benefit.json, config.yaml, metrics.json"
        )


def _save(tmp: Path, log: Any, res: Any, truth: Any, runs: list[Any], ins_html: str) -> None:
    """Into the results folder: the raw and corrected IMU as MCAP bags, the calibration's files and
    report, the INS runs (PNG, JSON) and metrics.json (the calibration against the simulator's truth:
    estimate - truth per parameter and the fit's 1-sigma; the INS runs)."""
    import numpy as np
    from matplotlib.figure import Figure

    from imuslam.imu.model import ACCEL_PARAM_NAMES, GYRO_PARAM_NAMES
    from imuslam.io.figures import save_figure
    from imuslam.io.load import write_imu

    write_imu(log, tmp / "raw_imu.mcap", "bag", topic="/imu/data")
    write_imu(res.calibration.correct(log), tmp / "corrected_imu.mcap", "bag", topic="/imu/data")
    write_outputs(res, log, tmp, extra_html=ins_html,
                  truth_accel=truth.accel_params, truth_gyro=truth.gyro_params)  # fmt: skip
    fig = Figure(figsize=(9, 5))
    ax = fig.subplots()
    for r in runs:
        ax.semilogy(r.t_s, np.maximum(r.err_m, 1e-3), label=r.name)
    ax.set_xlabel("time without fixes [s]")
    ax.set_ylabel("position error [m]")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    save_figure(fig, tmp / "ins_benefit.png")
    ins_rows = [{"variant": r.name, "attitude_err_deg": r.attitude_err_deg,
                 "position_err_m": r.position_err_m} for r in runs]  # fmt: skip
    write_json(tmp / "ins_benefit.json", ins_rows)
    cal = res.calibration
    write_json(tmp / "metrics.json", {
        "accel": _param_metrics(ACCEL_PARAM_NAMES, cal.accel_params, truth.accel_params, cal.cov_accel),
        "gyro": _param_metrics(GYRO_PARAM_NAMES, cal.gyro_params, truth.gyro_params, cal.cov_gyro),
        "ins_benefit": ins_rows,
    })  # fmt: skip


def _param_metrics(
    names: tuple[str, ...], est: Any, truth: Any, cov: Any
) -> dict[str, dict[str, float | None]]:
    """Per parameter: the estimate's error against the truth and the fit's 1-sigma (None without a
    covariance)."""
    import numpy as np

    sig = [None] * len(names) if cov is None else np.sqrt(np.diag(cov)).tolist()
    err = (np.asarray(est) - np.asarray(truth)).tolist()
    return {n: {"error": e, "sigma": s} for n, e, s in zip(names, err, sig, strict=True)}


def _ins_html(title: str, cols: list[str], rows: list[list[str]]) -> str:
    """The INS comparison as a report section: the table and the error-growth plot."""
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in r) + "</tr>" for r in rows
    )
    return (
        f"<h2>{html.escape(title)}</h2><table><tr>{head}</tr>{body}</table>"
        '<img src="ins_benefit.png" width="100%">'
    )
