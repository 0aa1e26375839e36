"""The VO covariance's learnt shape (vio/covcal.py) and the VO velocity conditioned on the VO rate
(VoVelocityGivenRate of the filter's Python reference, vio_reference.py): against known covariances
and the joint 6-dof update."""

from __future__ import annotations

import numpy as np
import pytest
from vio_reference import VoRate, VoVelocity, VoVelocityGivenRate

from imuslam.errors import EstimatorError, InputError
from imuslam.ins.core import ErrorLayout, Eskf, InsState, KfNoise
from imuslam.sim.stereo_run import SimStereoRun, StereoRunConfig
from imuslam.vio.config import VioConfig
from imuslam.vio.covcal import apply_vo_cov_correction, learn_vo_cov_correction, vo_errors
from imuslam.vio.pipeline import run_vio
from imuslam.vio.simvo import truth_vo_run


def _spd(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T + np.eye(n) * scale**2 * 0.1


def test_learnt_shape_recovers_a_known_correction() -> None:
    rng = np.random.default_rng(3)
    M_true = _spd(rng, 6, 1.0)
    n = 4000
    covs = np.array([_spd(rng, 6, 1e-3) for _ in range(n)])
    L = np.linalg.cholesky(covs)
    Lm = np.linalg.cholesky(M_true)
    w = rng.normal(size=(n, 6)) @ Lm.T  # cov M_true
    errors = np.einsum("nij,nj->ni", L, w)  # cov L M L^T per frame
    M = learn_vo_cov_correction(errors, covs)
    # each element of a sample second moment of Gaussians has variance (M_ii M_jj + M_ij^2) / n
    d = np.diag(M_true)
    sd = np.sqrt((np.outer(d, d) + M_true**2) / n)
    assert np.all(np.abs(M - M_true) < 5 * sd)
    # applied to a reported covariance it gives the true one
    np.testing.assert_allclose(apply_vo_cov_correction(covs[0], M_true),
                               L[0] @ M_true @ L[0].T, rtol=1e-12)  # fmt: skip
    with pytest.raises(EstimatorError, match="at least 60"):
        learn_vo_cov_correction(errors[:10], covs[:10])


def test_vo_errors_are_zero_for_exact_measurements() -> None:
    run = SimStereoRun(StereoRunConfig(duration_s=4.0, image_hz=5.0, seed=0))
    vo = truth_vo_run(run, 0.0, 0.0, seed=0)
    ms = [m for _, m in vo.frames if m is not None]
    E, C = vo_errors(ms, run.truth)
    assert E.shape == (len(ms), 6) and C.shape == (len(ms), 6, 6)
    assert np.abs(E).max() < 1e-9


def test_bad_correction_is_an_input_error() -> None:
    run = SimStereoRun(StereoRunConfig(duration_s=2.0, image_hz=5.0, seed=0))
    vo = truth_vo_run(run, 0.01, 0.003, seed=0)
    with pytest.raises(InputError, match="vo_cov_correction"):
        run_vio(run, VioConfig(vo_cov_correction=[[1.0, 0.0], [0.0, 1.0]]), vo_run=vo)
    with pytest.raises(InputError, match="positive definite"):
        run_vio(run, VioConfig(vo_cov_correction=(-np.eye(6)).tolist()), vo_run=vo)


def test_rate_then_velocity_given_rate_equals_the_joint_update() -> None:
    """Sequential processing of the decorrelated blocks equals one 6-dof update with the cross-
    covariance (to the relinearisation between the two steps, second order in the small correction)."""
    rng = np.random.default_rng(7)
    lay = ErrorLayout.full()
    R0 = np.eye(3)
    x = InsState(np.zeros(3), np.array([0.4, 0.05, 0.0]), R0, np.zeros(3), np.full(3, 1e-3),
                 np.array([0.0, 0.0, -9.81]))  # fmt: skip
    P = _spd(rng, lay.dim, 1e-3)
    # strong rate-velocity correlations, as the front end's fits have (0.9 and more)
    corr = np.eye(6)
    corr[1, 5] = corr[5, 1] = 0.9
    corr[2, 4] = corr[4, 2] = -0.85
    sd = np.r_[[1e-3] * 3, [3e-3] * 3]
    C = corr * np.outer(sd, sd)
    gyro_mean = np.array([0.01, -0.02, 0.03])
    z_w = gyro_mean - x.gyro_bias + rng.normal(0, 1e-3, 3)
    z_v = x.R_n_b.T @ x.v_n + rng.normal(0, 1e-3, 3)
    noise = KfNoise(1e-3, 1e-4, 1e-5, 1e-6)

    rate = VoRate(z_w, C[:3, :3], gyro_mean, 0.0)
    r_w, H_w, _ = rate.linearize(x, lay)
    r_v, H_v, _ = VoVelocity(z_v, C[3:, 3:]).linearize(x, lay)
    r, H = np.r_[r_w, r_v], np.vstack([H_w, H_v])
    S = H @ P @ H.T + C
    K = P @ H.T @ np.linalg.inv(S)
    dx_joint = K @ r
    P_joint = P - K @ S @ K.T
    nis_joint = r @ np.linalg.solve(S, r)

    kf = Eskf(InsState(x.p_n.copy(), x.v_n.copy(), x.R_n_b.copy(), x.accel_bias.copy(),
                       x.gyro_bias.copy(), x.g_n.copy()), P=P.copy(), noise=noise, layout=lay)  # fmt: skip
    u1 = kf.update(rate, 0.999)
    u2 = kf.update(VoVelocityGivenRate.from_joint(z_v, z_w, gyro_mean, C[:3, :3], C[:3, 3:],
                                                  C[3:, 3:]), 0.999)  # fmt: skip
    assert u1.accepted and u2.accepted
    # the velocity's Jacobian [R^T v]x is re-evaluated after the rate update turned the attitude by
    # dtheta: the sequential result differs from the joint one by that relative amount (first order)
    eps = 5 * float(np.linalg.norm(u1.dx[lay.TH]))
    assert 0 < eps < 0.01
    # the NIS of the two decorrelated blocks add up to the joint NIS
    assert abs(u1.nis + u2.nis - nis_joint) < eps * nis_joint
    dx = np.r_[kf.x.gyro_bias - x.gyro_bias, kf.x.v_n - x.v_n]
    ref = np.r_[dx_joint[lay.BG], dx_joint[lay.V]]
    assert np.abs(dx - ref).max() < eps * np.abs(ref).max()
    assert np.abs(kf.P - P_joint).max() < eps * np.abs(P_joint).max()
    # dropping the cross-covariance (two independent updates) is measurably different
    kf2 = Eskf(InsState(x.p_n.copy(), x.v_n.copy(), x.R_n_b.copy(), x.accel_bias.copy(),
                        x.gyro_bias.copy(), x.g_n.copy()), P=P.copy(), noise=noise, layout=lay)  # fmt: skip
    kf2.update(rate, 0.999)
    kf2.update(VoVelocity(z_v, C[3:, 3:]), 0.999)
    assert np.abs(kf2.P - P_joint).max() > 10 * eps * np.abs(P_joint).max()


def test_fit_vo_error_recovers_a_gauss_markov_part() -> None:
    """Errors = white noise (1.5e-3 m/s) + a first-order Gauss-Markov part (per axis 0.5e-3, 1e-3,
    0.8e-3 m/s; 0.6 s at 5 Hz), 20,000 pairs: the fitted sigmas within 12 % and the time constant within
    25 % (the autocovariances' sampling error is about 1.5e-3^2 / sqrt(20000), 5-20 % of the slow
    part's at lags 1-4). Without a slow part the fitted sigmas stay below a quarter of the white one."""
    from imuslam.vio.covcal import fit_vo_error

    rng = np.random.default_rng(7)
    n, dt, tau = 20000, 0.2, 0.6
    s = np.array([0.5e-3, 1e-3, 0.8e-3])
    rho = np.exp(-dt / tau)
    g = np.zeros((n, 3))
    g[0] = rng.normal(0, s)
    for k in range(1, n):
        g[k] = rho * g[k - 1] + rng.normal(0, s * np.sqrt(1 - rho**2))
    e = np.zeros((n, 6))
    e[:, :3] = rng.normal(0, 6e-4, (n, 3))
    e[:, 3:] = g + rng.normal(0, 1.5e-3, (n, 3))
    sd, tau_fit = fit_vo_error(e, dt)
    print(f"sigmas {np.array(sd)}, time constant {tau_fit:.3f} s")
    assert np.all(np.abs(np.array(sd) / s - 1) < 0.12)
    assert abs(tau_fit / tau - 1) < 0.25
    e[:, 3:] -= g
    sd0, _ = fit_vo_error(e, dt)
    print(f"white only: sigmas {np.array(sd0)}")
    assert max(sd0) < 0.25 * 1.5e-3
