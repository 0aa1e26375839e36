"""Accelerometer stage: the gravity-norm fit over the static intervals of each threshold of the sweep.

Levenberg-Marquardt on ``r = g - |T K (a_S ± b)|`` over the static samples (Tedaldi 2014, eq. 10; the
seed's eq. 12 squares both norms, which has the same minimiser for small residuals), with an analytic
Jacobian; the threshold kept is the one with the lowest residual per sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.imu.calibrate.checks import residual_covariance
from imuslam.imu.calibrate.config import CalibrationConfig, SweepRow
from imuslam.imu.lm import levenberg_marquardt
from imuslam.imu.model import BiasSign, TriadModel, misalignment_matrix
from imuslam.imu.static import StaticDetection, detect

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def accel_model_parts(theta: FloatArray, sign: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    T = misalignment_matrix(theta[0], theta[1], theta[2])
    return T, theta[3:6], sign * theta[6:9]


def accel_residual_jacobian(
    theta: FloatArray, samples: FloatArray, g: float, sign: float
) -> tuple[FloatArray, FloatArray]:
    """Residuals (M,) ``g - |T K (a + sign*b)|`` and their analytic Jacobian (M, 9) (Tedaldi 2014, eq. 10)."""
    T, K, off = accel_model_parts(theta, sign)
    u = samples + off  # (M, 3)
    v = u * K  # K u
    h = v @ T.T
    nh = np.linalg.norm(h, axis=1)
    r = g - nh
    e = h / nh[:, None]  # d|h|/dh
    J = np.empty((samples.shape[0], 9))
    # dh/d a_yz = [-v_y, 0, 0]; dh/d a_zy = [v_z, 0, 0]; dh/d a_zx = [0, -v_z, 0]
    J[:, 0] = e[:, 0] * v[:, 1]
    J[:, 1] = -e[:, 0] * v[:, 2]
    J[:, 2] = e[:, 1] * v[:, 2]
    # dh/ds_j = T[:, j] u_j ; dh/db_j = sign * T[:, j] s_j
    eT = e @ T  # (M, 3): e^T T[:, j]
    J[:, 3:6] = -eT * u
    J[:, 6:9] = -eT * K * sign
    return r, J


def accel_initial_guess(means: FloatArray, g: float) -> tuple[FloatArray, FloatArray]:
    """Scale (3,) and offset o (3,) with ``|K (m - o)| = g`` from static means (K, 3) in any unit.

    Linear least squares on the axis-aligned ellipsoid ``sum_j p_j m_j^2 + q_j m_j = 1``; then
    ``o_j = -q_j / (2 p_j)`` and ``s_j = g sqrt(p_j / G)``, ``G = 1 + sum_j p_j o_j^2``.
    """
    m = np.asarray(means, dtype=float)
    c = m.mean(axis=0)
    sc = np.maximum(np.abs(m - c).max(axis=0), 1e-12)
    z = (m - c) / sc  # conditioning
    A = np.hstack([z * z, z])
    sol, *_ = np.linalg.lstsq(A, np.ones(len(z)), rcond=None)
    p, q = sol[:3], sol[3:]
    if np.any(p <= 0):
        raise InputError(
            "the static poses do not outline a sphere: the IMU must be turned to many attitudes"
        )
    oz = -q / (2 * p)
    G = 1.0 + np.sum(p * oz * oz)
    if G <= 0:
        raise InputError(
            "the static poses do not outline a sphere: the IMU must be turned to many attitudes"
        )
    s = g * np.sqrt(p / G) / sc
    o = oz * sc + c
    return s, o


def interval_samples(x: FloatArray, intervals: IntArray, n: int, use_means: bool) -> FloatArray:
    if use_means:
        return np.stack([x[s : e + 1].mean(axis=0) for s, e in intervals])
    idx = (intervals[:, 0][:, None] + np.arange(n)[None, :]).ravel()
    return x[idx]


def solve_accel(
    samples: FloatArray, theta0: FloatArray, g: float, sign: float
) -> tuple[FloatArray, FloatArray, FloatArray, bool, str]:
    cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def both(th: FloatArray) -> tuple[FloatArray, FloatArray]:
        # LM asks for the residual and then the Jacobian at the same point: compute them once
        key = th.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = accel_residual_jacobian(th, samples, g, sign)
        return cache[key]

    def fun(th: FloatArray) -> FloatArray:
        return both(th)[0]

    def jac(th: FloatArray) -> FloatArray:
        return both(th)[1]

    x_scale = np.concatenate(
        [np.full(3, 1e-3), np.abs(theta0[3:6]), np.abs(theta0[3:6]) ** -1 * 1e-2]
    )
    res = levenberg_marquardt(
        fun, theta0, jac, x_scale=x_scale, xtol=1e-12, ftol=1e-12, max_nfev=2000
    )
    x, ok, message = res.x, res.success, res.message
    if not ok:
        # Poses clustered in a few directions leave the norm fit a valley along which LM can walk to
        # the degenerate solution (scales to zero, bias to infinity). Retry inside a physical box:
        # misalignments within 0.3 rad, scales within a factor 2, offsets within 0.5 g of the guess.
        half_b = 0.5 * g / np.abs(theta0[3:6])
        lo = np.concatenate([np.full(3, -0.3), 0.5 * theta0[3:6], theta0[6:9] - half_b])
        hi = np.concatenate([np.full(3, 0.3), 2.0 * theta0[3:6], theta0[6:9] + half_b])
        lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
        from scipy.optimize import least_squares  # only on this rare path: ~0.5 s to import

        box = least_squares(
            fun, theta0, jac=jac, method="trf", bounds=(lo, hi), x_scale=x_scale, xtol=1e-12,
            ftol=1e-12, max_nfev=2000,
        )  # fmt: skip
        x, ok, message = box.x, bool(box.success), str(box.message)
    r, J = accel_residual_jacobian(x, samples, g, sign)
    return x, r, J, bool(ok and np.all(np.isfinite(x))), message


@dataclass
class AccelFit:
    """The accelerometer stage's output: the threshold kept and its fit.

    detection: the threshold kept and its static intervals (``valid``, (K, 2)); theta / theta0: (9,)
    parameters ``[misalignment 3, scale 3, bias 3]`` (bias in the fit's sign) at the solution and at the
    initial guess; residual: (M,) ``g - |a|`` of each fitted sample, m/s^2; cov: (9, 9); sweep: every
    threshold tried.
    """

    detection: StaticDetection
    theta: FloatArray
    theta0: FloatArray
    residual: FloatArray
    cov: FloatArray
    sweep: list[SweepRow]

    def model(self, bias_sign: BiasSign) -> TriadModel:
        """The calibrated accelerometer."""
        th = self.theta
        return TriadModel(misalignment_matrix(*th[:3]), th[3:6], th[6:9], bias_sign)

    def initial_model(self, bias_sign: BiasSign) -> TriadModel:
        """The accelerometer of the initial guess."""
        th = self.theta0
        return TriadModel(misalignment_matrix(*th[:3]), th[3:6], th[6:9], bias_sign)


def fit_accelerometer(
    acc: FloatArray,
    detector: FloatArray,
    n0: float,
    cfg: CalibrationConfig,
    intervals: IntArray | None,
    source: str,
) -> AccelFit:
    """Static detection and the gravity-norm fit for each threshold ``k * n0`` of ``cfg.k_values`` (or
    on the given ``intervals`` (K, 2)); the threshold with the lowest residual per sample is kept.

    acc: (N, 3) raw accelerometer samples; detector: (N,) windowed variance norm; n0: its value over the
    still period. Raises InputError when no threshold gives a calibration.
    """
    nmin = cfg.samples_per_interval
    sign = 1.0 if cfg.bias_sign == "plus" else -1.0
    sweep: list[SweepRow] = []
    best: tuple[float, StaticDetection, FloatArray, FloatArray, FloatArray, FloatArray] | None = (
        None
    )
    max_found = 0
    if intervals is not None:
        fixed = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
        k_list: list[float] = [float("nan")]
    else:
        k_list = list(cfg.k_values)
    for k in k_list:
        d = (
            StaticDetection(k, float("nan"), fixed, fixed)
            if intervals is not None
            else detect(acc, detector, n0, k, nmin)
        )
        n_iv = len(d.valid)
        max_found = max(max_found, n_iv)
        if n_iv < cfg.min_intervals:
            sweep.append(
                SweepRow(k, n_iv, np.inf, False, f"{n_iv} intervals < {cfg.min_intervals}")
            )
            continue
        means = np.stack([acc[s : e + 1].mean(axis=0) for s, e in d.valid])
        try:
            s0, o0 = accel_initial_guess(means, cfg.g)
        except InputError as exc:
            sweep.append(SweepRow(k, n_iv, np.inf, False, str(exc)))
            continue
        theta0 = np.concatenate([np.zeros(3), s0, sign * o0 * -1.0])  # x + sign*b = x - o
        samples = interval_samples(acc, d.valid, nmin, cfg.use_means)
        theta, r, J, ok, msg = solve_accel(samples, theta0, cfg.g, sign)
        rps = float(r @ r) / len(r) if ok else np.inf
        sweep.append(SweepRow(k, n_iv, rps, ok, msg))
        if ok and (best is None or rps < best[0]):
            best = (rps, d, theta, theta0, r, J)
    if best is None:
        if max_found < 9:
            raise InputError(
                f"{source}: found at most {max_found} static intervals of {nmin} samples; the "
                "accelerometer has 9 parameters and needs many more poses (36-50 recommended): "
                "was the IMU turned and held still between turns?"
            )
        raise InputError(
            f"{source}: no threshold gave a calibration ({'; '.join(r.message for r in sweep)})"
        )
    _, d, theta_a, theta_a0, r_a, J_a = best
    cov_a = residual_covariance(J_a, r_a, len(r_a) - 9)
    return AccelFit(d, theta_a, theta_a0, r_a, cov_a, sweep)
