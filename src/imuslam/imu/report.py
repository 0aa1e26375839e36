"""Plots and an HTML report of a calibration; every file is written atomically."""

from __future__ import annotations

import html
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from imuslam.imu.calibrate import CalibrationResult
from imuslam.imu.crossval import CrossValidation
from imuslam.imu.model import ACCEL_PARAM_NAMES, GYRO_PARAM_NAMES
from imuslam.interfaces.imu import ImuLog
from imuslam.io.atomic import write_atomic
from imuslam.io.figures import save_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def plot_static_detection(res: CalibrationResult, log: ImuLog) -> Figure:
    """The raw accelerometer with the static detector's verdict over it (seed 000, figure 3)."""
    t = log.t_s
    static = np.zeros(len(t), dtype=bool)
    for s, e in res.intervals:
        static[s:e] = True
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 8))
    axes = fig.subplots(4, 1, sharex=True)
    for j, ax in enumerate(axes[:3]):
        ax.plot(t, log.accel[:, j], lw=0.6, color="C0")
        lo, hi = np.min(log.accel[:, j]), np.max(log.accel[:, j])
        ax.fill_between(t, lo, hi, where=static, color="C2", alpha=0.15, lw=0, label="static")
        ax.set_ylabel(f"a_{'xyz'[j]} [{log.accel_unit}]")
    axes[0].legend(loc="upper right")
    axes[3].semilogy(t, res.detector, lw=0.6, color="C1", label="detector")
    axes[3].axhline(res.threshold, color="k", ls="--", lw=0.8, label=f"threshold (k = {res.k:g})")
    axes[3].set_ylabel(f"s(t) [{log.accel_unit}^2]")
    axes[3].set_xlabel("time [s]")
    axes[3].legend(loc="upper right")
    fig.suptitle(f"Static detection: {len(res.intervals)} intervals")
    return fig


def raw_norm_error(res: CalibrationResult, log: ImuLog) -> np.ndarray | None:
    """|a| - g per static interval of the log as recorded (no model at all), m/s^2; None when the log
    is not in m/s^2 (counts or g have no gravity to compare with)."""
    if log.accel_unit != "m/s^2":
        return None
    acc, g = log.accel, res.calibration.g
    return np.array([np.mean(np.linalg.norm(acc[s : e + 1], axis=1)) - g for s, e in res.intervals])


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def plot_residuals(res: CalibrationResult, log: ImuLog | None = None) -> Figure:
    """Per static interval, the gravity-norm error |a| - g of the log as recorded (m/s^2 logs), of the
    fit's starting point (a scale and offset per axis, no misalignment, fitted to the intervals' means:
    already close on a good sensor) and calibrated; per pair of consecutive intervals, the gravity
    direction error of the gyro integration with the bias removed and unit scale, and calibrated.
    Magnitudes on a log scale (one sensor's raw error is 100 times its calibrated one), RMS in the
    legend."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 7))
    a1, a2 = fig.subplots(2, 1)
    raw = raw_norm_error(res, log) if log is not None else None
    series = ([("as recorded", raw)] if raw is not None else []) + [
        ("per-axis scale + offset (the fit's start)", res.accel_residual_before),
        ("calibrated", res.accel_residual_after),
    ]
    w = 0.8 / len(series)
    for n, (lab, y) in enumerate(series):
        k = np.arange(len(y))
        a1.bar(k + (n - (len(series) - 1) / 2) * w, np.abs(y), w, color=f"C{n}",
               label=f"{lab}: RMS {_rms(y):.3g} m/s^2")  # fmt: skip
    a1.set_yscale("log")
    a1.set_ylabel("| |a| - g | per interval [m/s^2]")
    a1.set_title(
        f"Accelerometer: gravity-norm error of each of the {len(res.intervals)} static intervals"
    )
    a1.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    p = np.arange(len(res.gyro_residual_after_deg))
    for n, (lab, y) in enumerate(
        (
            ("bias removed, unit scale", res.gyro_residual_before_deg),
            ("calibrated", res.gyro_residual_after_deg),
        )
    ):
        a2.bar(p + (n - 0.5) * 0.4, np.abs(y), 0.4, color=("C4", f"C{len(series) - 1}")[n],
               label=f"{lab}: RMS {_rms(y):.3g} deg")  # fmt: skip
    a2.set_yscale("log")
    a2.set_ylabel("gravity direction error [deg]")
    a2.set_xlabel("static interval (top) / pair of consecutive intervals (bottom)")
    a2.set_title("Gyroscope: gravity direction carried from one interval to the next")
    a2.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.suptitle(f"Residuals before and after calibration ({res.config.method}, k = {res.k:g})")
    return fig


def plot_sweep(res: CalibrationResult) -> Figure:
    """Residual per sample and interval count against the threshold multiple k, the chosen k marked."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    ks = [r.k for r in res.sweep]
    rr = [
        r.residual_per_sample if np.isfinite(r.residual_per_sample) else np.nan for r in res.sweep
    ]
    ax.plot(ks, rr, "o-", label="residual per sample")
    ax.axvline(res.k, color="k", ls="--", lw=0.8, label=f"chosen k = {res.k:g} (lowest residual)")
    ax.set_xlabel("threshold multiple k")
    ax.set_ylabel("mean (g - |a|)^2 [(m/s^2)^2]")
    ax2 = ax.twinx()
    ax2.plot(ks, [r.n_intervals for r in res.sweep], "s:", color="C1", label="static intervals")
    ax2.set_ylabel("static intervals", color="C1")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=8)
    ax.set_title("Static detector threshold sweep")
    return fig


def _param_rows(
    names: tuple[str, ...], est: np.ndarray, std: np.ndarray, truth: np.ndarray | None
) -> str:
    rows = []
    for i, n in enumerate(names):
        tv = (
            ""
            if truth is None
            else f"<td>{truth[i]:.6g}</td><td>{(est[i] - truth[i]) / std[i]:+.2f}</td>"
        )
        rows.append(f"<tr><td>{n}</td><td>{est[i]:.8g}</td><td>{std[i]:.2g}</td>{tv}</tr>")
    return "\n".join(rows)


def write_report(
    res: CalibrationResult,
    log: ImuLog,
    out_dir: str | Path,
    truth_accel: np.ndarray | None = None,
    truth_gyro: np.ndarray | None = None,
    cv: CrossValidation | None = None,
    extra_html: str = "",
) -> list[Path]:
    """PNG plots and ``report.html`` in ``out_dir``; returns the files written. ``extra_html``: more
    sections (already escaped HTML) appended to the report, e.g. what the calibration buys an INS."""
    out = Path(out_dir)
    files = {
        "static_detection.png": plot_static_detection(res, log),
        "residuals.png": plot_residuals(res, log),
        "sweep.png": plot_sweep(res),
    }
    for name, fig in files.items():
        save_figure(fig, out / name)
    c = res.calibration
    head = "<tr><th>parameter</th><th>estimate</th><th>1-sigma</th>"
    head_t = head + (
        "<th>truth</th><th>error / sigma</th></tr>" if truth_accel is not None else "</tr>"
    )
    sweep = "\n".join(
        f"<tr><td>{r.k:g}</td><td>{r.n_intervals}</td><td>{r.residual_per_sample:.4g}</td>"
        f"<td>{'yes' if r.ok else html.escape(r.message)}</td></tr>"
        for r in res.sweep
    )
    cv_html = (
        "<p>not run</p>"
        if cv is None
        else f"""<p>{cv.k_folds}-fold over the {len(cv.poses)} static poses found by the score's fixed
detector (pose i in fold i mod {cv.k_folds}): each fold refits the calibration ({html.escape(cv.method)})
without its poses and scores them, and every pair of poses with a held-out end.</p>
<table><tr><th>quantity</th><th>fit (all poses)</th><th>held out: RMS</th><th>held out: worst</th></tr>
<tr><td>gravity norm error per pose [m/s^2]</td><td>{cv.fit_norm_rms:.5f}</td>
<td>{cv.norm_rms:.5f}</td><td>{cv.norm_worst:.5f}</td></tr>
<tr><td>gravity direction error per pair [deg]</td><td>{cv.fit_direction_rms_deg:.3f}</td>
<td>{cv.direction_rms_deg:.3f}</td><td>{cv.direction_worst_deg:.3f}</td></tr></table>"""
    )
    g_sens = (
        ""
        if c.gyro_g_sensitivity is None
        else "<p>Gyro g-sensitivity G [deg/s per g]: "
        + html.escape(np.array2string(np.rad2deg(c.gyro_g_sensitivity) * c.g, precision=4))
        + "</p>"
    )
    warn = "".join(f"<li>{html.escape(w)}</li>" for w in res.warnings) or "<li>none</li>"
    doc = f"""<!doctype html><html><head><meta charset="utf-8"><title>IMU calibration</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}</style></head><body>
<h1>IMU calibration</h1>
<p>Data: {html.escape(c.source)} &mdash; {len(log)} samples at {log.rate_hz:.2f} Hz; raw units
accel {html.escape(c.accel_unit)}, gyro {html.escape(c.gyro_unit)}; g = {c.g} m/s^2; date {html.escape(c.date)}.</p>
<p>Model: x_O = T diag(K) (x_S {"+" if c.accel.bias_sign == "plus" else "-"} b) (Tedaldi et al., ICRA 2014).
Threshold k = {res.k:g}, {len(res.intervals)} static intervals. Per-sample RMS of |a| - g:
{res.accel_rms:.5f} m/s^2. Gravity-direction RMS error per pair: {res.gyro_rms_deg:.3f} deg.
Method {html.escape(res.config.method)}. Time {1e3 * res.timings_s.get("total", float("nan")):.0f} ms.</p>
<h2>Warnings</h2><ul>{warn}</ul>
<h2>Accelerometer</h2><table>{head_t}{_param_rows(ACCEL_PARAM_NAMES, c.accel_params, res.std_accel, truth_accel)}</table>
<h2>Gyroscope</h2><table>{head_t}{_param_rows(GYRO_PARAM_NAMES, c.gyro_params, res.std_gyro, truth_gyro)}</table>
<p>Gyro bias: {np.array2string(c.gyro.b, precision=6)} (raw units)</p>
{g_sens}
<h2>Cross-validation: poses the calibration did not see</h2>{cv_html}
<h2>Threshold sweep</h2><table><tr><th>k</th><th>intervals</th><th>residual / sample</th><th>solved</th></tr>{sweep}</table>
<h2>Static detection</h2><img src="static_detection.png" width="100%">
<h2>Residuals before and after</h2><img src="residuals.png" width="100%">
<h2>Sweep</h2><img src="sweep.png">
{extra_html}
</body></html>
"""
    write_atomic(out / "report.html", doc)
    return [out / n for n in files] + [out / "report.html"]
