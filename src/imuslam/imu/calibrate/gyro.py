"""Gyroscope stage: misalignment and scale from the gravity direction predicted across each rotation.

The gyro bias is the mean over the initial still period; misalignment and scale come from integrating the
corrected rate (RK4 on the quaternion, Tedaldi 2014, eq. 14) between consecutive static intervals and
comparing the predicted gravity direction with the measured one (eq. 13): ``r = R^T u_0 - u_1``. The
accelerometer calibration and the still-period bias are taken as known; their uncertainty is propagated
into the gyro covariance (Murphy & Topel 1985).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.imu.calibrate.accel import AccelFit, accel_model_parts
from imuslam.imu.calibrate.checks import residual_covariance
from imuslam.imu.calibrate.config import CalibrationConfig
from imuslam.imu.lm import levenberg_marquardt
from imuslam.imu.model import TriadModel, misalignment_matrix
from imuslam.imu.rk4 import (
    integrate_segments,
    integrate_segments_numpy,
    integrate_segments_sensitivity,
)
from imuslam.interfaces.imu import ImuLog

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Integrator = Callable[..., FloatArray]


def gyro_rate_matrix(theta: FloatArray) -> FloatArray:
    T = misalignment_matrix(*theta[:6])
    return T * theta[6:9][None, :]


def gyro_residuals(
    theta_stack: FloatArray,
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    u0: FloatArray,
    u1: FloatArray,
    integrate: Integrator = integrate_segments,
) -> FloatArray:
    """Gravity-direction residuals (P, 3S) ``R^T u0 - u1`` for each parameter vector of ``theta_stack``.

    ``theta_stack`` (P, 9 or 12): gyro misalignment (6), scale (3) and optionally a bias refinement (3);
    ``w`` (N, 3) raw rates at ``t_s``; ``segs`` (S, 2) sample ranges of the rotations between static
    poses; ``u0`` / ``u1`` (S, 3) the unit gravity directions measured before and after each one. ``R``
    is the rotation integrated with the corrected rates (Tedaldi 2014, eq. 16-17) by ``integrate``
    (``imu.rk4``: compiled or numpy). Used by the fit and by the pose planner (``imu.poseplan``).
    """
    P = theta_stack.shape[0]
    Ms = np.stack([gyro_rate_matrix(th) for th in theta_stack])
    if theta_stack.shape[1] == 12:
        # bias refinement: rates M (w - db); integrate each parameter set with its own shifted samples
        R = integrate(w, t_s, segs, Ms, theta_stack[:, 9:12])
        return (np.einsum("psji,sj->psi", R, u0) - u1[None]).reshape(P, -1)
    R = integrate(w, t_s, segs, Ms)
    return (np.einsum("psji,sj->psi", R, u0) - u1[None]).reshape(P, -1)


def gyro_residual_jacobian(
    theta: FloatArray,
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    u0: FloatArray,
    u1: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """``gyro_residuals`` of one parameter vector (9 or 12) and its Jacobian (3S, 9 or 12), analytic.

    With ``a = R^T u0`` and the rotation perturbed on the right, ``R Exp(dtheta)``, the residual moves
    by ``a x dtheta`` (Sola et al. 2018, eq. 145); ``dtheta`` per parameter comes from
    ``imu.rk4.integrate_segments_sensitivity``. ``M = T diag(s)`` is affine in each single parameter,
    so ``M(theta + e_j) - M(theta)`` is its exact derivative.
    """
    n = theta.size
    M = gyro_rate_matrix(theta[:9])
    R, Z, Y = integrate_segments_sensitivity(w, t_s, segs, M, theta[9:12] if n == 12 else None)
    a = np.einsum("sji,sj->si", R, u0)
    dM = np.stack([gyro_rate_matrix(theta[:9] + np.eye(9)[j]) - M for j in range(9)])  # (9, 3, 3)
    dtheta = np.einsum("siab,jab->jsi", Z, dM)  # (9, S, 3)
    if n == 12:
        dtheta = np.concatenate([dtheta, np.einsum("sia,aj->jsi", Y, -M)])  # rates M (w - o)
    J = np.cross(a[None], dtheta).reshape(n, -1).T
    return (a - u1).ravel(), J


def gyro_solve(
    theta0: FloatArray,
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    u0: FloatArray,
    u1: FloatArray,
    integrate: Integrator = integrate_segments,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    n = theta0.size
    step = np.concatenate([np.full(6, 1e-7), np.abs(theta0[6:9]) * 1e-7])
    if n == 12:
        step = np.concatenate([step, np.full(3, 1e-7) / np.maximum(np.abs(theta0[6:9]), 1e-12)])
    x_scale = np.concatenate([np.full(6, 1e-2), np.abs(theta0[6:9])])
    if n == 12:
        x_scale = np.concatenate([x_scale, 1e-3 / np.abs(theta0[6:9])])
    if integrate is integrate_segments_numpy:
        # numpy: the analytic Jacobian of one integration replaces n + 1 integrations
        pair: dict[bytes, tuple[FloatArray, FloatArray]] = {}

        def both(th: FloatArray) -> tuple[FloatArray, FloatArray]:
            key = th.tobytes()
            if key not in pair:
                pair.clear()
                pair[key] = gyro_residual_jacobian(th, w, t_s, segs, u0, u1)
            return pair[key]

        res = levenberg_marquardt(
            lambda th: both(th)[0], theta0, lambda th: both(th)[1], x_scale=x_scale, xtol=1e-12,
            ftol=1e-12,
        )  # fmt: skip
        return res.x, res.fun, res.jac
    # LM asks for the Jacobian where it just evaluated the residual
    last: dict[bytes, FloatArray] = {}

    def fun(th: FloatArray) -> FloatArray:
        r = gyro_residuals(th[None], w, t_s, segs, u0, u1, integrate)[0]
        last.clear()
        last[th.tobytes()] = r
        return r

    def jac(th: FloatArray) -> FloatArray:
        stack = np.repeat(th[None], n, axis=0) + np.diag(step)
        r = gyro_residuals(stack, w, t_s, segs, u0, u1, integrate)
        r0 = last[th.tobytes()] if th.tobytes() in last else fun(th)
        return ((r - r0) / step[:, None]).T

    res = levenberg_marquardt(fun, theta0, jac, x_scale=x_scale, xtol=1e-12, ftol=1e-12)
    return res.x, res.fun, res.jac


def gyro_scale_guess(
    w: FloatArray, t_s: FloatArray, segs: IntArray, u0: FloatArray, u1: FloatArray
) -> float:
    """A unit-free first scale: the angle between gravity directions over the integrated rate norm.

    ``angle(u0, u1) <= true rotation <= integral of |omega|``, so the ratio bounds the scale from below and
    reaches it for rotations about a horizontal axis; the upper quantile of the ratios is taken.
    """
    ang = np.arccos(np.clip(np.sum(u0 * u1, axis=1), -1.0, 1.0))
    norms = np.linalg.norm(w, axis=1)
    dt = np.diff(t_s)
    c = np.concatenate([[0.0], np.cumsum(0.5 * (norms[1:] + norms[:-1]) * dt)])
    phi = c[segs[:, 1]] - c[segs[:, 0]]
    ok = (ang > np.deg2rad(20.0)) & (phi > 0)
    if not np.any(ok):
        raise InputError(
            "no rotation of more than 20 deg between static poses: the gyro cannot be calibrated"
        )
    return float(np.quantile(ang[ok] / phi[ok], 0.9))


def extend_to_motion(
    segs: IntArray, iv: IntArray, w: FloatArray, n_init: int, margin: int
) -> IntArray:
    """Widen each gyro segment into its static intervals while the rate is above the still-period noise.

    The accelerometer detector sees a slow rotation start late (gravity barely moves at first); a rotation
    missed by the integration biases the scale. Each end moves outwards, at most ``margin`` samples and
    never past the middle of its interval, while |w| exceeds the 99.9 % level of the still period.
    """
    if margin <= 0:
        return segs
    gn = np.linalg.norm(w, axis=1)
    thr = float(np.quantile(gn[: n_init + 1], 0.999))
    moving = gn > thr
    out = segs.copy()
    mid = (iv[:, 0] + iv[:, 1]) // 2
    for i in range(len(segs)):
        a, b = int(segs[i, 0]), int(segs[i, 1])
        lo = max(a - margin, int(mid[i]))
        quiet = np.flatnonzero(~moving[lo : a + 1])
        out[i, 0] = lo + int(quiet[-1]) if quiet.size else lo
        hi = min(b + margin, int(mid[i + 1]))
        quiet = np.flatnonzero(~moving[b : hi + 1])
        out[i, 1] = b + int(quiet[0]) if quiet.size else hi
    return out


def extend_to_rest(
    segs: IntArray, iv: IntArray, w: FloatArray, n_init: int, margin: int, n_avg: int, pad: int
) -> IntArray:
    """Widen each gyro segment until the rotation has come to rest, for the joint fit.

    :func:`extend_to_motion` stops at the first sample whose rate falls below the still-period noise,
    but a minimum-jerk move ends with its rate falling as the square of the time left: the last tens of
    ms of the rotation (about 1e-4 rad per move at 100 Hz) are then left out of the integration while
    the pose's mean is taken after them. That shortfall has the sign of the rotation, so it biases the
    gyro scales and misalignments (0.6 sigma of a weakly observed scale on simulated logs); it vanishes
    without noise, which is how it was found. Here the rate is averaged over ``n_avg`` samples (its
    noise falls by sqrt(n_avg)) and each end moves outwards to the last sample, within ``margin`` and
    the interval's middle, where that average still exceeds the 99.9 % level of the still period, plus
    ``pad`` samples. Integrating a few still samples more costs only their white noise (the joint fit
    estimates the bias), so the ends are placed late rather than early.
    """
    if margin <= 0:
        return segs
    c = np.concatenate([np.zeros((1, 3)), np.cumsum(w, axis=0)])
    lo_i = np.clip(np.arange(len(w)) - n_avg // 2, 0, len(w) - n_avg)
    gn = np.linalg.norm((c[lo_i + n_avg] - c[lo_i]) / n_avg, axis=1)
    thr = float(np.quantile(gn[: n_init + 1], 0.999))
    moving = gn > thr
    out = segs.copy()
    mid = (iv[:, 0] + iv[:, 1]) // 2
    for i in range(len(segs)):
        a, b = int(segs[i, 0]), int(segs[i, 1])
        lo = max(a - margin, int(mid[i]))
        mv = np.flatnonzero(moving[lo : a + 1])
        if mv.size:
            out[i, 0] = min(max(lo + int(mv[0]) - n_avg // 2 - pad, lo), a)
        hi = min(b + margin, int(mid[i + 1]))
        mv = np.flatnonzero(moving[b : hi + 1])
        if mv.size:
            out[i, 1] = max(min(b + int(mv[-1]) + n_avg // 2 + pad, hi), b)
    return out


def motion_compensated_means(
    acc: FloatArray,
    accel_model: TriadModel,
    omega: FloatArray,
    t_s: FloatArray,
    windows: IntArray,
    refs: IntArray,
) -> FloatArray:
    """Raw accelerometer means (K, 3) of each window [s, e] expressed in the sensor's attitude at its
    reference sample: each calibrated sample f_k is turned by the gyro rotation from k to the reference,
    ``f_ref = f_k + phi_k x f_k`` (small angles), then mapped back to raw units.

    omega: (N, 3) calibrated angular rate, rad/s; windows: (K, 2); refs: (K,) sample index in each window.
    """
    out = np.empty((len(windows), 3))
    Minv = np.linalg.inv(accel_model.M)
    for i, ((s, e), c) in enumerate(zip(windows, refs, strict=True)):
        w_ = omega[s : e + 1]
        dt = np.diff(t_s[s : e + 1])
        cum = np.concatenate(
            [np.zeros((1, 3)), np.cumsum(0.5 * (w_[1:] + w_[:-1]) * dt[:, None], 0)]
        )
        phi = cum - cum[c - s]  # rotation vector from the reference to sample k (body frame)
        f = accel_model.apply(acc[s : e + 1])
        out[i] = acc[s : e + 1].mean(axis=0) + Minv @ np.cross(phi, f).mean(axis=0)
    return out


def direction_residuals(R: FloatArray, u0: FloatArray, u1: FloatArray) -> FloatArray:
    """Stacked residuals (3S,) ``R^T u0 - u1``."""
    return (np.einsum("sji,sj->si", R, u0) - u1).ravel()


def angle_deg(R: FloatArray, u0: FloatArray, u1: FloatArray) -> FloatArray:
    pred = np.einsum("sji,sj->si", R, u0)
    return np.rad2deg(np.arccos(np.clip(np.sum(pred * u1, axis=1), -1.0, 1.0)))


@dataclass
class GyroSegments:
    """The rotations the gyro fit integrates and the gravity directions around them.

    w: (N, 3) raw rates less the still-period bias ``gyro_bias`` (3,); segs: (S, 2) sample ranges
    (imu_tk's, widened into the intervals while the rate is above the still-period noise); segs_rest:
    (S, 2) the same widened until the rotation has come to rest (:func:`extend_to_rest`, the joint fit's);
    pairs: (S, 2) the poses before and after each; u0 / u1: (S, 3) their measured gravity directions.
    """

    w: FloatArray
    gyro_bias: FloatArray
    segs: IntArray
    segs_rest: IntArray
    pairs: IntArray
    u0: FloatArray
    u1: FloatArray


@dataclass
class GyroFit:
    """The gyroscope stage's output.

    theta: (9,) misalignments and scales, or (12,) with a bias refinement; cov: (9 or 12, 9 or 12);
    cov_bias: (3, 3) of the gyro bias; bias_total: (3,) the still-period mean plus the refinement db (3,);
    R_before / R_fit: (S, 3, 3) the rotations of the initial guess and of the solution; integrate: the
    integrator used (compiled or numpy).
    """

    segments: GyroSegments
    theta: FloatArray
    cov: FloatArray
    cov_bias: FloatArray
    bias_total: FloatArray
    db: FloatArray
    R_before: FloatArray
    R_fit: FloatArray
    integrate: Integrator


def gyro_segments(
    log_: ImuLog,
    iv: IntArray,
    accel_model: TriadModel,
    n_init: int,
    cfg: CalibrationConfig,
    pair_ok: NDArray[np.bool_] | None,
) -> GyroSegments:
    """The rotations between the static intervals ``iv`` (K, 2) and the gravity directions around them."""
    acc, rate = log_.accel, log_.rate_hz
    # Gravity directions from the calibrated means of each interval (imu_tk: the whole interval).
    means_c = np.stack([accel_model.apply(acc[s : e + 1].mean(axis=0)[None])[0] for s, e in iv])
    u = means_c / np.linalg.norm(means_c, axis=1, keepdims=True)
    # From the end of one interval to the start of the next (imu_tk's segments) ...
    segs = np.stack([iv[:-1, 1], iv[1:, 0]], axis=1)
    gyro_bias = log_.gyro[: n_init + 1].mean(axis=0)
    w = log_.gyro - gyro_bias
    margin = int(round(cfg.gyro_margin_s * rate))
    segs_rest = extend_to_rest(
        segs, iv, w, n_init, margin, max(int(round(0.1 * rate)), 1), int(round(0.05 * rate))
    )
    segs = extend_to_motion(segs, iv, w, n_init, margin)
    pairs = np.stack([np.arange(len(iv) - 1), np.arange(1, len(iv))], axis=1)
    if pair_ok is not None:
        keep = np.asarray(pair_ok, dtype=bool)
        segs, pairs, segs_rest = segs[keep], pairs[keep], segs_rest[keep]
        if len(segs) < 6:
            raise InputError(f"{log_.source}: only {len(segs)} rotations between kept poses")
    spread = np.linalg.svd(u - u.mean(axis=0), compute_uv=False)
    if spread[1] < 0.1:
        raise InputError(
            f"{log_.source}: the static poses span too few directions (gravity stays within a cone): "
            "turn the IMU about at least two axes"
        )
    return GyroSegments(w, gyro_bias, segs, segs_rest, pairs, u[pairs[:, 0]], u[pairs[:, 1]])


def fit_gyroscope(
    log_: ImuLog,
    accel: AccelFit,
    accel_model: TriadModel,
    n_init: int,
    cfg: CalibrationConfig,
    pair_ok: NDArray[np.bool_] | None,
) -> GyroFit:
    """Gyro misalignment and scale (and optionally a bias refinement) with the accelerometer held fixed."""
    sg = gyro_segments(log_, accel.detection.valid, accel_model, n_init, cfg, pair_ok)
    w, t_s, segs, u0, u1 = sg.w, log_.t_s, sg.segs, sg.u0, sg.u1
    # One tedaldi fit integrates a few hundred times: numpy beats importing numba and loading its
    # kernel (about 0.6 s of a whole process); the joint fit and its many refits use the compiled one.
    integ: Integrator = integrate_segments if cfg.method == "joint" else integrate_segments_numpy
    s_g0 = gyro_scale_guess(w, t_s, segs, u0, u1)
    theta_g0 = np.concatenate([np.zeros(6), np.full(3, s_g0)])
    # A one-dimensional refinement of the common scale before LM keeps LM in its basin for any unit.
    cands = s_g0 * np.linspace(0.8, 1.25, 10)
    cand_thetas = np.concatenate([np.zeros((len(cands), 6)), np.repeat(cands[:, None], 3, 1)], 1)
    cost = np.sum(gyro_residuals(cand_thetas, w, t_s, segs, u0, u1, integ) ** 2, axis=1)
    theta_g0[6:9] = cands[int(np.argmin(cost))]
    R_before = integ(w, t_s, segs, gyro_rate_matrix(theta_g0)[None])[0]
    if cfg.estimate_gyro_bias:
        theta_g0 = np.concatenate([theta_g0, np.zeros(3)])
    theta_g, r_g, J_g = gyro_solve(theta_g0, w, t_s, segs, u0, u1, integ)
    # Each residual R^T u0 - u1 has two degrees of freedom (both are unit vectors).
    cov_g_full = residual_covariance(J_g, r_g, 2 * len(segs) - theta_g.size)
    bias_total = sg.gyro_bias + (theta_g[9:12] if cfg.estimate_gyro_bias else 0.0)
    n_init_s = n_init + 1
    cov_bias = (
        cov_g_full[9:12, 9:12]
        if cfg.estimate_gyro_bias
        else np.diag(np.var(log_.gyro[:n_init_s], axis=0, ddof=1) / n_init_s)
    )
    R_fit = integ(w, t_s, segs, gyro_rate_matrix(theta_g[:9])[None])[0]
    cov_g_full = _two_step_covariance(
        log_.accel, accel, sg, theta_g, J_g, cov_g_full, cov_bias, R_fit, t_s, integ, cfg
    )
    db = theta_g[9:12] if cfg.estimate_gyro_bias else np.zeros(3)
    return GyroFit(sg, theta_g, cov_g_full, cov_bias, bias_total, db, R_before, R_fit, integ)


def _two_step_covariance(
    acc: FloatArray,
    accel: AccelFit,
    sg: GyroSegments,
    theta_g: FloatArray,
    J_g: FloatArray,
    cov_g_full: FloatArray,
    cov_bias: FloatArray,
    R_fit: FloatArray,
    t_s: FloatArray,
    integ: Integrator,
    cfg: CalibrationConfig,
) -> FloatArray:
    """The gyro covariance widened by the uncertainty of what the fit took as known.

    Two-step estimation: the gyro fit takes the accelerometer calibration (through u0, u1) and the
    still-period bias as known. Their uncertainty is propagated into the gyro covariance
    (Murphy & Topel 1985): d theta_g = -(J^T J)^-1 J^T D d theta_other.
    """
    sign = 1.0 if cfg.bias_sign == "plus" else -1.0
    iv, pairs, theta_a, cov_a = accel.detection.valid, sg.pairs, accel.theta, accel.cov
    w, segs, u0, u1 = sg.w, sg.segs, sg.u0, sg.u1
    raw_means = np.stack([acc[s : e + 1].mean(axis=0) for s, e in iv])

    def resid_for_accel(th_a: FloatArray) -> FloatArray:
        T, K, off = accel_model_parts(th_a, sign)
        m = ((raw_means + off) * K) @ T.T
        uu = m / np.linalg.norm(m, axis=1, keepdims=True)
        return (np.einsum("sji,sj->si", R_fit, uu[pairs[:, 0]]) - uu[pairs[:, 1]]).ravel()

    r0 = resid_for_accel(theta_a)
    h_a = np.sqrt(np.maximum(np.diag(cov_a), 1e-30))
    D_a = np.stack(
        [(resid_for_accel(theta_a + h_a[j] * np.eye(9)[j]) - r0) / h_a[j] for j in range(9)], axis=1
    )
    try:
        A = np.linalg.solve(J_g.T @ J_g, J_g.T)
        extra = D_a @ cov_a @ D_a.T
        if not cfg.estimate_gyro_bias:
            h_b = np.sqrt(np.maximum(np.diag(cov_bias), 1e-30))
            Mfit = gyro_rate_matrix(theta_g[:9])[None]
            D_b = np.stack(
                [
                    (
                        direction_residuals(
                            integ(w - h_b[j] * np.eye(3)[j], t_s, segs, Mfit)[0],
                            u0,
                            u1,
                        )
                        - r0
                    )
                    / h_b[j]
                    for j in range(3)
                ],
                axis=1,
            )
            extra = extra + D_b @ cov_bias @ D_b.T
        return np.asarray(cov_g_full + A @ extra @ A.T, dtype=np.float64)
    except np.linalg.LinAlgError:
        return np.full_like(cov_g_full, np.inf)
