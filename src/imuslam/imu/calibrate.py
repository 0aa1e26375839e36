"""Multi-position IMU calibration without external equipment (Tedaldi, Pretto, Menegatti, ICRA 2014).

1. Static detection with a threshold sweep (``imu/static.py``).
2. Accelerometer: Levenberg-Marquardt on the gravity-norm residual ``r = g - |T K (a_S ± b)|`` over the
   static samples (Tedaldi 2014, eq. 10; the seed's eq. 12 squares both norms, which has the same
   minimiser for small residuals), with an analytic Jacobian. The threshold kept is the one with the
   lowest residual per sample.
3. Gyroscope: bias = mean over the initial still period; misalignment and scale by integrating the
   corrected rate (RK4 on the quaternion, eq. 14) between consecutive static intervals and comparing the
   predicted gravity direction with the measured one (eq. 13): ``r = R^T u_0 - u_1``.
4. Covariance ``s^2 (J^T J)^-1`` at the solution with ``s^2`` the residual variance, and an
   observability verdict.
5. ``method="joint"`` (the default): steps 2-3 only start a joint weighted least squares of both triads,
   the gyro bias and its g-sensitivity over every pose's accelerometer mean, every rotation's predicted
   gravity direction and every pose's rate at rest (``imu/joint.py``), whose covariance replaces theirs.
   Each residual is weighted by the noise measured in the initial still period; the g-sensitivity and a
   linear accelerometer bias drift are fitted and kept only when their Wald test is significant.
   ``method="tedaldi"`` stops after step 4 (imu_tk's result, for reproduction).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, Field, field_validator

from imuslam.errors import InputError
from imuslam.imu.lm import levenberg_marquardt
from imuslam.imu.model import (
    ACCEL_PARAM_NAMES,
    GYRO_PARAM_NAMES,
    ImuCalibration,
    TriadModel,
    misalignment_matrix,
)
from imuslam.imu.rk4 import (
    integrate_segments,
    integrate_segments_numpy,
    integrate_segments_sensitivity,
)
from imuslam.imu.static import (
    StaticDetection,
    detect,
    init_variance_norm,
    window_half_size,
    windowed_variance_norm,
)
from imuslam.interfaces.imu import ImuLog

if TYPE_CHECKING:
    from imuslam.imu.joint import JointFit
log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Integrator = Callable[..., FloatArray]


class CalibrationConfig(BaseModel):
    """Settings of the multi-position calibration (YAML keys equal these names)."""

    g: float = Field(9.80665, gt=0, description="local gravity magnitude, m/s^2")
    t_init_s: float = Field(50.0, gt=0, description="initial still period, s")
    window_s: float = Field(1.0, gt=0, description="static detector window, s")
    k_values: list[float] = Field(
        default_factory=lambda: [2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0],
        description="threshold multiples of the initial variance norm to sweep",
    )
    samples_per_interval: int = Field(
        100, ge=10, description="samples used from each static interval (and its minimum length)"
    )
    use_means: bool = Field(
        False,
        description="fit one mean per interval instead of its first samples_per_interval samples",
    )
    bias_sign: Literal["plus", "minus"] = Field(
        "plus",
        description="model x_O = T K (x_S + b) ('plus', seed 000) or (x_S - b) ('minus', imu_tk)",
    )
    estimate_gyro_bias: bool = Field(
        False,
        description="refine the gyro bias in the fit instead of keeping the still-period mean",
    )
    method: Literal["joint", "tedaldi"] = Field(
        "joint",
        description="joint: accelerometer and gyroscope refined together by weighted least squares over "
        "every pose's gravity norm and every rotation's predicted gravity direction (imu/joint.py); "
        "tedaldi: imu_tk's two steps (accelerometer from the norm, then the gyro with it held fixed)",
    )
    gyro_g_sensitivity: bool = Field(
        True,
        description="joint method: estimate the gyro's g-sensitivity G (omega = T K (w ± b) - G f, rad/s per "
        "m/s^2) and the gyro bias from the rate at every static pose, not only the still start",
    )
    joint_poses: Literal["middle", "still"] = Field(
        "still",
        description="joint method: middle: each pose referred to its middle sample (motion-compensated "
        "mean, gyro integrated middle to middle); still: plain mean of its still part, gyro integrated "
        "between still parts",
    )
    weigh_by_length: bool = Field(
        True,
        description="joint method: weigh each pose by the square root of its length (white noise)",
    )
    accel_bias_drift: bool | Literal["auto"] = Field(
        "auto",
        description="joint method: let the accelerometer bias drift linearly over the session in the fit "
        "(a nuisance; the calibration keeps the bias at the mean of the poses' times); auto: fit it and keep "
        "it only if it differs from zero significantly (Wald test, chi-square 3 dof, 99.9 %; when G is "
        "tested too, only if G and the drift together also pass, 12 dof, 99.9 %)",
    )
    joint_weights: Literal["measured", "variance_components"] = Field(
        "measured",
        description="joint method: measured: each residual weighted by the noise measured in the still "
        "period (white noise of the pose means, angle random walk over each rotation), covariance "
        "widened only where the misfit exceeds it significantly; variance_components: each group's noise "
        "estimated from its own residuals",
    )
    g_sensitivity_test: bool = Field(
        True,
        description="joint method: keep the g-sensitivity G only if it differs from zero significantly "
        "(Wald test, chi-square 9 dof, 99.9 %; when the drift is tested too, only if G and the drift "
        "together also pass, 12 dof, 99.9 %); otherwise refit without it",
    )
    norm_weight: float | Literal["auto"] = Field(
        "auto",
        description="joint method: factor (>= 1) on the weight of each pose's gravity-norm error over its "
        "measured noise (1: maximum likelihood; larger trades gyro-predicted direction for gravity norm "
        "where an unmodelled error such as an in-session bias drift makes the two disagree); auto: 1 "
        "unless the accelerometer residuals exceed their measured noise significantly and the fit's "
        "gravity norm (constant bias) is worse than the norm-only fit's on the same poses, then the "
        "smallest of 2, 4, 8 that brings it level",
    )

    @field_validator("norm_weight")
    @classmethod
    def _norm_weight(cls, v: float | str) -> float | str:
        if v != "auto" and not float(v) >= 1.0:
            raise ValueError("norm_weight must be 'auto' or a number >= 1")
        return v

    gyro_ends: Literal["rest", "first_quiet"] = Field(
        "rest",
        description="joint method: where a gyro segment ends in a static interval; rest: where the rate "
        "averaged over 0.1 s falls to the still-period noise for good, plus 0.05 s; first_quiet: the "
        "first sample below it (tedaldi's ends, which miss the slow tail of a move)",
    )
    min_intervals: int = Field(12, ge=9, description="fewest static intervals a threshold may give")
    gyro_margin_s: float = Field(
        0.5,
        ge=0,
        description="how far a gyro segment may reach into a static interval to catch a gentle start or "
        "end of motion that the accelerometer detector took for still, s",
    )

    @field_validator("k_values")
    @classmethod
    def _k_positive(cls, v: list[float]) -> list[float]:
        if not v or any(k <= 0 for k in v):
            raise ValueError("k_values must be a non-empty list of positive multiples")
        return v


@dataclass
class SweepRow:
    """One threshold of the sweep."""

    k: float
    n_intervals: int
    residual_per_sample: float  # mean squared gravity-norm residual, (m/s^2)^2; inf if not solvable
    ok: bool
    message: str = ""


@dataclass
class CalibrationResult:
    """Everything a calibration produced: the model, the evidence and the verdict."""

    calibration: ImuCalibration
    config: CalibrationConfig
    k: float
    intervals: IntArray  # (K, 2) static intervals used, [start, end] sample indices
    detector: FloatArray  # (N,) detector value
    threshold: float
    sweep: list[SweepRow]
    accel_residual_before: FloatArray  # (K,) |a| - g per interval with the initial guess, m/s^2
    accel_residual_after: FloatArray  # (K,) |a| - g per interval, calibrated, m/s^2
    accel_rms: float  # per-sample RMS of |a| - g over the fitted samples, m/s^2
    gyro_residual_before_deg: FloatArray  # (K-1,) angle between predicted and measured gravity, deg
    gyro_residual_after_deg: FloatArray
    std_accel: FloatArray  # (9,) 1-sigma of the accel parameters
    std_gyro: FloatArray  # (9,)
    poorly_determined: list[str]
    warnings: list[str] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def gyro_rms_deg(self) -> float:
        """RMS gravity-direction error per pair of poses after calibration, deg."""
        return float(np.sqrt(np.mean(self.gyro_residual_after_deg**2)))


# ----------------------------------------------------------------------------------------------
# Accelerometer


def _accel_model(theta: FloatArray, sign: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    T = misalignment_matrix(theta[0], theta[1], theta[2])
    return T, theta[3:6], sign * theta[6:9]


def accel_residual_jacobian(
    theta: FloatArray, samples: FloatArray, g: float, sign: float
) -> tuple[FloatArray, FloatArray]:
    """Residuals (M,) ``g - |T K (a + sign*b)|`` and their analytic Jacobian (M, 9) (Tedaldi 2014, eq. 10)."""
    T, K, off = _accel_model(theta, sign)
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


def _interval_samples(x: FloatArray, intervals: IntArray, n: int, use_means: bool) -> FloatArray:
    if use_means:
        return np.stack([x[s : e + 1].mean(axis=0) for s, e in intervals])
    idx = (intervals[:, 0][:, None] + np.arange(n)[None, :]).ravel()
    return x[idx]


def _solve_accel(
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


# ----------------------------------------------------------------------------------------------
# Gyroscope


def _gyro_M(theta: FloatArray) -> FloatArray:
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
    Ms = np.stack([_gyro_M(th) for th in theta_stack])
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
    M = _gyro_M(theta[:9])
    R, Z, Y = integrate_segments_sensitivity(w, t_s, segs, M, theta[9:12] if n == 12 else None)
    a = np.einsum("sji,sj->si", R, u0)
    dM = np.stack([_gyro_M(theta[:9] + np.eye(9)[j]) - M for j in range(9)])  # (9, 3, 3)
    dtheta = np.einsum("siab,jab->jsi", Z, dM)  # (9, S, 3)
    if n == 12:
        dtheta = np.concatenate([dtheta, np.einsum("sia,aj->jsi", Y, -M)])  # rates M (w - o)
    J = np.cross(a[None], dtheta).reshape(n, -1).T
    return (a - u1).ravel(), J


def _gyro_solve(
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


def _gyro_scale_guess(
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


def _angle_free_resid(R: FloatArray, u0: FloatArray, u1: FloatArray) -> FloatArray:
    """Stacked residuals (3S,) ``R^T u0 - u1``."""
    return (np.einsum("sji,sj->si", R, u0) - u1).ravel()


def _angle_deg(R: FloatArray, u0: FloatArray, u1: FloatArray) -> FloatArray:
    pred = np.einsum("sji,sj->si", R, u0)
    return np.rad2deg(np.arccos(np.clip(np.sum(pred * u1, axis=1), -1.0, 1.0)))


# ----------------------------------------------------------------------------------------------
# Driver


def _check_log(log_: ImuLog) -> None:
    n = len(log_)
    if n == 0:
        raise InputError(f"{log_.source}: the log is empty")
    for name, x in (("accel", log_.accel), ("gyro", log_.gyro)):
        bad = ~np.isfinite(x).all(axis=1)
        if bad.any():
            raise InputError(f"{log_.source}: {name} sample {int(np.argmax(bad))} is not finite")
    dt = np.diff(log_.t_ns)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise InputError(f"{log_.source}: time is not strictly increasing at sample {i + 1}")
    # Saturation: a clipped axis sits exactly at its extreme value for many samples.
    for name, x in (("accel", log_.accel), ("gyro", log_.gyro)):
        for j, ax in enumerate("xyz"):
            col = x[:, j]
            for extreme in (col.max(), col.min()):
                hits = int(np.count_nonzero(col == extreme))
                if hits > max(10, n // 200):
                    raise InputError(
                        f"{log_.source}: {name} {ax} axis is saturated ({hits} samples at {extreme:g}): "
                        "the sensor's range was exceeded, those poses cannot be used"
                    )


#: SI per unit: a calibrated scale K (SI per raw unit) of a log in one of these is near its value.
_UNIT_SI = {"m/s^2": 1.0, "g": 9.80665, "rad/s": 1.0, "deg/s": np.pi / 180.0}


def _check_units(K: FloatArray, sensor: str, unit: str, option: str, source: str) -> None:
    """InputError when the fitted scale says the log is not in its declared unit: a gyro in deg/s
    declared rad/s fits K = 0.0175 (pi/180), which would otherwise be reported as a scale error of
    98 %. Low-cost MEMS scale errors are a few percent; [0.7, 1.4] x the unit's factor is accepted."""
    if unit not in _UNIT_SI:
        return  # raw counts: any scale
    k = float(np.mean(K))
    ratio = k / _UNIT_SI[unit]
    if 0.7 <= ratio <= 1.4:
        return
    si, candidates = (
        ("m/s^2", ("m/s^2", "g")) if sensor == "accelerometer" else ("rad/s", ("rad/s", "deg/s"))
    )
    like = [u for u in candidates if u != unit and 0.7 <= k / _UNIT_SI[u] <= 1.4]
    hint = (
        f"the data look like {like[0]} (give {option} {like[0]})"
        if like
        else (f"the data look like raw counts (give {option} counts)")
    )
    raise InputError(
        f"{source}: the {sensor} scale came out {k:.4g} {si} per {unit}, {ratio:.3g} x the expected "
        f"{_UNIT_SI[unit]:.4g}: the {sensor} is not in {unit}; {hint}"
    )


def _std_or_inf(var: np.ndarray) -> np.ndarray:
    """Standard deviations from variances; a non-positive variance (undetermined) gives inf."""
    var = np.asarray(var, dtype=np.float64)
    return np.where(var > 0.0, np.sqrt(np.where(var > 0.0, var, 1.0)), np.inf)


def _verdict(
    std_a: FloatArray, std_g: FloatArray, theta_a: FloatArray, theta_g: FloatArray, n_poses: int
) -> list[str]:
    """Names of poorly determined parameters: angles worse than 1 mrad (accel) / 2 mrad (gyro),
    scale worse than 0.1 % (accel) / 0.5 % (gyro), accel bias worse than 0.02 m/s^2."""
    poor: list[str] = []
    lim_a = np.concatenate(
        [np.full(3, 1e-3), np.abs(theta_a[3:6]) * 1e-3, 0.02 / np.abs(theta_a[3:6])]
    )
    lim_g = np.concatenate([np.full(6, 2e-3), np.abs(theta_g[6:9]) * 5e-3])
    poor += [nm for nm, s, lim in zip(ACCEL_PARAM_NAMES, std_a, lim_a, strict=True) if not s <= lim]
    poor += [nm for nm, s, lim in zip(GYRO_PARAM_NAMES, std_g, lim_g, strict=True) if not s <= lim]
    return poor


def _cov(J: FloatArray, r: FloatArray, dof: int) -> FloatArray:
    s2 = float(r @ r) / max(dof, 1)
    try:
        return np.asarray(s2 * np.linalg.inv(J.T @ J), dtype=np.float64)
    except np.linalg.LinAlgError:
        return np.full((J.shape[1], J.shape[1]), np.inf)


def calibrate(
    log_: ImuLog,
    config: CalibrationConfig | None = None,
    intervals: IntArray | None = None,
    pair_ok: NDArray[np.bool_] | None = None,
) -> CalibrationResult:
    """Calibrate accelerometer and gyroscope from a multi-position log.

    log_: raw IMU log (any units): a still period of ``config.t_init_s`` first, then static poses with
        rotations between them.
    intervals: (K, 2) static intervals to use instead of the threshold sweep (cross-validation);
    pair_ok: (K-1,) which consecutive pairs of them the gyro fit may use (default all).
    Raises InputError when the data cannot give a calibration (too short, no rotations, saturation,
    too few static intervals), never returns an identity calibration.
    """
    cfg = config or CalibrationConfig()
    t0 = time.perf_counter()
    _check_log(log_)
    t_s = log_.t_s
    rate = log_.rate_hz
    n_init = int(np.searchsorted(t_s, cfg.t_init_s, side="right")) - 1
    if t_s[-1] < cfg.t_init_s * 1.1 or n_init < 20:
        raise InputError(
            f"{log_.source}: the log lasts {t_s[-1]:.1f} s; it needs the initial still period of "
            f"{cfg.t_init_s:g} s and static poses after it"
        )
    acc = log_.accel
    half = window_half_size(cfg.window_s, rate)
    det = windowed_variance_norm(acc, half)
    n0 = init_variance_norm(acc, n_init)
    if not n0 > 0:
        raise InputError(
            f"{log_.source}: the accelerometer is constant over the still period (no noise?)"
        )
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
            else detect(acc, det, n0, k, nmin)
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
        samples = _interval_samples(acc, d.valid, nmin, cfg.use_means)
        theta, r, J, ok, msg = _solve_accel(samples, theta0, cfg.g, sign)
        rps = float(r @ r) / len(r) if ok else np.inf
        sweep.append(SweepRow(k, n_iv, rps, ok, msg))
        if ok and (best is None or rps < best[0]):
            best = (rps, d, theta, theta0, r, J)
    if best is None:
        if max_found < 9:
            raise InputError(
                f"{log_.source}: found at most {max_found} static intervals of {nmin} samples; the "
                "accelerometer has 9 parameters and needs many more poses (36-50 recommended): "
                "was the IMU turned and held still between turns?"
            )
        raise InputError(
            f"{log_.source}: no threshold gave a calibration ({'; '.join(r.message for r in sweep)})"
        )
    _, d, theta_a, theta_a0, r_a, J_a = best
    t_acc = time.perf_counter()
    warnings: list[str] = []

    accel_model = TriadModel(
        misalignment_matrix(*theta_a[:3]), theta_a[3:6], theta_a[6:9], cfg.bias_sign
    )
    accel_init = TriadModel(
        misalignment_matrix(*theta_a0[:3]), theta_a0[3:6], theta_a0[6:9], cfg.bias_sign
    )
    cov_a = _cov(J_a, r_a, len(r_a) - 9)
    iv = d.valid

    def per_interval_norm_err(model: TriadModel) -> FloatArray:
        return np.array(
            [np.mean(np.linalg.norm(model.apply(acc[s : e + 1]), axis=1)) - cfg.g for s, e in iv]
        )

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
    u0, u1 = u[pairs[:, 0]], u[pairs[:, 1]]
    spread = np.linalg.svd(u - u.mean(axis=0), compute_uv=False)
    if spread[1] < 0.1:
        raise InputError(
            f"{log_.source}: the static poses span too few directions (gravity stays within a cone): "
            "turn the IMU about at least two axes"
        )
    # One tedaldi fit integrates a few hundred times: numpy beats importing numba and loading its
    # kernel (about 0.6 s of a whole process); the joint fit and its many refits use the compiled one.
    integ: Integrator = integrate_segments if cfg.method == "joint" else integrate_segments_numpy
    s_g0 = _gyro_scale_guess(w, t_s, segs, u0, u1)
    theta_g0 = np.concatenate([np.zeros(6), np.full(3, s_g0)])
    # A one-dimensional refinement of the common scale before LM keeps LM in its basin for any unit.
    cands = s_g0 * np.linspace(0.8, 1.25, 10)
    cand_thetas = np.concatenate([np.zeros((len(cands), 6)), np.repeat(cands[:, None], 3, 1)], 1)
    cost = np.sum(gyro_residuals(cand_thetas, w, t_s, segs, u0, u1, integ) ** 2, axis=1)
    theta_g0[6:9] = cands[int(np.argmin(cost))]
    R_before = integ(w, t_s, segs, _gyro_M(theta_g0)[None])[0]
    if cfg.estimate_gyro_bias:
        theta_g0 = np.concatenate([theta_g0, np.zeros(3)])
    theta_g, r_g, J_g = _gyro_solve(theta_g0, w, t_s, segs, u0, u1, integ)
    # Each residual R^T u0 - u1 has two degrees of freedom (both are unit vectors).
    cov_g_full = _cov(J_g, r_g, 2 * len(segs) - theta_g.size)
    bias_total = gyro_bias + (theta_g[9:12] if cfg.estimate_gyro_bias else 0.0)
    n_init_s = n_init + 1
    cov_bias = (
        cov_g_full[9:12, 9:12]
        if cfg.estimate_gyro_bias
        else np.diag(np.var(log_.gyro[:n_init_s], axis=0, ddof=1) / n_init_s)
    )
    # Two-step estimation: the gyro fit takes the accelerometer calibration (through u0, u1) and the
    # still-period bias as known. Their uncertainty is propagated into the gyro covariance
    # (Murphy & Topel 1985): d theta_g = -(J^T J)^-1 J^T D d theta_other.
    R_fit = integ(w, t_s, segs, _gyro_M(theta_g[:9])[None])[0]
    raw_means = np.stack([acc[s : e + 1].mean(axis=0) for s, e in iv])

    def resid_for_accel(th_a: FloatArray) -> FloatArray:
        T, K, off = _accel_model(th_a, sign)
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
            Mfit = _gyro_M(theta_g[:9])[None]
            D_b = np.stack(
                [
                    (
                        _angle_free_resid(
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
        cov_g_full = cov_g_full + A @ extra @ A.T
    except np.linalg.LinAlgError:
        cov_g_full = np.full_like(cov_g_full, np.inf)
    db = theta_g[9:12] if cfg.estimate_gyro_bias else np.zeros(3)
    G: FloatArray | None = None
    drift_notes: dict[str, object] = {}
    f_c = np.zeros((1, 3))
    if cfg.method == "joint":
        from scipy.special import chdtri  # chi-square quantile (scipy.stats costs ~1 s to import)

        from imuslam.imu.joint import joint_refine, measured_noise

        use_g = cfg.gyro_g_sensitivity
        f_c = accel_model.apply(acc) if use_g else np.zeros((1, 3))
        # Each pose is referred to the middle sample of its interval, and the gyro is integrated from
        # one pose's middle to the next's (still parts included: the bias is estimated). The slow ends
        # of motion the accelerometer detector took for still are turned back into the pose's frame at
        # that middle sample with the gyro (motion-compensated means), instead of being cut at a guess.
        # The static-rate means use each pose's still part only: between the ends of the gyro segments
        # that reach into its interval while the rate is above the still-period noise.
        if cfg.gyro_ends == "rest":
            segs = segs_rest
        still = iv.copy()
        still[pairs[:, 1], 0] = np.maximum(still[pairs[:, 1], 0], segs[:, 1])
        still[pairs[:, 0], 1] = np.minimum(still[pairs[:, 0], 1], segs[:, 0])
        short = still[:, 1] - still[:, 0] < 20
        still[short] = iv[short]
        if cfg.joint_poses == "middle":
            refs = (iv[:, 0] + iv[:, 1]) // 2
            segs = np.stack([refs[pairs[:, 0]], refs[pairs[:, 1]]], axis=1)
            pose_means = motion_compensated_means(
                acc, accel_model, w @ _gyro_M(theta_g[:9]).T, t_s, iv, refs
            )
        else:  # "still": plain means of the still parts, gyro segments between them
            pose_means = np.stack([acc[s : e + 1].mean(axis=0) for s, e in still])
        raw_means = pose_means
        gyro_means = np.stack([w[s : e + 1].mean(axis=0) for s, e in still])
        pose_n = (still[:, 1] - still[:, 0] + 1).astype(float)
        noise = None
        if cfg.joint_weights == "measured":
            sig_a = np.std(acc[: n_init + 1], axis=0, ddof=1) * np.abs(theta_a[3:6])
            sig_w = np.std(log_.gyro[: n_init + 1], axis=0, ddof=1) * np.abs(theta_g[6:9])
            noise = measured_noise(
                sig_a, sig_w, pose_n, t_s[segs[:, 1]] - t_s[segs[:, 0]], 1.0 / rate
            )

        pose_t = t_s[(iv[:, 0] + iv[:, 1]) // 2]

        def run_joint(with_g: bool, with_drift: bool, norm_weight: float = 1.0) -> JointFit:
            return joint_refine(
                pose_means, gyro_means, w, f_c, t_s, segs, pairs, theta_a, theta_g[:9], cfg.g, sign,
                cfg.estimate_gyro_bias or cfg.gyro_g_sensitivity, with_g, integrate_segments,
                pose_t=pose_t if with_drift else None,
                pose_n=pose_n if cfg.weigh_by_length else None, noise=noise,
                norm_weight=norm_weight,
            )  # fmt: skip

        def wald(jf: JointFit, a: int, b: int, x: FloatArray) -> float:
            """Wald statistic x^T C^-1 x of the parameters [a, b) of the fit (Koch 1999, sec. 4.2)."""
            try:
                return float(x @ np.linalg.solve(jf.cov[a:b, a:b], x))
            except np.linalg.LinAlgError:
                return float("inf")

        # Optional terms are fitted and kept only if significant (Wald test at 99.9 %): an insignificant
        # g-sensitivity or bias drift only adds variance to the parameters that matter.
        with_drift = cfg.accel_bias_drift is not False
        lam = 1.0 if cfg.norm_weight == "auto" else float(cfg.norm_weight)
        jf = run_joint(use_g, with_drift, lam)
        n_b = 3 if (cfg.estimate_gyro_bias or cfg.gyro_g_sensitivity) else 0
        # Wald statistics of the optional terms, recorded in the calibration's notes
        wald_notes: dict[str, float] = {}
        test_g = use_g and cfg.g_sensitivity_test
        test_d = with_drift and cfg.accel_bias_drift == "auto"
        if test_g and test_d:
            # Closed testing (Marcus, Peritz & Gabriel 1976, Biometrika 63): a term is kept only if the
            # hypothesis "neither term" is rejected too (one Wald test of G and the drift together, 12
            # dof, 99.9 %), so the chance of keeping any term on a log that has neither is at most
            # 0.1 %, where two separate tests allow 0.2 %.
            a = 18 + n_b
            w_both = wald(jf, a, a + 12, np.concatenate([jf.G.ravel(), jf.drift]))
            log.debug("g-sensitivity and drift together: Wald statistic %.1f (12 dof)", w_both)
            wald_notes["g_sensitivity_and_accel_bias_drift_12dof"] = w_both
            if w_both < float(chdtri(12, 1.0 - 0.999)):
                use_g = test_g = with_drift = test_d = False
                jf = run_joint(False, False, lam)
        if test_g:
            w_G = wald(jf, 18 + n_b, 27 + n_b, jf.G.ravel())
            log.debug("g-sensitivity Wald statistic %.1f (9 dof)", w_G)
            wald_notes["g_sensitivity_9dof"] = w_G
            if w_G < float(chdtri(9, 1.0 - 0.999)):
                use_g = False
                log.debug("g-sensitivity not significant (Wald %.1f): left out", w_G)
                jf = run_joint(False, with_drift, lam)

        def norm_rms(th: FloatArray) -> float:
            """Gravity-norm RMS over the poses of the accelerometer ``th`` with a constant bias."""
            T, Kd, off = _accel_model(th, sign)
            e = np.linalg.norm(((pose_means + off) * Kd) @ T.T, axis=1) - cfg.g
            return float(np.sqrt(np.mean(e**2)))

        if test_d:
            a = 18 + n_b + (9 if use_g else 0)
            w_d = wald(jf, a, a + 3, jf.drift)
            log.debug("accelerometer bias drift Wald statistic %.1f (3 dof)", w_d)
            wald_notes["accel_bias_drift_3dof"] = w_d
            if w_d < float(chdtri(3, 1.0 - 0.999)):
                with_drift = False
                log.debug("accelerometer bias drift not significant (Wald %.1f): left out", w_d)
                jf = run_joint(use_g, False, lam)
        if cfg.norm_weight == "auto" and jf.accel_misfit:
            # An unmodelled error (in-session drift) makes the rotations and the gravity norms disagree;
            # the calibration file keeps one constant bias, so its gravity norm is kept no worse than the
            # norm-only (two-step) fit's on the same poses, at the least cost in direction.
            ref = norm_rms(theta_a)
            for lam in (2.0, 4.0, 8.0):
                if norm_rms(jf.theta_a) <= ref:
                    break
                jf = run_joint(use_g, with_drift, lam)
            log.debug("gravity-norm weight %g (norm-only fit: %.5f m/s^2)", lam, ref)
        drift_notes["gravity_norm_weight"] = lam
        if wald_notes:
            drift_notes["wald_statistics"] = wald_notes
        theta_a, theta_g, db = jf.theta_a, jf.theta_g, jf.db
        if with_drift:
            # the fitted bias is the one at the mean of the poses' times (their average bias)
            drift_notes |= {
                "accel_bias_drift_per_s": jf.drift.tolist(),
                "accel_bias_drift_t_ref_s": float(np.mean(pose_t)),
            }
        G = jf.G if use_g else None
        bias_total = gyro_bias + db
        cov_a = jf.cov[:9, :9]
        cov_g_full = jf.cov[9:18, 9:18]
        if cfg.estimate_gyro_bias or cfg.gyro_g_sensitivity:
            cov_bias = jf.cov[18:21, 18:21]
        log.debug("joint fit noise levels: %s", jf.sigmas)
        accel_model = TriadModel(
            misalignment_matrix(*theta_a[:3]), theta_a[3:6], theta_a[6:9], cfg.bias_sign
        )
        means_c = accel_model.apply(raw_means)
        u = means_c / np.linalg.norm(means_c, axis=1, keepdims=True)
        u0, u1 = u[pairs[:, 0]], u[pairs[:, 1]]
        idx = (iv[:, 0][:, None] + np.arange(nmin)[None, :]).ravel()
        r_a = cfg.g - np.linalg.norm(accel_model.apply(acc[idx]), axis=1)
    gyro_b = -bias_total if cfg.bias_sign == "plus" else bias_total
    gyro_model = TriadModel(misalignment_matrix(*theta_g[:6]), theta_g[6:9], gyro_b, cfg.bias_sign)
    same_as_fit = G is None and not np.any(db) and cfg.method == "tedaldi"
    R_after = (
        R_fit
        if same_as_fit
        else integ(
            w,
            t_s,
            segs,
            _gyro_M(theta_g[:9])[None],
            db[None],
            None if G is None else G[None],
            None if G is None else f_c,
        )[0]
    )
    t_gyro = time.perf_counter()

    _check_units(accel_model.K, "accelerometer", log_.accel_unit, "--accel-unit", log_.source)
    _check_units(gyro_model.K, "gyro", log_.gyro_unit, "--gyro-unit", log_.source)
    # A rank-deficient fit (too few poses about an axis) leaves a zero or slightly negative variance from
    # the pseudo-inverse: that parameter is undetermined, so its std is infinite, never NaN.
    std_a = _std_or_inf(np.diag(cov_a))
    std_g = _std_or_inf(np.diag(cov_g_full))[:9]
    poor = _verdict(std_a, std_g, theta_a, theta_g[:9], len(iv))
    if poor:
        warnings.append("poorly determined: " + ", ".join(poor))
    if len(iv) < 36:
        warnings.append(f"only {len(iv)} static poses; 36-50 keep every parameter well observable")
    calib = ImuCalibration(
        accel=accel_model,
        gyro=gyro_model,
        cov_accel=cov_a,
        cov_gyro=cov_g_full[:9, :9],
        cov_gyro_bias=cov_bias,
        accel_unit=log_.accel_unit,
        gyro_unit=log_.gyro_unit,
        g=cfg.g,
        source=log_.source,
        notes={
            "k": d.k,
            "n_intervals": int(len(iv)),
            "method": cfg.method,
            "warnings": list(warnings),
            **drift_notes,
        },
        gyro_g_sensitivity=G,
    )
    rms = float(np.sqrt(np.mean(r_a**2)))
    return CalibrationResult(
        calibration=calib,
        config=cfg,
        k=d.k,
        intervals=iv,
        detector=det,
        threshold=d.threshold,
        sweep=sweep,
        accel_residual_before=per_interval_norm_err(accel_init),
        accel_residual_after=per_interval_norm_err(accel_model),
        accel_rms=rms,
        gyro_residual_before_deg=_angle_deg(R_before, u0, u1),
        gyro_residual_after_deg=_angle_deg(R_after, u0, u1),
        std_accel=std_a,
        std_gyro=std_g,
        poorly_determined=poor,
        warnings=warnings + list(log_.warnings),
        timings_s={"accel": t_acc - t0, "gyro": t_gyro - t_acc, "total": t_gyro - t0},
    )
