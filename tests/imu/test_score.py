"""imuslam score: the score of calibrations on a log, against simulated truth and imu_tk's published result."""

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.imu.score import detect_poses, score_calibrations
from imuslam.interfaces.imu import ImuLog, InputError
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg

runner = CliRunner()

# imu_tk's parameters on its xsens log (../shared/data/README.md), as imu_tk writes them.
XSENS_ACC = ("1 -0.0033593 -0.00890639\n0 1 -0.0213341\n0 0 1\n\n"
             "0.00241278 0 0\n0 0.00242712 0\n0 0 0.00241168\n\n33124.2\n33275.2\n32364.4\n")  # fmt: skip
XSENS_GYRO = ("1 0.00593634 0.00111101\n0.00808812 1 -0.0535569\n0.0253067 -0.0025513 1\n\n"
              "0.000209295 0 0\n0 0.000209899 0\n0 0 0.000209483\n\n32777.1\n32459.8\n32511.8\n")  # fmt: skip


def _truth() -> ImuCalibration:
    return ImuCalibration(
        TriadModel(SEED000_ACCEL.T, SEED000_ACCEL.K, SEED000_ACCEL.b),
        TriadModel(SEED000_GYRO.T, SEED000_GYRO.K, SEED000_GYRO.b),
    )


@pytest.fixture(scope="module")
def sim_log() -> ImuLog:
    rng = np.random.default_rng(11)
    return simulate_multipose(sphere_plan_deg(20, rng), rng).log


def test_true_calibration_scores_at_the_noise_and_errors_show(sim_log: ImuLog) -> None:
    """The true parameters score at the noise level; a 1 % accel scale error gives |a| - g = 0.01 g on
    every pose; a 1 % gyro scale error turns each 40-180 deg rotation into a 0.4-1.8 deg direction error."""
    truth = _truth()
    acc_scaled = ImuCalibration(
        TriadModel(truth.accel.T, truth.accel.K * 1.01, truth.accel.b), truth.gyro
    )
    gyro_scaled = ImuCalibration(
        truth.accel, TriadModel(truth.gyro.T, truth.gyro.K * 1.01, truth.gyro.b)
    )
    res = score_calibrations(sim_log, [("truth", truth), ("acc", acc_scaled), ("gyro", gyro_scaled)], 9.80665)  # fmt: skip
    assert len(res.poses) == 20
    t, a, gs = res.scores
    # BWT901CL-class noise: 0.029 m/s^2 per sample, >= 100 samples per pose -> <= 0.003 per pose mean;
    # gyro 1.75e-3 rad/s per sample at 100 Hz over <= 8 s -> <= 5e-4 rad plus two pose directions.
    assert t.norm_rms < 0.004
    assert t.direction_rms_deg < 0.08
    assert a.norm_rms == pytest.approx(0.01 * 9.80665, rel=0.05)
    assert a.direction_rms_deg == pytest.approx(t.direction_rms_deg, abs=0.01)  # isotropic scale
    assert gs.direction_rms_deg > 0.4 and gs.norm_rms == pytest.approx(t.norm_rms)


def test_imutk_xsens_score_matches_its_published_direction_error(
    shared_data: Path, tmp_path: Path
) -> None:
    """imu_tk reports about 0.5 deg of gravity-direction error per pair of poses on its xsens log."""
    (tmp_path / "acc.calib").write_text(XSENS_ACC)
    (tmp_path / "gyro.calib").write_text(XSENS_GYRO)
    d = shared_data / "imu_tk_xsens"
    out = tmp_path / "score"
    r = runner.invoke(
        app,
        ["score", str(d / "xsens_acc.mat"), "--gyro", str(d / "xsens_gyro.mat"),
         str(tmp_path / "acc.calib"), str(tmp_path / "gyro.calib"), "--g", "9.81744", "--out", str(out)],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    rows = (out / "scores.csv").read_text().splitlines()
    assert len(rows) == 2
    norm_rms, _, dir_rms, _ = (float(v) for v in rows[1].split(",")[1:])
    assert dir_rms == pytest.approx(0.5, abs=0.1)
    # Its per-sample RMS of |a| - g is 0.00795 m/s^2; the mean over >= 100 samples per pose is lower.
    assert norm_rms < 0.00795
    assert (out / "score.png").stat().st_size > 10_000
    assert (
        len((out / "pairs.csv").read_text().splitlines())
        == len((out / "poses.csv").read_text().splitlines()) - 1
    )


def test_calibration_for_other_units_is_one_clear_line(shared_data: Path, tmp_path: Path) -> None:
    """imu_tk's xsens calibration (raw counts) on the t265 log (m/s^2): the gravity norm is off by 1e3."""
    (tmp_path / "acc.calib").write_text(XSENS_ACC)
    (tmp_path / "gyro.calib").write_text(XSENS_GYRO)
    d = shared_data / "imu_tk_t265"
    r = runner.invoke(
        app,
        ["score", str(d / "t265_acc.mat"), "--gyro", str(d / "t265_gyr.mat"),
         str(tmp_path / "acc.calib"), str(tmp_path / "gyro.calib")],
    )  # fmt: skip
    assert r.exit_code == 2
    err = " ".join(r.output.split())  # one message (the terminal may wrap it)
    assert err.count("error:") == 1 and "Traceback" not in err
    assert "other units" in err and "acc.calib" in err


def test_yaml_unit_fields_must_match_the_log(sim_log: ImuLog) -> None:
    cal = _truth()
    cal.accel_unit = "counts"
    poses = detect_poses(sim_log)
    with pytest.raises(InputError, match="calibration for accel in counts"):
        score_calibrations(sim_log, [("counts.yaml", cal)], 9.80665)
    assert len(poses) == 20


def test_log_without_static_poses_is_refused() -> None:
    """Still for 60 s, then turning all the time: no static pose to score."""
    rng = np.random.default_rng(5)
    n = 9000
    t = np.arange(n) * 0.01
    moving = t >= 60.0
    ang = np.where(moving, 0.8 * (t - 60.0) + 0.3 * np.sin(2.1 * t), 0.0)
    acc = np.stack([9.80665 * np.sin(ang), np.zeros(n), 9.80665 * np.cos(ang)], axis=1)
    acc += rng.normal(size=(n, 3)) * 0.03
    gyro = np.zeros((n, 3)) + rng.normal(size=(n, 3)) * 2e-3
    log = ImuLog((t * 1e9).astype(np.int64), acc, gyro, source="turning.csv")
    with pytest.raises(InputError, match=r"turning.csv: 1 static poses found"):
        score_calibrations(log, [("truth", _truth())], 9.80665)
