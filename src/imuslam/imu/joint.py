"""Joint maximum-likelihood refinement of the accelerometer and gyroscope calibration.

Tedaldi 2014 solves the accelerometer from the gravity norm alone, then the gyroscope with the
accelerometer held fixed. But the gravity *directions* the gyro fit compares depend on the
accelerometer's misalignment and scales, which the norm barely constrains when the poses are few or
clustered; the rotations the gyro measures between poses carry that information. Here both triads (and
optionally a gyro bias correction) are estimated in one weighted least squares over

- the gravity norm of every static pose: ``r_i = (|T_a K_a (a_i ± b_a)| - g) / sigma_n``,
- the gravity direction predicted across every rotation: ``r_s = (R_s^T u_i - u_j) / sigma_d`` with
  ``u = h / |h|`` the calibrated direction of each pose and ``R_s`` the calibrated gyro integrated
  between the poses (Tedaldi 2014, eqs. 13-14),

with the two noise levels estimated from the data by variance-component estimation (Foerstner 1979;
Koch, Parameter Estimation and Hypothesis Testing, 1999, sec. 3.6): ``sigma_k^2 = ||r_k||^2 / rho_k``,
``rho_k`` the redundancy of group k, iterated with the least squares until the weights settle. The
covariance of the 18 (or 21) parameters is ``(J^T W J)^-1`` at the solution with those weights.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from imuslam.imu.model import misalignment_matrix

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class JointFit:
    """Result of :func:`joint_refine`.

    theta_a: (9,) accelerometer parameters (order of ``ACCEL_PARAM_NAMES``, bias in the fit's sign).
    theta_g: (9,) gyro misalignments and scales (order of ``GYRO_PARAM_NAMES``).
    db: (3,) correction added to the gyro bias (raw units; zero when not estimated).
    cov: (P, P) covariance of ``[theta_a, theta_g, db]`` (P = 18 or 21).
    sigma_norm: noise of a pose's gravity norm, m/s^2; sigma_dir: of a direction residual component.
    """

    theta_a: FloatArray
    theta_g: FloatArray
    db: FloatArray
    cov: FloatArray
    sigma_norm: float
    sigma_dir: float
    norm_residual: FloatArray  # (K,) |h| - g, m/s^2
    dir_residual: FloatArray  # (S, 3) R^T u_i - u_j
    iterations: int


def _accel_h(theta_a: FloatArray, means: FloatArray, sign: float) -> FloatArray:
    T = misalignment_matrix(theta_a[0], theta_a[1], theta_a[2])
    return ((means + sign * theta_a[6:9]) * theta_a[3:6]) @ T.T


def _gyro_M(theta_g: FloatArray) -> FloatArray:
    return misalignment_matrix(*theta_g[:6]) * theta_g[6:9][None, :]


def joint_refine(
    means: FloatArray,
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    pairs: IntArray,
    theta_a0: FloatArray,
    theta_g0: FloatArray,
    g: float,
    sign: float,
    estimate_bias: bool,
    integrate: Callable[..., FloatArray],
    max_vce: int = 6,
) -> JointFit:
    """Refine ``theta_a0`` (9,) and ``theta_g0`` (9,) jointly.

    means: (K, 3) raw accelerometer mean of each static pose.
    w: (N, 3) gyro samples with the still-period bias removed, raw units; t_s: (N,) times, s.
    segs: (S, 2) sample ranges integrated between poses ``pairs`` (S, 2) (indices into ``means``).
    integrate: ``imuslam.imu.calibrate.integrate_segments`` (passed in to keep this module below it).
    """
    integ = integrate  # callable (w, t_s, segs, Ms, offsets) -> (P, S, 3, 3)
    n_b = 3 if estimate_bias else 0
    x0 = np.concatenate([theta_a0, theta_g0[:9], np.zeros(n_b)])
    P = x0.size
    K, S = len(means), len(segs)
    # Finite-difference steps and LM scales from the size of each parameter.
    scale = np.concatenate(
        [
            np.full(3, 1e-3),
            np.abs(theta_a0[3:6]),
            1e-2 / np.abs(theta_a0[3:6]),
            np.full(6, 1e-2),
            np.abs(theta_g0[6:9]),
            np.full(n_b, 1e-3) / np.abs(theta_g0[6:9])[:n_b] if n_b else np.zeros(0),
        ]
    )
    step = scale * 1e-5

    def directions(theta_a: FloatArray) -> tuple[FloatArray, FloatArray]:
        h = _accel_h(theta_a, means, sign)
        nh = np.linalg.norm(h, axis=1)
        return h, h / nh[:, None]

    def gyro_rot(xs: FloatArray) -> FloatArray:
        """Rotations (Q, S, 3, 3) for the gyro parts of parameter vectors xs (Q, P)."""
        Ms = np.stack([_gyro_M(x[9:18]) for x in xs])
        offs = xs[:, 18:21] if n_b else np.zeros((len(xs), 3))
        return integ(w, t_s, segs, Ms, offs)

    def raw_resid(x: FloatArray, R: FloatArray) -> tuple[FloatArray, FloatArray]:
        h, u = directions(x[:9])
        rn = np.linalg.norm(h, axis=1) - g
        rd = np.einsum("sji,sj->si", R, u[pairs[:, 0]]) - u[pairs[:, 1]]
        return rn, rd

    weights = np.array([1.0, 1.0])  # 1 / sigma of the norm and direction groups

    def fun_jac(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        xs = np.repeat(x[None], 1 + 9 + n_b, axis=0)
        for j in range(9 + n_b):
            xs[1 + j, 9 + j] += step[9 + j]
        Rs = gyro_rot(xs)
        rn, rd = raw_resid(x, Rs[0])
        J = np.zeros((K + 3 * S, P))
        for j in range(9):  # accelerometer columns: cheap (no integration)
            xp = x.copy()
            xp[j] += step[j]
            rn_j, rd_j = raw_resid(xp, Rs[0])
            J[:K, j] = (rn_j - rn) / step[j]
            J[K:, j] = (rd_j - rd).ravel() / step[j]
        for j in range(9 + n_b):  # gyro columns: one batched integration
            _, rd_j = raw_resid(x, Rs[1 + j])
            J[K:, 9 + j] = (rd_j - rd).ravel() / step[9 + j]
        r = np.concatenate([rn * weights[0], rd.ravel() * weights[1]])
        J[:K] *= weights[0]
        J[K:] *= weights[1]
        return r, J

    cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def both(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        key = x.tobytes() + weights.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = fun_jac(x)
        return cache[key]

    # First weights from the starting point's residuals (each group its own RMS).
    R0 = gyro_rot(x0[None])[0]
    rn0, rd0 = raw_resid(x0, R0)
    weights[:] = [
        1.0 / max(float(np.sqrt(np.mean(rn0**2))), 1e-9),
        1.0 / max(float(np.sqrt(np.sum(rd0**2) / (2 * S))), 1e-9),
    ]
    x = x0
    n_iter = 0
    for _ in range(max_vce):
        n_iter += 1
        res = least_squares(
            lambda z: both(z)[0],
            x,
            jac=lambda z: both(z)[1],
            method="lm",
            x_scale=scale,
            xtol=1e-12,
            ftol=1e-12,
        )
        x = res.x
        r, J = fun_jac(x)
        # Variance-component estimation: redundancy of each group from the hat matrix.
        N_inv = np.linalg.pinv(J.T @ J)
        hat = np.einsum("ij,jk,ik->i", J, N_inv, J)
        rho_n = K - float(hat[:K].sum())
        rho_d = 2 * S - float(hat[K:].sum())  # each direction residual has 2 degrees of freedom
        s2_n = float(r[:K] @ r[:K]) / max(rho_n, 1.0)
        s2_d = float(r[K:] @ r[K:]) / max(rho_d, 1.0)
        new = weights / np.sqrt([s2_n, s2_d])
        done = bool(np.all(np.abs(new / weights - 1.0) < 1e-3))
        weights[:] = new
        if done:
            break
    r, J = fun_jac(x)
    cov = np.linalg.pinv(J.T @ J)
    R = gyro_rot(x[None])[0]
    rn, rd = raw_resid(x, R)
    return JointFit(
        theta_a=x[:9].copy(),
        theta_g=x[9:18].copy(),
        db=x[18:21].copy() if n_b else np.zeros(3),
        cov=cov,
        sigma_norm=1.0 / float(weights[0]),
        sigma_dir=1.0 / float(weights[1]),
        norm_residual=rn,
        dir_residual=rd,
        iterations=n_iter,
    )
