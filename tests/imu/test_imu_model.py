"""The error model: apply/invert, sign conventions, YAML and imu_tk .calib round trips, the RK4 kernel."""

from pathlib import Path

import numpy as np
import pytest
from rk4_reference import rk4_integrate_gyro

from imuslam.errors import InputError
from imuslam.geometry import quat_to_matrix
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.imu.rk4 import integrate_segments
from imuslam.interfaces.imu import ImuLog
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO, raw_from_errors


def _calib() -> ImuCalibration:
    a, g = SEED000_ACCEL, SEED000_GYRO
    return ImuCalibration(
        TriadModel(a.T, a.K, a.b, "plus"),
        TriadModel(g.T, g.K, g.b, "plus"),
        cov_accel=np.diag(np.arange(1.0, 10.0)) * 1e-8,
        cov_gyro=np.eye(9) * 1e-7,
        sensor_id="bwt901cl-1",
    )


def test_apply_inverts_the_simulated_sensor() -> None:
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(100, 3)) * 9.8
    c = _calib()
    raw = raw_from_errors(truth, SEED000_ACCEL)
    np.testing.assert_allclose(c.accel.apply(raw), truth, atol=1e-12)
    np.testing.assert_allclose(c.accel.invert(truth), raw, atol=1e-12)
    minus = c.accel.with_sign("minus")
    np.testing.assert_allclose(minus.apply(raw), truth, atol=1e-12)


def test_yaml_round_trip(tmp_path: Path) -> None:
    c = _calib()
    c.save_yaml(tmp_path / "c.yaml")
    d = ImuCalibration.load_yaml(tmp_path / "c.yaml")
    for a, b in ((c.accel, d.accel), (c.gyro, d.gyro)):
        np.testing.assert_array_equal(a.T, b.T)
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.b, b.b)
    np.testing.assert_array_equal(c.cov_accel, d.cov_accel)
    assert d.sensor_id == "bwt901cl-1" and d.date == c.date


def test_imutk_calib_round_trip(tmp_path: Path) -> None:
    c = _calib()
    c.export_imutk(tmp_path / "acc.calib", tmp_path / "gyro.calib")
    d = ImuCalibration.import_imutk(
        tmp_path / "acc.calib", tmp_path / "gyro.calib", "m/s^2", "rad/s"
    )
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 3))
    np.testing.assert_allclose(d.accel.apply(x), c.accel.apply(x), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(d.gyro.apply(x), c.gyro.apply(x), rtol=1e-9, atol=1e-9)
    text = (tmp_path / "acc.calib").read_text().split("\n\n")
    assert len([t for t in text if t.strip()]) == 3  # T, K, B blocks as imu_tk writes them


def test_bad_calibration_files(tmp_path: Path) -> None:
    p = tmp_path / "bad.calib"
    p.write_text("1 0 0\n0 1 0\n")
    with pytest.raises(InputError, match="21 numbers"):
        TriadModel.load_imutk(p)
    y = tmp_path / "bad.yaml"
    y.write_text("accel: {T: [[1,0],[0,1]], K: [1,1,1], b: [0,0,0]}\ngyro: {}\n")
    with pytest.raises(InputError, match="field 'accel'"):
        ImuCalibration.load_yaml(y)


def test_correct_checks_units() -> None:
    c = _calib()
    log = ImuLog(np.arange(3), np.zeros((3, 3)), np.zeros((3, 3)), "counts", "counts", "x.txt")
    with pytest.raises(InputError, match="x.txt"):
        c.correct(log)


def test_numba_rk4_kernel_matches_reference() -> None:
    """The compiled segment integrator equals the vectorised reference in imuslam.geometry."""
    rng = np.random.default_rng(2)
    n = 400
    t = np.cumsum(rng.uniform(0.009, 0.011, n))
    w = np.cumsum(rng.normal(size=(n, 3)) * 0.05, axis=0)
    segs = np.array([[0, 120], [100, 399], [250, 260]])
    M = np.eye(3) + rng.normal(size=(3, 3)) * 0.02
    R = integrate_segments(w, t, segs, M[None])[0]
    for s, (a, b) in enumerate(segs):
        q = rk4_integrate_gyro(w[a : b + 1] @ M.T, np.diff(t[a : b + 1]))
        np.testing.assert_allclose(R[s], quat_to_matrix(q), atol=1e-12)


# Tedaldi 2014 eq. 3, written out here independently of the code: the matrix entry each angle occupies
# and its sign. T = [[1, -yz, zy], [xz, 1, -zx], [-xy, yx, 1]].
_TEDALDI_ENTRY = {
    "g_yz": ((0, 1), -1.0),
    "g_zy": ((0, 2), 1.0),
    "g_xz": ((1, 0), 1.0),
    "g_zx": ((1, 2), -1.0),
    "g_xy": ((2, 0), -1.0),
    "g_yx": ((2, 1), 1.0),
}


@pytest.mark.parametrize("name", sorted(_TEDALDI_ENTRY))
def test_gyro_parameter_names_match_the_matrix_entries(name: str, tmp_path: Path) -> None:
    """A gyro T with one non-zero angle (0.01 rad) is reported under that angle's name in calibration.yaml,
    every other angle zero."""
    import yaml

    (i, j), sign = _TEDALDI_ENTRY[name]
    T = np.eye(3)
    T[i, j] = sign * 0.01
    c = ImuCalibration(TriadModel(), TriadModel(T, np.ones(3), np.zeros(3)))
    c.save_yaml(tmp_path / "calibration.yaml")
    d = yaml.safe_load((tmp_path / "calibration.yaml").read_text())
    reported = dict(zip(d["gyro_param_names"], d["gyro_params"], strict=True))
    for other in _TEDALDI_ENTRY:
        assert reported[other] == pytest.approx(0.01 if other == name else 0.0, abs=1e-15), other
