"""Online calibration on a simulated robot whose IMU errors drift over an hour; calibration history."""

import os
from pathlib import Path

import numpy as np
import pytest

from imuslam.imu.calibrate import CalibrationConfig
from imuslam.imu.history import CalibrationHistory
from imuslam.imu.online import OnlineConfig, StillDetector
from imuslam.imu.online_sim import T0_NS, Drift, run_simulated_robot
from imuslam.imu.static import windowed_variance_norm
from imuslam.sim.multipose import sphere_plan_deg

CFG = OnlineConfig(calibration=CalibrationConfig(t_init_s=20.0))
CHI2_9_999 = 27.88  # 99.9 % quantile of chi-square with 9 degrees of freedom


def _run(drift: Drift, seed: int, tmp_path: Path | None = None):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    hist = CalibrationHistory(tmp_path) if tmp_path else None
    return run_simulated_robot(sphere_plan_deg(24, rng), 3600.0, drift, rng, CFG, hist)


def test_no_trigger_below_threshold() -> None:
    """z accelerometer bias drifting 0.02 m/s^2 in the hour: below the 0.03 m/s^2 threshold, never flagged."""
    run = _run(Drift(accel_bias_per_h=np.array([0.0, 0.0, 0.02])), 1)
    kinds = [e.kind for e in run.calibrator.events]
    assert kinds.count("calibrated") == 1 and "drift" not in kinds
    assert len(run.calibrator.drift_stats) >= 10


def test_trigger_above_threshold_and_track_truth(tmp_path: Path) -> None:
    """0.05 m/s^2 per hour on z (plus gyro bias and scale drift): the monitor fires only once the true
    gravity-norm error exceeds 0.03 m/s^2, the robot recalibrates, and every calibration agrees with the
    truth of its session within its covariance (chi-square, 9 dof, 99.9 %)."""
    drift = Drift(
        accel_bias_per_h=np.array([0.0, 0.0, 0.05]),
        gyro_bias_per_h=np.full(3, 0.001),
        scale_per_h=2e-4,
    )
    run = _run(drift, 2, tmp_path)
    cal = run.calibrator
    ev = [e for e in cal.events if e.kind == "drift"]
    assert len(ev) >= 1
    first = (ev[0].t_ns - T0_NS) * 1e-9
    truth = drift.truth_at(first)
    session_cal = CalibrationHistory(tmp_path).load(1)
    # true gravity-norm error of the first calibration at home pose (z up) when it fired
    raw = truth.accel.invert(np.array([[0.0, 0.0, 9.80665]]))
    true_err = abs(np.linalg.norm(session_cal.correct_accel(raw)) - 9.80665)
    assert true_err > CFG.max_norm_error
    # no drift event while the true error was below the threshold
    for s in cal.drift_stats:
        if s["t_s"] - T0_NS * 1e-9 < first:
            r = drift.truth_at(s["t_s"] - T0_NS * 1e-9).accel.invert(
                np.array([[0.0, 0.0, 9.80665]])
            )
            assert (
                abs(np.linalg.norm(session_cal.correct_accel(r)) - 9.80665)
                < CFG.max_norm_error + 0.01
            )
    versions = CalibrationHistory(tmp_path).versions()
    assert len(versions) == len(run.sessions) >= 2
    for v, (t0, t1) in zip(versions, run.sessions, strict=True):
        c = CalibrationHistory(tmp_path).load(v)
        tr = drift.truth_at(0.5 * (t0 + t1))
        e = c.accel_params - tr.accel_params
        assert c.cov_accel is not None and e @ np.linalg.solve(c.cov_accel, e) < CHI2_9_999
        eg = c.gyro_params - tr.gyro_params
        assert c.cov_gyro is not None and eg @ np.linalg.solve(c.cov_gyro, eg) < CHI2_9_999
        # Each version carries its cross-validated score: held-out poses at the BWT901CL noise floor
        # (~0.03 deg per pair, ~0.002 m/s^2 per pose; twice that for the parameters' own error).
        cv = c.notes["cross_validation"]
        assert cv["folds"] == 5 and cv["poses"] >= 20
        assert 0 < cv["direction_rms_deg"] < 0.1 and 0 < cv["norm_rms_mps2"] < 0.005


def test_streaming_detector_equals_batch() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 3)) + 100.0
    det = StillDetector(101)
    s = np.array([det.push(v) for v in x])
    ref = windowed_variance_norm(x, 50)
    # the streaming value at sample k is the batch value centred 50 samples earlier
    np.testing.assert_allclose(s[100:], ref[50:-50], rtol=1e-9)


def test_history_lookup_and_crash_safety(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from imuslam.imu.model import ImuCalibration, TriadModel
    from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO

    h = CalibrationHistory(tmp_path)
    for i, date in enumerate(["2026-01-01T00:00:00+00:00", "2026-03-01T00:00:00+00:00"]):
        c = ImuCalibration(TriadModel(SEED000_ACCEL.T, SEED000_ACCEL.K * (1 + i), SEED000_ACCEL.b),
                           TriadModel(SEED000_GYRO.T, SEED000_GYRO.K, SEED000_GYRO.b), date=date)  # fmt: skip
        assert h.add(c) == i + 1
    assert h.in_force("2026-02-01T00:00:00+00:00").accel.K[0] == SEED000_ACCEL.K[0]  # type: ignore[union-attr]
    assert h.closest("2026-02-20T00:00:00+00:00").accel.K[0] == 2 * SEED000_ACCEL.K[0]  # type: ignore[union-attr]
    assert h.in_force("2025-12-31T00:00:00+00:00") is None

    def boom(*_: object) -> None:
        raise OSError("power cut")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="power cut"):
        h.add(h.load(2))
    monkeypatch.undo()
    assert h.versions() == [1, 2]
    assert h.latest().accel.K[0] == 2 * SEED000_ACCEL.K[0]  # type: ignore[union-attr]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "v0001.yaml",
        "v0002.yaml",
    ]  # no leftovers


def test_without_gimbal_gyro_bias_refreshed_from_still_moments() -> None:
    """No gimbal: the gyro bias drifts by 0.01 rad/s; a still moment flags it and the bias alone is
    re-estimated, to the accuracy its still moment allows (noise 1.75e-3 rad/s / sqrt(600): 7e-5 rad/s)."""
    from imuslam.imu.model import ImuCalibration, TriadModel
    from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO
    from imuslam.sim.multipose import GimbalImuStream

    drift = Drift(gyro_bias_per_h=np.array([0.01, -0.01, 0.005]))
    rng = np.random.default_rng(4)
    stream = GimbalImuStream(rng, drift.errors_at)
    start = ImuCalibration(TriadModel(SEED000_ACCEL.T, SEED000_ACCEL.K, SEED000_ACCEL.b),
                           TriadModel(SEED000_GYRO.T, SEED000_GYRO.K, SEED000_GYRO.b))  # fmt: skip
    from imuslam.imu.online import OnlineCalibrator

    cal = OnlineCalibrator(sphere_plan_deg(24), None, CFG, current=start)
    stream.skip(3600.0)
    t, a, w = stream.read(600)
    for i in range(len(t)):
        cal.step(int(t[i]), a[i], w[i])
    cal._end_still(int(t[-1]))
    kinds = [e.kind for e in cal.events]
    assert "drift" in kinds and "calibrated" in kinds
    true_b = drift.errors_at(3600.0)[1].b
    assert cal.current is not None
    np.testing.assert_allclose(cal.current.gyro.b, true_b, atol=5 * 7e-5 * 1.04)
    np.testing.assert_array_equal(cal.current.accel.K, start.accel.K)
