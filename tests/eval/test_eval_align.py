"""Alignment on synthetic cases with known offsets, trajectory file round trips, and bad input."""

from pathlib import Path

import numpy as np
import pytest

from imuslam.errors import InputError
from imuslam.eval.align import align, apply
from imuslam.eval.associate import interpolate
from imuslam.eval.metrics import evaluate
from imuslam.geometry import exp
from imuslam.interfaces.trajectory import Trajectory
from imuslam.io.trajectory import read_kitti, read_trajectory, read_tum, write_kitti, write_tum


def _traj(n: int = 300, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_000
    s = np.linspace(0, 6 * np.pi, n)
    p = np.stack([5 * np.cos(s), 3 * np.sin(2 * s), 0.5 * np.sin(s) + 1], axis=1)
    R = exp(np.cumsum(rng.normal(size=(n, 3)) * 0.02, axis=0))
    return Trajectory(t, p, R, "synthetic")


def _rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_yaw_alignment_recovers_known_4dof_offset() -> None:
    ref = _traj()
    R0, t0 = _rz(0.7), np.array([3.0, -2.0, 0.4])
    # est expressed in a frame rotated by yaw and shifted: p_ref = R0 p_est + t0
    est = Trajectory(ref.t_ns, (ref.p_w - t0) @ R0, R0.T @ ref.R_w_b, "est")
    s, R, t = align(ref, est, "yaw")
    np.testing.assert_allclose(R, R0, atol=1e-12)
    np.testing.assert_allclose(t, t0, atol=1e-12)
    res, _, _ = evaluate(ref, est, "yaw")
    assert res.ape_trans.max < 1e-10 and res.ape_rot_deg.max < 1e-6


def test_yaw_alignment_ignores_roll_pitch_noise_and_keeps_gravity() -> None:
    """An estimate with noisy positions: yaw-only never tilts the estimate (R stays about z), while the
    SE(3) fit would; the recovered yaw is within the noise level."""
    ref = _traj()
    rng = np.random.default_rng(1)
    R0, t0 = _rz(-1.2), np.array([1.0, 2.0, 0.0])
    noisy = ref.p_w + rng.normal(size=ref.p_w.shape) * 0.05
    est = Trajectory(ref.t_ns, (noisy - t0) @ R0, R0.T @ ref.R_w_b, "est")
    _, R, _ = align(ref, est, "yaw")
    assert R[2, 2] == 1.0 and R[0, 2] == 0.0
    # yaw error ~ noise / (spread of points * sqrt(n)) ~ 0.05 / (4 * 17) = 7e-4 rad; allow 5 sigma
    assert abs(np.arctan2(R[1, 0], R[0, 0]) + 1.2) < 5e-3


def test_sim3_recovers_scale() -> None:
    ref = _traj()
    R0 = exp(np.array([0.3, -0.2, 1.0]))
    est = Trajectory(ref.t_ns, 0.5 * (ref.p_w @ R0), R0.T @ ref.R_w_b, "est")
    s, R, t = align(ref, est, "sim3")
    assert s == pytest.approx(2.0, rel=1e-12)
    np.testing.assert_allclose(apply(est, s, R, t).p_w, ref.p_w, atol=1e-10)


def test_interpolation_is_exact_on_linear_motion() -> None:
    ref = _traj()
    mid = (ref.t_ns[:-1] + ref.t_ns[1:]) // 2
    it = interpolate(ref, mid)
    np.testing.assert_allclose(it.p_w, 0.5 * (ref.p_w[:-1] + ref.p_w[1:]), atol=1e-12)


def test_round_trips(tmp_path: Path) -> None:
    ref = _traj()
    write_tum(ref, tmp_path / "a.tum")
    write_kitti(ref, tmp_path / "a.kitti")
    a = read_tum(tmp_path / "a.tum")
    k = read_kitti(tmp_path / "a.kitti")
    np.testing.assert_allclose(a.p_w, ref.p_w, atol=1e-8)
    np.testing.assert_allclose(a.R_w_b, ref.R_w_b, atol=1e-8)
    assert np.max(np.abs(a.t_ns - ref.t_ns)) <= 512
    np.testing.assert_allclose(k.R_w_b, ref.R_w_b, atol=1e-8)


def test_bad_input(tmp_path: Path) -> None:
    ref = _traj()
    write_tum(ref, tmp_path / "a.tum")
    with pytest.raises(InputError, match="unknown trajectory format"):
        read_trajectory(tmp_path / "a.tum", "g2o")
    late = Trajectory(ref.t_ns + 10**12, ref.p_w, ref.R_w_b, "late")
    with pytest.raises(InputError, match="do not overlap"):
        evaluate(ref, late)
    sparse = Trajectory(ref.t_ns[:2], ref.p_w[:2], ref.R_w_b[:2], "two")
    with pytest.raises(InputError, match="associated"):
        evaluate(ref, sparse)
    p = ref.p_w.copy()
    p[5, 1] = np.nan
    with pytest.raises(InputError, match="pose 5"):
        Trajectory(ref.t_ns, p, ref.R_w_b, "nan")
    (tmp_path / "nan.tum").write_text("1.0 0 0 0 0 0 0 1\n2.0 nan 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match="line 2"):
        read_tum(tmp_path / "nan.tum")
