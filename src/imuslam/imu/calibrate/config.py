"""Settings and result records of the multi-position calibration."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, field_validator

from imuslam.imu.model import ImuCalibration, TriadModel

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class CalibrationConfig(BaseModel):
    """Settings of the multi-position calibration (YAML keys equal these names)."""

    model_config = ConfigDict(allow_inf_nan=False)
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


@dataclass
class Estimate:
    """The calibration as one stage hands it to the next (two-step fit, then the joint refinement).

    theta_a: (9,) accelerometer parameters (bias in the fit's sign); theta_g: (9,) gyro misalignments and
    scales, or (12,) with the two-step bias refinement; db: (3,) gyro bias correction; G: (3, 3) gyro
    g-sensitivity or None; bias_total: (3,) raw gyro bias; cov_a (9, 9), cov_g (9+, 9+), cov_bias (3, 3);
    accel_model: the calibrated accelerometer; u0 / u1: (S, 3) gravity directions around each rotation
    segs (S, 2); r_a: (M,) ``g - |a|`` of the fitted samples, m/s^2; f_c: (N, 3) calibrated specific force
    for the g-sensitivity term ((1, 3) zeros without it); notes: what the calibration file records.
    """

    theta_a: FloatArray
    theta_g: FloatArray
    db: FloatArray
    G: FloatArray | None
    bias_total: FloatArray
    cov_a: FloatArray
    cov_g: FloatArray
    cov_bias: FloatArray
    accel_model: TriadModel
    u0: FloatArray
    u1: FloatArray
    segs: IntArray
    r_a: FloatArray
    f_c: FloatArray
    notes: dict[str, object] = field(default_factory=dict)
