"""The configuration of the stereo VO + IMU filter (``imuslam vio --config``; keys = field names):
the filter's noises, the VO measurement model and its gating, the non-holonomic constraints."""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    FiniteFloat,
    NonNegativeFloat,
    NonNegativeInt,
    model_validator,
)

from imuslam.ins.core import (
    KfNoise,
)
from imuslam.vio.frontend import VoConfig

FloatArray = NDArray[np.float64]
U8Image = NDArray[np.uint8]
log_ = logging.getLogger(__name__)


class NoiseConfig(BaseModel):
    """IMU noise densities (per sqrt(Hz)) and bias random walks for the filter."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    accel: float = Field(2e-3, gt=0, description="m/s^2/sqrt(Hz)")
    gyro: float = Field(1.7e-4, gt=0, description="rad/s/sqrt(Hz)")
    accel_bias_rw: float = Field(1e-4, gt=0, description="m/s^3/sqrt(Hz)")
    gyro_bias_rw: float = Field(2e-5, gt=0, description="rad/s^2/sqrt(Hz)")

    def kf(self) -> KfNoise:
        return KfNoise(self.accel, self.gyro, self.accel_bias_rw, self.gyro_bias_rw)


class VioConfig(BaseModel):
    """Everything the VIO pipeline reads; YAML keys equal the field names."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    vo: VoConfig = Field(default_factory=VoConfig)
    noise: NoiseConfig = Field(default_factory=NoiseConfig)
    g: float = Field(9.80665, gt=9.7, lt=9.9, description="local gravity, m/s^2")
    noise_from_log: bool = Field(
        True,
        description="raise the noise densities to what the log shows (vibration; KfNoise.from_log)",
    )
    nhc: bool = Field(False, description="non-holonomic constraints (ground vehicles)")
    nhc_std: float = Field(
        0.02, gt=0, description="1-sigma of lateral / vertical vehicle velocity, m/s"
    )
    nhc_std_vertical: float | None = Field(
        None,
        gt=0,
        description="1-sigma of the vertical vehicle velocity, m/s (None: nhc_std). On uneven ground the "
        "body pitches while the path stays level: the vertical body velocity is speed x pitch, a "
        "slowly varying error that white noise at nhc_rate_hz must cover with a larger sigma",
    )
    nhc_rate_hz: float = Field(20.0, gt=0, le=1000)
    vehicle_rpy_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="vehicle frame in the body (roll, pitch, yaw), deg"
    )
    vehicle_p_b: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="vehicle origin (non-sliding point) in the body, m"
    )
    gate_prob: float | None = Field(
        0.9999,
        gt=0.5,
        lt=1.0,
        description="chi-square gate; None: off. 99.99 %: the VO errors have a heavier tail than "
        "chi-square; 99.9 % rejected up to 0.48 % of good VO on the rendered robot (1.1-1.56 % with "
        "earlier front ends; bench/vio.py nhc)",
    )
    vo_cov_model: Literal["prior_floor", "residual"] = Field(
        "prior_floor",
        description="VO covariance: the motion fit's (J^T W J)^-1 at the prior pixel sigma, raised by "
        "the fit's a-posteriori variance factor when that exceeds one (prior_floor), or scaled by it "
        "(residual: sigma^2 from the reprojection residuals alone)",
    )
    vo_cov_scale: float = Field(
        1.0,
        gt=0,
        description="scale of the VO velocity covariance (1: as the front end reports it; a value "
        "calibrated on another run with known truth, e.g. by bench/vio.py sim)",
    )
    vo_rate_cov_scale: float = Field(1.0, gt=0, description="the same for the VO rate covariance")
    vo_cov_adapt_n: NonNegativeInt = Field(
        0,
        description="online scales of the VO rate and velocity covariances, learnt from the filter's "
        "own innovations (no truth needed): after each accepted VO update of a kind, its scale is "
        "multiplied by exp((NIS / 3 - 1) / n), a stochastic approximation (Robbins and Monro 1951) of "
        "E[NIS] = 3, so the scale follows the mean NIS of about the last n updates (innovation-based "
        "adaptive estimation: Mehra 1970, IEEE TAC 15(2); Mohamed and Schwarz 1999, J. Geodesy 73); "
        "applied on top of vo_cov_scale / vo_rate_cov_scale and kept within a factor 20 of them; "
        "0: off. While it adapts, a kind's mean NIS over N updates equals 3 + 3 n ln(s_end / "
        "s_start) / N exactly (the steps sum up): in band by construction, so it is no test of "
        "consistency; vo_cov_adapt_s holds the scales after a warm-up, and the NIS after it is one",
    )
    vo_cov_adapt_s: float | None = Field(
        None,
        gt=0,
        description="with vo_cov_adapt_n: adapt during this many seconds after the filter's start "
        "(the first VO pair's mid-time), then hold the scales; None: throughout the run",
    )
    vo_cov_correction: list[list[float]] | None = Field(
        None,
        description="6x6 second moment of the VO errors whitened by the front end's covariance, learnt "
        "on a run with truth (vio.covcal); the filter uses L M L^T (L L^T the reported covariance), "
        "then the block scales",
    )
    vo_bias: (
        tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] | None
    ) = Field(
        None,
        description="mean VO error [omega_b rad/s (3), vel_b m/s (3)] learnt on a run with truth "
        "(vio.covcal.vo_errors), subtracted from every VO measurement: the front end's sub-pixel "
        "tracking bias leaves a steady lateral velocity / yaw rate error that the non-holonomic "
        "constraint would otherwise explain by a gyro bias (README, VIO: the VO's shared error)",
    )
    vo_joint: bool = Field(
        True,
        description="VO rate and velocity of a frame pair as one measurement with their cross-covariance "
        "(the rate update, then the velocity conditioned on the rate; vio.kernels); "
        "False: two independent updates, the cross-covariance dropped",
    )
    vo_model: Literal["rate", "relative"] = Field(
        "rate",
        description="how the filter reads a frame pair's VO: 'rate', the mean body rate against the mean "
        "gyro (it observes the gyro bias) and the body velocity at the pair's mid-time (seed 004); "
        "'relative', the pair's rotation and translation against the pose cloned at the pair's start "
        "(stochastic cloning, vio.kernels.relative_rotation): the VO then corrects the attitude and "
        "position themselves",
    )
    vo_velocity_model: Literal["twist", "mean"] = Field(
        "twist",
        description="with vo_model 'rate': 'twist' reads the VO's mean velocity over a pair (the chord "
        "over the interval) as the constant-twist body velocity at mid-time "
        "(measurements.twist_velocity); 'mean' takes the chord for the instantaneous velocity, short "
        "by |v| (|omega| dt)^2 / 24 in turns",
    )
    vo_error_std: NonNegativeFloat | tuple[NonNegativeFloat, NonNegativeFloat, NonNegativeFloat] = (
        Field(
            0.0,
            description="with vo_model 'rate': 1-sigma of a slowly varying VO velocity error, m/s, body "
            "frame, one value or one per body axis (a first-order Gauss-Markov process with time constant "
            "vo_error_tau_s, three extra states; vio.kernels; vio.covcal.fit_vo_error learns "
            "it against a truth); 0: off",
        )
    )
    vo_error_tau_s: float = Field(
        0.6, gt=0, description="time constant of the slowly varying VO velocity error, s"
    )
    vo_velocity: bool = True
    vo_rate: bool = True
    level_window_s: float = Field(
        0.5, gt=0, description="IMU averaged for the initial roll and pitch"
    )
    init_std_theta: float = Field(0.02, gt=0, description="rad (roll, pitch)")
    init_std_yaw: float = Field(
        1e-6,
        gt=0,
        description="rad. No measurement here observes the absolute yaw, so the start's yaw defines the "
        "navigation frame (a gauge, fixed by a near-zero sigma). A large sigma without the matching "
        "correlation of the velocity (whose start is the first VO velocity rotated by that yaw) lets "
        "velocity residuals turn the heading: with 1 rad the rendered seeds' mean ATE was 0.0141 m "
        "(NHC off) / 0.0125 m (on), with 1e-6 0.0116 / 0.0079 m (bench/vio.py nhc)",
    )
    init_std_ba: float = Field(0.1, gt=0, description="m/s^2")
    init_std_bg: float = Field(
        0.002, gt=0, description="rad/s, added to the first VO rate's covariance (bias change)"
    )
    outlier_fraction: float = Field(
        0.0, ge=0, lt=1, description="simulation: VO measurements corrupted"
    )
    outlier_vel: tuple[float, float] = Field((0.1, 0.5), description="m/s, uniform magnitude range")
    outlier_rate: tuple[float, float] = Field(
        (0.02, 0.1), description="rad/s, uniform magnitude range"
    )
    outlier_seed: int = Field(0, ge=0, le=2**32 - 1)

    @model_validator(mode="after")
    def _vo_error_needs_rate(self) -> VioConfig:
        if self.vo_model != "rate" and np.max(self.vo_error_std) > 0:
            raise ValueError(
                f"vo_error_std applies to vo_model 'rate' only (vo_model is '{self.vo_model}')"
            )
        return self

    @model_validator(mode="after")
    def _adapt_s_needs_adapt_n(self) -> VioConfig:
        if self.vo_cov_adapt_s is not None and self.vo_cov_adapt_n == 0:
            raise ValueError(
                "vo_cov_adapt_s holds the online scales after a warm-up; it needs vo_cov_adapt_n > 0"
            )
        return self
