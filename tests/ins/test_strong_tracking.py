"""Strong tracking (STKF): when its fading factor acts, and that it helps where the plain KF's model breaks.

The fading factor of Zhou & Frank (Int. J. Control 64(6), 1996), lambda = max(1, tr N / tr M) with
N = V - H Q H^T - beta R and M = H Phi P Phi^T H^T, exceeds 1 only when the innovations' covariance V
exceeds the predicted one H P H^T + R by (beta - 1) tr R: innovations at or below their predicted size
(a mean NIS of 3 or less for a position fix) leave the filter a plain KF.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from imuslam.geometry import exp as so3_exp
from imuslam.ins.align import Aiding, run_alignment
from imuslam.ins.core import ErrorLayout, kalman_update
from imuslam.ins.kf import KfNoise
from imuslam.interfaces.nav import NavState
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.imu_errors import TriadErrors
from imuslam.sim.trajectory import Handheld

G = 9.80665
BA = np.array([0.06, -0.04, 0.09])  # measured = true + bias
BG = np.array([0.003, -0.002, 0.004])
NOISE = KfNoise(3e-3, 2e-4, 1e-5, 1e-6)  # the simulated densities, small bias walks


def _case(seed: int, duration: float, fix_std: float):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    spec = ImuErrorSpec(TriadErrors(np.eye(3), np.ones(3), BA, "minus"),
                        TriadErrors(np.eye(3), np.ones(3), BG, "minus"), 3e-3, 2e-4)  # fmt: skip
    traj = Handheld()
    log, truth = simulate_imu(traj, duration, rng, spec, 200.0, g=G)
    ta = np.arange(0.1, duration, 0.1)
    fixes = traj.state(ta).p_w + rng.normal(size=(len(ta), 3)) * fix_std
    return log, truth, ta, fixes


def test_fading_factor_is_zhou_frank() -> None:
    """One update with known numbers: the factor is max(1, tr N / tr M) (capped), and the update is the
    Kalman update of lambda (P - Q) + Q; an innovation at its predicted size leaves it at 1."""
    lay = ErrorLayout.full()
    m = 15
    ip = lay.offsets[1]
    P = np.diag(lay.diag(theta=1e-4, p=4e-4, v=1e-3, ba=1e-2, bg=1e-4))
    Q = np.diag(lay.diag(theta=1e-8, p=1e-6, v=1e-5, ba=1e-9, bg=1e-10))
    H = np.zeros((3, m))
    H[:, ip : ip + 3] = np.eye(3)
    Rm = np.eye(3) * 0.01**2
    trS = np.trace(H @ P @ H.T + Rm)  # 3 x 5e-4
    trM = np.trace(H @ (P - Q) @ H.T)  # 3 x 3.99e-4
    V = np.zeros((3, 3))
    # the innovation of the predicted size: tr N = tr S - tr HQH - 3 tr R = tr M - 2 tr R < tr M
    r = np.full(3, np.sqrt(trS / 3))
    dx, P1, _, lam = kalman_update(P, Q, r, H, Rm, True, V, False, 0.95, 3.0, 5.0)
    dx0, P0, _, _ = kalman_update(P, Q, r, H, Rm, False, V, False, 0.95, 3.0, 5.0)
    assert lam == 1.0 and np.array_equal(P1, P0) and np.array_equal(dx, dx0)
    # three times the predicted variance: lambda = (3 tr S - tr HQH - 3 tr R) / tr M
    r = np.full(3, np.sqrt(trS))
    want = (3 * trS - np.trace(H @ Q @ H.T) - 3.0 * np.trace(Rm)) / trM
    dx, P1, _, lam = kalman_update(P, Q, r, H, Rm, True, V, False, 0.95, 3.0, 5.0)
    assert 1.0 < want < 5.0 and abs(lam - want) < 1e-12
    Pf = want * (P - Q) + Q
    S = H @ Pf @ H.T + Rm
    K = Pf @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(dx, K @ r, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(P1, (np.eye(m) - K @ H) @ Pf, rtol=1e-8, atol=1e-14)
    # the cap
    _, _, _, lam = kalman_update(P, Q, 10 * r, H, Rm, True, V, False, 0.95, 3.0, 5.0)
    assert lam == 5.0


def test_overstated_fix_noise_keeps_strong_tracking_off() -> None:
    """Fixes good to 2 mm, stated as 2 cm (the LIO's alignment: LiDAR-registered positions given the
    range noise's 1-sigma): the NIS is far below chi-square(3), the factor never exceeds 1 and the STKF is
    the KF (to rounding). Stated right, the NIS is chi-square(3) (99.9 % band of the mean)."""
    log, truth, ta, fixes = _case(5, 20.0, 0.002)
    init = NavState(truth.p_w[0], truth.vel_w[0], truth.R_w_i[0])
    n_tail = len(ta) - 20  # the first 2 s: the prior's transient
    lo, hi = chi2.ppf(0.0005, 3 * n_tail) / n_tail, chi2.ppf(0.9995, 3 * n_tail) / n_tail
    right = run_alignment(log, Aiding(ta, "position", fixes, 0.002), init, "kf", NOISE, g=G)
    assert lo < np.mean(right.nis[20:]) < hi
    over = {m: run_alignment(log, Aiding(ta, "position", fixes, 0.02), init, m, NOISE, g=G)  # type: ignore[arg-type]
            for m in ("kf", "stkf")}  # fmt: skip
    # innovations ~ the 2 mm noise plus the prediction's, against a predicted 2 cm: NIS ~ 3 (2/20)^2 x a few
    assert np.mean(over["kf"].nis[20:]) < lo / 10
    assert np.all(over["stkf"].fading == 1.0)
    # lambda = 1 still recomputes 1 (P - Q) + Q: the two differ by rounding only
    np.testing.assert_allclose(over["stkf"].accel_bias, over["kf"].accel_bias, rtol=0, atol=1e-12)
    np.testing.assert_allclose(over["stkf"].R_n_b, over["kf"].R_n_b, rtol=0, atol=1e-12)


def test_strong_tracking_recovers_from_a_heading_error_beyond_the_linear_range() -> None:
    """A 30 deg initial heading error (ten times the prior's 2.9 deg 1-sigma: the small-angle model is
    wrong at the start) over 20 s of hand motion with 1 cm fixes: the KF locks in what the first,
    mis-linearised updates did and ends with gyro biases more than 3.5 of its sigmas off on some seed; the
    STKF's fading factor opens the covariance (lambda > 1) and every bias of every seed ends within 3.5
    sigma of the truth (18 comparisons: a false failure below 1 %), its gyro bias error below the KF's."""
    worst_kf = 0.0
    for seed in (0, 1, 2):
        log, truth, ta, fixes = _case(seed, 20.0, 0.01)
        R0 = so3_exp(np.array([0.0, 0.0, np.deg2rad(30.0)])) @ truth.R_w_i[0]
        init = NavState(truth.p_w[0], truth.vel_w[0], R0)
        aid = Aiding(ta, "position", fixes, 0.01)
        kf = run_alignment(log, aid, init, "kf", NOISE, g=G)
        st = run_alignment(log, aid, init, "stkf", NOISE, g=G)
        assert np.max(st.fading) > 1.0
        assert np.all(np.abs(st.accel_bias[-1] - BA) < 3.5 * st.accel_bias_std[-1])
        assert np.all(np.abs(st.gyro_bias[-1] - BG) < 3.5 * st.gyro_bias_std[-1])
        assert np.linalg.norm(st.gyro_bias[-1] - BG) < np.linalg.norm(kf.gyro_bias[-1] - BG)
        worst_kf = max(
            worst_kf, float(np.max(np.abs(kf.gyro_bias[-1] - BG) / kf.gyro_bias_std[-1]))
        )
    assert worst_kf > 3.5
