"""The calibration driver: the stages in order, from the raw log to the result."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.imu.calibrate.accel import AccelFit, fit_accelerometer
from imuslam.imu.calibrate.checks import check_log, check_units, std_or_inf, verdict
from imuslam.imu.calibrate.config import CalibrationConfig, CalibrationResult, Estimate
from imuslam.imu.calibrate.gyro import GyroFit, angle_deg, fit_gyroscope, gyro_rate_matrix
from imuslam.imu.model import ImuCalibration, TriadModel, misalignment_matrix
from imuslam.imu.static import init_variance_norm, window_half_size, windowed_variance_norm
from imuslam.interfaces.imu import ImuLog

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class StillPeriod:
    """The initial still period and the static detector: n_init, the last sample of the still period;
    detector: (N,) windowed variance norm of the accelerometer; n0: its value over the still period."""

    n_init: int
    detector: FloatArray
    n0: float


def still_period(log_: ImuLog, cfg: CalibrationConfig) -> StillPeriod:
    """Check the log and measure the initial still period (raises InputError when it cannot be used)."""
    check_log(log_)
    t_s = log_.t_s
    n_init = int(np.searchsorted(t_s, cfg.t_init_s, side="right")) - 1
    if t_s[-1] < cfg.t_init_s * 1.1 or n_init < 20:
        raise InputError(
            f"{log_.source}: the log lasts {t_s[-1]:.1f} s; it needs the initial still period of "
            f"{cfg.t_init_s:g} s and static poses after it"
        )
    acc = log_.accel
    det = windowed_variance_norm(acc, window_half_size(cfg.window_s, log_.rate_hz))
    n0 = init_variance_norm(acc, n_init)
    if not n0 > 0:
        raise InputError(
            f"{log_.source}: the accelerometer is constant over the still period (no noise?)"
        )
    return StillPeriod(n_init, det, n0)


def two_step_estimate(accel: AccelFit, accel_model: TriadModel, gyro: GyroFit) -> Estimate:
    """The calibration of the two steps (Tedaldi 2014: accelerometer, then gyroscope)."""
    sg = gyro.segments
    return Estimate(
        theta_a=accel.theta, theta_g=gyro.theta, db=gyro.db, G=None, bias_total=gyro.bias_total,
        cov_a=accel.cov, cov_g=gyro.cov, cov_bias=gyro.cov_bias, accel_model=accel_model, u0=sg.u0,
        u1=sg.u1, segs=sg.segs, r_a=accel.residual, f_c=np.zeros((1, 3)),
    )  # fmt: skip


def rotations_after(est: Estimate, gyro: GyroFit, t_s: FloatArray, method: str) -> FloatArray:
    """The rotations (S, 3, 3) of the calibrated gyro over the estimate's segments."""
    G, db = est.G, est.db
    if G is None and not np.any(db) and method == "tedaldi":
        return gyro.R_fit
    return gyro.integrate(
        gyro.segments.w,
        t_s,
        est.segs,
        gyro_rate_matrix(est.theta_g[:9])[None],
        db[None],
        None if G is None else G[None],
        None if G is None else est.f_c,
    )[0]


def calibration_of(
    log_: ImuLog, est: Estimate, accel: AccelFit, cfg: CalibrationConfig, warnings: list[str]
) -> tuple[ImuCalibration, FloatArray, FloatArray, list[str]]:
    """The calibration file's content with its covariance and observability verdict: the calibration,
    the 1-sigma (9,) of each triad's parameters and the names of the poorly determined ones."""
    theta_a, theta_g, iv = est.theta_a, est.theta_g, accel.detection.valid
    gyro_b = -est.bias_total if cfg.bias_sign == "plus" else est.bias_total
    gyro_model = TriadModel(misalignment_matrix(*theta_g[:6]), theta_g[6:9], gyro_b, cfg.bias_sign)
    check_units(est.accel_model.K, "accelerometer", log_.accel_unit, "--accel-unit", log_.source)
    check_units(gyro_model.K, "gyro", log_.gyro_unit, "--gyro-unit", log_.source)
    # A rank-deficient fit (too few poses about an axis) leaves a zero or slightly negative variance from
    # the pseudo-inverse: that parameter is undetermined, so its std is infinite, never NaN.
    std_a = std_or_inf(np.diag(est.cov_a))
    std_g = std_or_inf(np.diag(est.cov_g))[:9]
    poor = verdict(std_a, std_g, theta_a, theta_g[:9], len(iv))
    if poor:
        warnings.append("poorly determined: " + ", ".join(poor))
    if len(iv) < 36:
        warnings.append(f"only {len(iv)} static poses; 36-50 keep every parameter well observable")
    calib = ImuCalibration(
        accel=est.accel_model,
        gyro=gyro_model,
        cov_accel=est.cov_a,
        cov_gyro=est.cov_g[:9, :9],
        cov_gyro_bias=est.cov_bias,
        accel_unit=log_.accel_unit,
        gyro_unit=log_.gyro_unit,
        g=cfg.g,
        source=log_.source,
        notes={
            "k": accel.detection.k,
            "n_intervals": int(len(iv)),
            "method": cfg.method,
            "warnings": list(warnings),
            **est.notes,
        },
        gyro_g_sensitivity=est.G,
    )
    return calib, std_a, std_g, poor


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
    still = still_period(log_, cfg)
    accel = fit_accelerometer(log_.accel, still.detector, still.n0, cfg, intervals, log_.source)
    t_acc = time.perf_counter()
    accel_model, accel_init = accel.model(cfg.bias_sign), accel.initial_model(cfg.bias_sign)
    gyro = fit_gyroscope(log_, accel, accel_model, still.n_init, cfg, pair_ok)
    est = two_step_estimate(accel, accel_model, gyro)
    if cfg.method == "joint":
        from imuslam.imu.calibrate.refine import refine_jointly  # scipy.special, numba

        est = refine_jointly(log_, accel, accel_model, gyro, still.n_init, cfg)
    R_after = rotations_after(est, gyro, log_.t_s, cfg.method)
    t_gyro = time.perf_counter()
    warnings: list[str] = []
    calib, std_a, std_g, poor = calibration_of(log_, est, accel, cfg, warnings)
    iv, acc = accel.detection.valid, log_.accel

    def per_interval_norm_err(model: TriadModel) -> FloatArray:
        return np.array(
            [np.mean(np.linalg.norm(model.apply(acc[s : e + 1]), axis=1)) - cfg.g for s, e in iv]
        )

    return CalibrationResult(
        calibration=calib,
        config=cfg,
        k=accel.detection.k,
        intervals=iv,
        detector=still.detector,
        threshold=accel.detection.threshold,
        sweep=accel.sweep,
        accel_residual_before=per_interval_norm_err(accel_init),
        accel_residual_after=per_interval_norm_err(est.accel_model),
        accel_rms=float(np.sqrt(np.mean(est.r_a**2))),
        gyro_residual_before_deg=angle_deg(gyro.R_before, est.u0, est.u1),
        gyro_residual_after_deg=angle_deg(R_after, est.u0, est.u1),
        std_accel=std_a,
        std_gyro=std_g,
        poorly_determined=poor,
        warnings=warnings + list(log_.warnings),
        timings_s={"accel": t_acc - t0, "gyro": t_gyro - t_acc, "total": t_gyro - t0},
    )
