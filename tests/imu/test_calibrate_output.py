"""What ``calibrate``'s pictures and terminal say: residuals.png titled, every series named with its RMS
(the log as recorded included, so the calibration's gain shows), the chosen k marked in sweep.png, the
observability verdict printed, the help naming the default method."""

from __future__ import annotations

import numpy as np
import pytest

from imuslam.imu.calibrate import CalibrationConfig, CalibrationResult, calibrate
from imuslam.imu.report import plot_residuals, plot_sweep
from imuslam.interfaces.imu import ImuLog
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg


@pytest.fixture(scope="module")
def run() -> tuple[CalibrationResult, ImuLog]:
    rng = np.random.default_rng(3)
    sim = simulate_multipose(sphere_plan_deg(36, rng), rng)
    return calibrate(sim.log, CalibrationConfig(g=sim.truth.g, method="tedaldi")), sim.log


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_residuals_are_titled_and_every_series_named_with_its_rms(
    run: tuple[CalibrationResult, ImuLog],
) -> None:
    res, log = run
    fig = plot_residuals(res, log)
    assert fig.get_suptitle().startswith("Residuals before and after calibration")
    top, bottom = fig.axes
    assert top.get_title() and bottom.get_title()
    labels = top.get_legend_handles_labels()[1]
    assert [lab.split(":")[0] for lab in labels] == [
        "as recorded", "per-axis scale + offset (the fit's start)", "calibrated",
    ]  # fmt: skip
    g = res.calibration.g
    raw = [np.mean(np.linalg.norm(log.accel[s : e + 1], axis=1)) - g for s, e in res.intervals]
    rms = [_rms(np.asarray(raw)), _rms(res.accel_residual_before), _rms(res.accel_residual_after)]
    for lab, r in zip(labels, rms, strict=True):
        assert lab.endswith(f"RMS {r:.3g} m/s^2")
    # the simulated sensor's scale and bias errors are what the calibration removes: the log as
    # recorded is far off gravity, the calibrated one within the noise of an interval's mean
    assert rms[0] > 20 * rms[2]
    # the bars are the magnitudes of those residuals, interval by interval
    heights = [p.get_height() for p in top.patches]
    n = len(res.intervals)
    assert np.allclose(heights[2 * n : 3 * n], np.abs(res.accel_residual_after))
    assert [lab.split(":")[0] for lab in bottom.get_legend_handles_labels()[1]] == [
        "bias removed, unit scale", "calibrated",
    ]  # fmt: skip


def test_a_log_in_counts_has_no_as_recorded_series(run: tuple[CalibrationResult, ImuLog]) -> None:
    res, log = run
    counts = ImuLog(log.t_ns, log.accel * 100, log.gyro, "counts", "rad/s", log.source)
    labels = plot_residuals(res, counts).axes[0].get_legend_handles_labels()[1]
    assert not any(lab.startswith("as recorded") for lab in labels)


def test_the_chosen_k_is_marked_and_named_in_the_sweep(
    run: tuple[CalibrationResult, ImuLog],
) -> None:
    res, _ = run
    ax = plot_sweep(res).axes[0]
    chosen = [ln for ln in ax.get_lines() if ln.get_label().startswith("chosen k")]
    assert len(chosen) == 1
    assert chosen[0].get_xdata()[0] == res.k
    assert chosen[0].get_label() == f"chosen k = {res.k:g} (lowest residual)"
    best = min(res.sweep, key=lambda r: r.residual_per_sample)
    assert best.k == res.k
    assert "chosen k" in " ".join(t.get_text() for t in ax.get_legend().get_texts())


def test_the_observability_verdict_names_the_poor_parameters(
    run: tuple[CalibrationResult, ImuLog],
) -> None:
    from dataclasses import replace

    from imuslam.cli.calibrate import observability_line

    res, _ = run
    assert observability_line(res).startswith("observability: every parameter determined")
    poor = replace(res, poorly_determined=["g_zx", "s_gz"])
    assert "poorly determined: g_zx, s_gz" in observability_line(poor)


def test_the_help_names_the_default_method() -> None:
    from typer.testing import CliRunner

    from imuslam.cli import app

    text = " ".join(
        CliRunner().invoke(app, ["calibrate", "--help"], env={"COLUMNS": "300"}).output.split()
    )
    assert "a joint fit of both (default)" in text
    assert "Tedaldi 2014, imu_tk's method)" not in text


def test_the_terminal_names_each_count_and_norm(
    run: tuple[CalibrationResult, ImuLog], monkeypatch: pytest.MonkeyPatch
) -> None:
    import io

    from rich.console import Console

    from imuslam.cli import calibrate as cli_calibrate

    res, _ = run
    buf = io.StringIO()
    monkeypatch.setattr(cli_calibrate, "console", Console(file=buf, width=200, emoji=False))
    cli_calibrate.print_result(res)
    text = buf.getvalue()
    row = next(
        ln for ln in text.splitlines() if "static intervals the fit used (detected at k)" in ln
    )
    assert f" {len(res.intervals)} " in row
    row = next(ln for ln in text.splitlines() if "|a| - g, RMS over every static sample" in ln)
    assert f"{res.accel_rms:.5f}" in row and "m/s^2" in row
    assert "observability:" in text
