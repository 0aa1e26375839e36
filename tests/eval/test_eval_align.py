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
    res = evaluate(ref, est, "yaw")
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
    """Constant velocity and constant angular rate, p(t) = p0 + v t and R(t) = R0 exp(w t), sampled at
    irregular stamps and queried at random times between them: linear position and slerp reproduce the
    motion itself (computed here from its closed form), to rounding."""
    rng = np.random.default_rng(3)
    t0 = 1_700_000_000_000_000_000
    t_ns = t0 + np.cumsum(rng.integers(20_000_000, 80_000_000, size=200)).astype(np.int64)
    p0, v = np.array([1.0, -2.0, 0.5]), np.array([0.8, 0.3, -0.1])
    R0, w = exp(np.array([0.3, -0.2, 1.0])), np.array([0.05, -0.1, 0.4])

    def motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ts = (t - t0) * 1e-9
        return p0 + ts[:, None] * v, R0 @ exp(ts[:, None] * w)

    p, R = motion(t_ns)
    ref = Trajectory(t_ns, p, R, "linear")
    q = np.sort(rng.integers(t_ns[0], t_ns[-1], size=500)).astype(np.int64)
    it = interpolate(ref, q)
    p_true, R_true = motion(q)
    np.testing.assert_allclose(it.p_w, p_true, atol=1e-9)
    np.testing.assert_allclose(it.R_w_b, R_true, atol=1e-9)


def _straight_line(n: int, R: np.ndarray | None = None, scale: float = 1.0) -> Trajectory:
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    p = np.zeros((n, 3))
    p[:, 0] = scale * np.arange(n)  # 1 m per frame along x
    return Trajectory(t, p, np.tile(np.eye(3), (n, 1, 1)) if R is None else R, "line")


def test_kitti_drift_on_hand_computed_cases() -> None:
    """1001 frames 1 m apart along x. By the KITTI devkit's rules (segments start every 10th frame and end
    at the first frame more than L metres on), a 100 m segment starting at frame s ends at s + 101, so
    starts 0..890 fit: 90 segments; 800 m: starts 0..190, 20 segments. The devkit divides a segment's
    error by L, not by its length L + 1: an estimate 1 % too long drifts 1 % x (L + 1) / L and 0 deg/m; one
    that rolls 0.001 rad per frame about the direction of travel keeps every translation and drifts 0 % and
    0.001 (L + 1) / L rad/m (0.0573 deg/m x (L + 1) / L)."""
    from imuslam.eval.metrics import kitti_drift

    ref = _straight_line(1001)
    long = kitti_drift(ref, _straight_line(1001, scale=1.01))
    assert long[100.0][2] == 90 and long[800.0][2] == 20
    for L, (tp, rd, _) in long.items():
        assert tp == pytest.approx(1.0 * (L + 1) / L, rel=1e-9), L
        assert rd == pytest.approx(0.0, abs=1e-9), L
    roll = exp(np.outer(np.arange(1001) * 0.001, [1.0, 0.0, 0.0]))
    rolled = kitti_drift(ref, _straight_line(1001, R=roll))
    for L, (tp, rd, _) in rolled.items():
        assert tp == pytest.approx(0.0, abs=1e-9)
        # the devkit's angle of a segment of L + 1 frames: 0.001 (L + 1) rad, over L metres
        assert rd == pytest.approx(np.rad2deg(0.001 * (L + 1)) / L, rel=1e-6), L


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
