"""Stereo VO + IMU fusion for a ground robot (seed 004): the filter driver and the pipeline.

:class:`VioFilter` wraps the shared inertial core's :class:`~imuslam.ins.core.Eskf` (error state
``[dtheta, dp, dv, db_a, db_g]``): it propagates with the core's kernel to any time (IMU samples
interpolated at block ends), applies the measurements of :mod:`imuslam.vio.measurements` through the
core's gated ``update`` (chi-square test per measurement kind, ``gate_prob``), counts accepted and rejected
updates and keeps their NIS, and records the trajectory. :func:`run_vio` drives it from a stereo dataset:
VO per frame pair, a VO rate and a VO velocity update at each pair's mid-time (the velocity conditioned on
the rate: one motion fit gives both, with strongly correlated errors), and the non-holonomic
pseudo-measurements at ``nhc_rate_hz``; beside it, VO alone (relative poses chained) and the IMU alone
(the core's strapdown from the same initial state) for comparison.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Protocol

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

from imuslam.errors import InputError
from imuslam.geometry import exp
from imuslam.ins.core import (
    ErrorLayout,
    Eskf,
    InsState,
    KfNoise,
    Measurement,
    chi2_threshold,
    gate,
    integrate_nominal,
)
from imuslam.io.imulog import ImuLog
from imuslam.io.trajectory import Trajectory
from imuslam.vio.covcal import apply_vo_cov_correction
from imuslam.vio.frontend import StereoVO, VoConfig, VoMeasurement, VoStats
from imuslam.vio.measurements import (
    NonHolonomic,
    VoClone,
    VoRate,
    VoRelativeRotation,
    VoRelativeTranslation,
    VoRelativeTranslationGivenRotation,
    VoVelocity,
    VoVelocityGivenRate,
    WithVoError,
    twist_velocity,
)

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
        "(the rate update, then the velocity conditioned on the rate; measurements.VoVelocityGivenRate); "
        "False: two independent updates, the cross-covariance dropped",
    )
    vo_model: Literal["rate", "relative"] = Field(
        "rate",
        description="how the filter reads a frame pair's VO: 'rate', the mean body rate against the mean "
        "gyro (it observes the gyro bias) and the body velocity at the pair's mid-time (seed 004); "
        "'relative', the pair's rotation and translation against the pose cloned at the pair's start "
        "(stochastic cloning, measurements.VoRelativeRotation): the VO then corrects the attitude and "
        "position themselves. 'relative' runs the Python filter (compiled is ignored)",
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
            "vo_error_tau_s, three extra states; measurements.WithVoError; vio.covcal.fit_vo_error learns "
            "it against a truth); 0: off. Runs the Python filter (compiled is ignored)",
        )
    )
    vo_error_tau_s: float = Field(
        0.6, gt=0, description="time constant of the slowly varying VO velocity error, s"
    )
    compiled: bool = Field(
        True,
        description="the compiled frame step (vio/kernels.py); False: the Python reference filter",
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


@dataclass
class GateStats:
    """Accepted / rejected updates of one measurement kind and their NIS (all, gated or not)."""

    dof: int
    accepted: int = 0
    rejected: int = 0
    nis: list[float] = field(default_factory=list)
    accepted_mask: list[bool] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        from scipy.stats import chi2

        nis = np.asarray(self.nis)
        acc = np.asarray(self.accepted_mask, bool)
        n = int(acc.sum())
        out: dict[str, Any] = {
            "dof": self.dof,
            "accepted": self.accepted,
            "rejected": self.rejected,
        }
        if n:
            m = float(nis[acc].mean())
            out["nis_mean_accepted"] = m
            out["nis_mean_band_95"] = [
                float(chi2.ppf(0.025, n * self.dof) / n),
                float(chi2.ppf(0.975, n * self.dof) / n),
            ]
            lo, hi = chi2.ppf(0.025, self.dof), chi2.ppf(0.975, self.dof)
            out["nis_share_in_95_band"] = float(np.mean((nis[acc] >= lo) & (nis[acc] <= hi)))
        return out


def level_attitude(accel_b: FloatArray) -> FloatArray:
    """R_n_b with zero yaw whose gravity matches the mean specific force (N, 3) (f_b = R^T [0, 0, g])."""
    f = accel_b.mean(axis=0)
    roll = np.arctan2(f[1], f[2])
    pitch = np.arctan2(-f[0], np.hypot(f[1], f[2]))
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return Ry @ Rx


def rpy_matrix(rpy_deg: tuple[float, float, float]) -> FloatArray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) from degrees."""
    r, p, y = np.deg2rad(rpy_deg)
    return (
        exp(np.array([0.0, 0.0, y])) @ exp(np.array([0.0, p, 0.0])) @ exp(np.array([r, 0.0, 0.0]))
    )


# the row of VioFilter.vo_scale that a measurement kind's NIS adapts
_ADAPT_ROW = {"vo_rate": 0, "vo_velocity": 1}


class VioFilter:
    """The core's ESKF driven to arbitrary times, with per-kind gating statistics and a recorded track.

    Times are float seconds since ``t_ref_ns``. IMU samples (SI, body frame) are interpolated linearly at
    the ends of each prediction block, so an update happens exactly at its measurement's time.
    """

    def __init__(
        self, imu: ImuLog, t_ref_ns: int, x0: InsState, P0: FloatArray, t0_s: float, cfg: VioConfig
    ) -> None:
        self.cfg = cfg
        self.t_ref_ns = t_ref_ns
        self.t_imu = (imu.t_ns - t_ref_ns).astype(float) * 1e-9
        self.acc = imu.accel
        self.gyr = imu.gyro
        noise = cfg.noise.kf()
        if cfg.noise_from_log:
            sel = (self.t_imu >= t0_s) & (self.t_imu <= t0_s + 5.0)
            if sel.sum() > 10:
                noise = KfNoise.from_log(self.acc[sel], self.gyr[sel], imu.rate_hz, floor=noise)
        self.noise = noise
        self.clone: VoClone | None = None
        self.vo_error: FloatArray | None = None  # the slowly varying VO velocity error (nominal)
        self.vo_error_var = np.broadcast_to(np.asarray(cfg.vo_error_std, float) ** 2, (3,)).copy()
        if cfg.vo_model == "rate" and self.vo_error_var.max() > 0:
            lay = ErrorLayout(True, True, False, extra=3)
            Pa = np.zeros((lay.dim, lay.dim))
            Pa[: lay.base_dim, : lay.base_dim] = P0
            Pa[lay.base_dim :, lay.base_dim :] = np.diag(self.vo_error_var)
            self.kf = Eskf(x0, P=Pa, noise=noise, layout=lay)
            self.vo_error = np.zeros(3)
        elif cfg.vo_model == "relative":
            # the pose at the pair's start, cloned into the error state
            lay = ErrorLayout(True, True, False, extra=6)
            Pa = np.zeros((lay.dim, lay.dim))
            Pa[: lay.base_dim, : lay.base_dim] = P0
            self.kf = Eskf(x0, P=Pa, noise=noise, layout=lay)
            self._clone()
        else:
            self.kf = Eskf(x0, P=P0, noise=noise, layout=ErrorLayout.full())
        self.t = t0_s
        self.stats: dict[str, GateStats] = {}
        self._t: list[FloatArray] = [np.array([t0_s])]
        self._p: list[FloatArray] = [x0.p_n[None].copy()]
        self._R: list[FloatArray] = [x0.R_n_b[None].copy()]
        self._bias_t: list[float] = []
        self._bias: list[FloatArray] = []
        self._bias_std: list[FloatArray] = []
        self.next_nhc = t0_s + 1.0 / cfg.nhc_rate_hz
        # the online VO covariance scales [rate, velocity] (cfg.vo_cov_adapt_n; ones when off)
        self.vo_scale = np.ones(2)
        self.adapt_until = np.inf if cfg.vo_cov_adapt_s is None else t0_s + cfg.vo_cov_adapt_s
        self.R_b_v = rpy_matrix(cfg.vehicle_rpy_deg)
        self.p_b_v = np.asarray(cfg.vehicle_p_b, float)

    def _clone(self) -> None:
        """Clone the current attitude and position (their error rows and columns of P, and their nominal
        values) into the extra states, replacing the former clone."""
        lay = self.kf.layout
        o = lay.base_dim
        idx = np.r_[np.arange(lay.TH.start, lay.TH.stop), np.arange(lay.P.start, lay.P.stop)]
        P = self.kf.P
        P[o : o + 6, :] = P[idx, :]
        P[:, o : o + 6] = P[:, idx]
        x = self.kf.x
        self.clone = VoClone(x.R_n_b.copy(), x.p_n.copy(), o)

    def sample_at(self, t: float) -> tuple[FloatArray, FloatArray]:
        """Interpolated (accel, gyro) at time t."""
        k = int(np.clip(np.searchsorted(self.t_imu, t) - 1, 0, len(self.t_imu) - 2))
        w = (t - self.t_imu[k]) / (self.t_imu[k + 1] - self.t_imu[k])
        return (1 - w) * self.acc[k] + w * self.acc[k + 1], (1 - w) * self.gyr[k] + w * self.gyr[
            k + 1
        ]

    def gyro_mean(self, t0: float, t1: float) -> FloatArray:
        """Mean raw gyro over [t0, t1] (trapezoid over the samples and the interpolated ends)."""
        i0, i1 = np.searchsorted(self.t_imu, [t0, t1], side="right")
        ts = np.concatenate([[t0], self.t_imu[i0:i1], [t1]])
        g0, g1 = self.sample_at(t0)[1], self.sample_at(t1)[1]
        gs = np.concatenate([g0[None], self.gyr[i0:i1], g1[None]])
        dt = np.diff(ts)
        return (0.5 * (gs[1:] + gs[:-1]) * dt[:, None]).sum(axis=0) / max(t1 - t0, 1e-12)

    def advance(self, t: float) -> None:
        """Predict from the current time to ``t`` (no-op when ``t`` is not later)."""
        if t <= self.t:
            return
        i0, i1 = np.searchsorted(self.t_imu, [self.t, t], side="right")
        a0, g0 = self.sample_at(self.t)
        a1, g1 = self.sample_at(t)
        ts = np.concatenate([[self.t], self.t_imu[i0:i1], [t]])
        keep = np.concatenate([[True], np.diff(ts) > 1e-9])
        acc = np.concatenate([a0[None], self.acc[i0:i1], a1[None]])[keep]
        gyr = np.concatenate([g0[None], self.gyr[i0:i1], g1[None]])[keep]
        ts = ts[keep]
        if len(ts) < 2:
            return
        Ps, _, Rs = self.kf.predict(acc, gyr, ts)
        if self.vo_error is not None:
            # the Gauss-Markov error's own transition (the core's is identity)
            o = self.kf.layout.base_dim
            phi = float(np.exp(-(ts[-1] - ts[0]) / self.cfg.vo_error_tau_s))
            P = self.kf.P
            P[o:, :] *= phi
            P[:, o:] *= phi
            P[o:, o:] += np.diag(self.vo_error_var) * (1.0 - phi**2)
            self.vo_error = self.vo_error * phi
        self._t.append(ts[1:-1])
        self._p.append(Ps[1:-1])
        self._R.append(Rs[1:-1])
        self.t = t

    def mark(self) -> None:
        """Record the current (posterior) state at the current time."""
        x = self.kf.x
        self._t.append(np.array([self.t]))
        self._p.append(x.p_n[None].copy())
        self._R.append(x.R_n_b[None].copy())
        d = np.sqrt(np.diag(self.kf.P))
        lay = self.kf.layout
        self._bias_t.append(self.t)
        self._bias.append(np.concatenate([x.accel_bias, x.gyro_bias]))
        self._bias_std.append(np.concatenate([d[lay.BA], d[lay.BG]]))

    def update(self, meas: Measurement, dof: int) -> bool:
        """Gated update through the core; returns whether it was accepted."""
        if self.vo_error is not None and isinstance(meas, VoVelocity | VoVelocityGivenRate):
            meas = WithVoError(meas, self.vo_error, self.kf.layout.base_dim)
        st = self.stats.setdefault(meas.kind, GateStats(dof))
        if self.cfg.gate_prob is None:  # no gate: the NIS for the statistics, then the update
            r, H, Rm = meas.linearize(self.kf.x, self.kf.layout)
            nis = gate(r, H, Rm, self.kf.P, 0.5)[1]
            res = self.kf.update(meas, None)
        else:
            res = self.kf.update(meas, self.cfg.gate_prob)
            nis = res.nis
        st.nis.append(nis)
        st.accepted_mask.append(res.accepted)
        if res.accepted and self.vo_error is not None:  # the VO error's share of the correction
            o = self.kf.layout.base_dim
            self.vo_error = self.vo_error + res.dx[o : o + 3]
        if res.accepted and self.clone is not None:  # the clone's share of the correction
            c = self.clone
            c.R_n_b = c.R_n_b @ exp(res.dx[c.TH])
            c.p_n = c.p_n + res.dx[c.P]
        if res.accepted:
            st.accepted += 1
            row = _ADAPT_ROW.get(meas.kind)
            if self.cfg.vo_cov_adapt_n and row is not None and self.t < self.adapt_until:
                from imuslam.vio.kernels import adapt_scale

                self.vo_scale[row] = adapt_scale(
                    self.vo_scale[row], nis, 3.0, self.cfg.vo_cov_adapt_n
                )
        else:
            st.rejected += 1
        return res.accepted

    def frame(
        self,
        t_s: float,
        vel_b: FloatArray | None = None,
        cov_vel: FloatArray | None = None,
        omega_b: FloatArray | None = None,
        cov_omega: FloatArray | None = None,
        t0_s: float = 0.0,
        t1_s: float = 0.0,
        cov_wv: FloatArray | None = None,
    ) -> bool:
        """Everything up to one VO frame's mid-time ``t_s``: the non-holonomic updates due before it
        (when ``cfg.nhc``), the prediction to ``t_s``, the VO rate update (``omega_b`` (3,) rad/s over
        [t0_s, t1_s], covariance (3, 3)) and the VO velocity update (``vel_b`` (3,) m/s, body, covariance
        (3, 3)) when given, and a record. With ``cov_wv`` (3, 3), the rate-velocity cross-covariance,
        and an accepted rate update, the velocity is conditioned on the rate
        (:class:`~imuslam.vio.measurements.VoVelocityGivenRate`); otherwise it is applied alone. Returns
        whether the velocity update was accepted (True without one). This is the reference (one Python
        call per event); :class:`CompiledVioFilter` does the same in one compiled call."""
        if self.cfg.vo_cov_adapt_n:  # the online scales in force now
            s_w, s_v = self.vo_scale
            cov_omega = None if cov_omega is None else cov_omega * s_w
            cov_vel = None if cov_vel is None else cov_vel * s_v
            cov_wv = None if cov_wv is None else cov_wv * np.sqrt(s_w * s_v)
        if self.clone is not None:
            return self._frame_relative(t_s, vel_b, cov_vel, omega_b, cov_omega, t0_s, t1_s, cov_wv)
        self._nhc_until(t_s)
        self.advance(t_s)
        ok_v = ok_w = True
        rate = None
        if omega_b is not None and cov_omega is not None:
            g_mean = self.gyro_mean(t0_s, t1_s)
            gv = self.noise.gyro**2 / (t1_s - t0_s)
            rate = VoRate(omega_b, cov_omega, g_mean, gv)
            ok_w = self.update(rate, 3)
        if vel_b is not None and cov_vel is not None:
            if rate is not None and ok_w and cov_wv is not None:
                ok_v = self.update(
                    VoVelocityGivenRate.from_joint(
                        vel_b, rate.omega_b, rate.gyro_mean, rate.cov + np.eye(3) * rate.gyro_var,
                        cov_wv, cov_vel,
                    ), 3,
                )  # fmt: skip
            else:
                ok_v = self.update(VoVelocity(vel_b, cov_vel), 3)
        self.mark()
        return ok_v

    def _nhc_until(self, t_s: float) -> None:
        """The non-holonomic updates due before ``t_s`` (when ``cfg.nhc``), each with a record."""
        cfg = self.cfg
        while cfg.nhc and self.next_nhc < t_s:
            self.advance(self.next_nhc)
            gyro = self.sample_at(self.next_nhc)[1]
            self.update(
                NonHolonomic(cfg.nhc_std, gyro, self.R_b_v, self.p_b_v, cfg.nhc_std_vertical), 2
            )
            self.mark()
            self.next_nhc += 1.0 / cfg.nhc_rate_hz

    def _frame_relative(
        self,
        t_s: float,
        vel_b: FloatArray | None,
        cov_vel: FloatArray | None,
        omega_b: FloatArray | None,
        cov_omega: FloatArray | None,
        t0_s: float,
        t1_s: float,
        cov_wv: FloatArray | None,
    ) -> bool:
        """:meth:`frame` with ``vo_model: relative``: to the pair's start ``t0_s`` (clone there), to its
        end ``t1_s``, then the VO rotation and translation against the clone (the translation
        conditioned on the rotation when ``cov_wv`` is given). A pair that starts before the filter's
        current time (the first, whose mid-time starts the filter) only moves the filter to its end.
        Without a measurement: to ``t_s``."""
        if omega_b is None and vel_b is None:
            self._nhc_until(t_s)
            self.advance(t_s)
            self.mark()
            return True
        usable = self.t <= t0_s + 1e-9
        if usable:
            self._nhc_until(t0_s)
            self.advance(t0_s)
            self._clone()
        self._nhc_until(t1_s)
        self.advance(t1_s)
        ok_v = ok_w = True
        if usable:
            assert self.clone is not None
            dt = t1_s - t0_s
            w = omega_b if omega_b is not None else np.zeros(3)
            if omega_b is not None and cov_omega is not None:
                ok_w = self.update(VoRelativeRotation(omega_b, cov_omega, dt, self.clone), 3)
            if vel_b is not None and cov_vel is not None:
                if omega_b is not None and cov_omega is not None and ok_w and cov_wv is not None:
                    meas: Measurement = VoRelativeTranslationGivenRotation(
                        vel_b, omega_b, cov_omega, cov_wv, cov_vel, dt, self.clone
                    )
                else:
                    meas = VoRelativeTranslation(vel_b, cov_vel, w, dt, self.clone)
                ok_v = self.update(meas, 3)
        self.mark()
        return ok_v

    def trajectory(self, source: str) -> Trajectory:
        t = np.concatenate(self._t)
        order = np.argsort(t, kind="stable")
        t_ns = self.t_ref_ns + np.round(t[order] * 1e9).astype(np.int64)
        # a time recorded twice (prior then posterior): keep the last
        last = np.concatenate([t_ns[1:] != t_ns[:-1], [True]])
        return Trajectory(
            t_ns[last],
            np.concatenate(self._p)[order][last],
            np.concatenate(self._R)[order][last],
            source,
        )

    def gate_stats(self) -> dict[str, GateStats]:
        """Accepted / rejected updates and their NIS per measurement kind."""
        return self.stats

    def biases(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Times (s since t_ref), biases (N, 6) [accel, gyro] and their 1-sigma (N, 6) at each mark."""
        return np.asarray(self._bias_t), np.asarray(self._bias), np.asarray(self._bias_std)


class CompiledVioFilter(VioFilter):
    """:class:`VioFilter` whose :meth:`frame` is one compiled call (:func:`imuslam.vio.kernels.frame_step`)
    per VO frame: the NHC updates, the prediction over the IMU samples and the VO updates run in numba
    on the core's kernels, updating the core filter's state arrays in place; records go to growing
    buffers. Results equal the reference's to rounding (``tests/vio/test_vio_filter.py``)."""

    _KINDS = (("nhc", 2), ("vo_velocity", 3), ("vo_rate", 3))

    def __init__(
        self, imu: ImuLog, t_ref_ns: int, x0: InsState, P0: FloatArray, t0_s: float, cfg: VioConfig
    ) -> None:
        super().__init__(imu, t_ref_ns, x0, P0, t0_s, cfg)
        x = self.kf.x
        for name in ("p_n", "v_n", "R_n_b", "accel_bias", "gyro_bias", "g_n"):
            setattr(x, name, np.ascontiguousarray(getattr(x, name), dtype=np.float64).copy())
        self.kf.P = np.ascontiguousarray(self.kf.P, dtype=np.float64)
        self.t_imu = np.ascontiguousarray(self.t_imu)
        self.acc = np.ascontiguousarray(self.acc, dtype=np.float64)
        self.gyr = np.ascontiguousarray(self.gyr, dtype=np.float64)
        self._clock = np.array([t0_s, self.next_nhc])
        self._cnt = np.zeros(5, np.int64)
        self._tr_t = np.zeros(0)
        self._tr_p = np.zeros((0, 3))
        self._tr_R = np.zeros((0, 3, 3))
        self._b_t = np.zeros(0)
        self._b = np.zeros((0, 6))
        self._b_s = np.zeros((0, 6))
        self._nis = np.zeros((3, 0))
        self._acc = np.zeros((3, 0), bool)
        self._reserve(1024, 256)
        # the reference's first record (the initial state)
        self._tr_t[0], self._tr_p[0], self._tr_R[0] = t0_s, x0.p_n, x0.R_n_b
        self._cnt[0] = 1
        self._gate = cfg.gate_prob is not None
        self._thr2 = chi2_threshold(cfg.gate_prob, 2) if cfg.gate_prob is not None else np.inf
        self._thr3 = chi2_threshold(cfg.gate_prob, 3) if cfg.gate_prob is not None else np.inf
        self._q = self.noise.q
        self._off = self.kf.layout.offsets
        import imuslam.vio.kernels as kern
        from imuslam.vio.kernels import C_LEN

        self._kern = kern
        self._const = np.zeros(C_LEN)
        std_z = cfg.nhc_std if cfg.nhc_std_vertical is None else cfg.nhc_std_vertical
        self._const[:] = (float(cfg.nhc), cfg.nhc_std, 1.0 / cfg.nhc_rate_hz, self.noise.gyro**2,
                          float(self._gate), self._thr2, self._thr3, std_z,
                          float(cfg.vo_cov_adapt_n), self.adapt_until)  # fmt: skip
        self.R_b_v = np.ascontiguousarray(self.R_b_v, dtype=np.float64)
        self.p_b_v = np.ascontiguousarray(self.p_b_v, dtype=np.float64)

    def _reserve(self, n_track: int, n_events: int) -> None:
        """Grow the buffers (doubling) so that ``n_track`` more track rows and ``n_events`` more marks
        and updates per kind fit."""

        def grow(a: Any, need: int, axis: int = 0) -> Any:
            if a.shape[axis] >= need:
                return a
            shape = list(a.shape)
            shape[axis] = max(need, 2 * a.shape[axis])
            b = np.zeros(shape, a.dtype)
            if axis == 0:
                b[: a.shape[0]] = a
            else:
                b[:, : a.shape[1]] = a
            return b

        c = self._cnt
        self._tr_t = grow(self._tr_t, c[0] + n_track)
        self._tr_p = grow(self._tr_p, c[0] + n_track)
        self._tr_R = grow(self._tr_R, c[0] + n_track)
        self._b_t = grow(self._b_t, c[1] + n_events)
        self._b = grow(self._b, c[1] + n_events)
        self._b_s = grow(self._b_s, c[1] + n_events)
        need = int(c[2:].max()) + n_events
        self._nis = grow(self._nis, need, 1)
        self._acc = grow(self._acc, need, 1)

    def pack(
        self,
        t_s: float,
        vel_b: FloatArray | None = None,
        cov_vel: FloatArray | None = None,
        omega_b: FloatArray | None = None,
        cov_omega: FloatArray | None = None,
        t0_s: float = 0.0,
        t1_s: float = 0.0,
        cov_wv: FloatArray | None = None,
    ) -> FloatArray:
        """One frame's arguments of :meth:`frame` as the kernel's packed row (M_LEN,)."""
        K = self._kern
        meas = np.zeros(K.M_LEN)
        meas[K.M_T] = t_s
        if vel_b is not None and cov_vel is not None:
            meas[K.M_VEL : K.M_VEL + 3] = vel_b
            meas[K.M_COV_V : K.M_COV_V + 9] = cov_vel.reshape(9)
            meas[K.M_VEL_ON] = 1.0
        if omega_b is not None and cov_omega is not None:
            meas[K.M_OMEGA : K.M_OMEGA + 3] = omega_b
            meas[K.M_COV_W : K.M_COV_W + 9] = cov_omega.reshape(9)
            meas[K.M_T0], meas[K.M_T1], meas[K.M_RATE_ON] = t0_s, t1_s, 1.0
            if cov_wv is not None:
                meas[K.M_COV_WV : K.M_COV_WV + 9] = cov_wv.reshape(9)
                meas[K.M_JOINT] = 1.0
        return meas

    def frames(self, meas: FloatArray) -> NDArray[np.bool_]:
        """Several frames at once, their packed rows ``meas`` (n, M_LEN) from :meth:`pack` in time
        order, in one compiled call (:func:`imuslam.vio.kernels.run_frames`). Returns per frame whether
        its velocity update was accepted (True without one)."""
        K = self._kern
        cfg = self.cfg
        meas = np.ascontiguousarray(meas, dtype=np.float64).reshape(-1, K.M_LEN)
        n = len(meas)
        if n == 0:
            return np.zeros(0, bool)
        t_now, t_nhc = float(self._clock[0]), float(self._clock[1])
        t_last = float(meas[:, K.M_T].max())
        n_nhc = (
            int(np.ceil((t_last - t_nhc) * cfg.nhc_rate_hz)) + 2
            if cfg.nhc and t_last > t_nhc
            else 0
        )
        i0, i1 = self.t_imu.searchsorted((t_now, t_last), side="right")
        # per frame at most: its IMU samples, two interpolated block ends per NHC and per frame
        n_track = max(int(i1 - i0), 0) + 2 * n_nhc + 4 * n
        c = self._cnt
        n_events = n_nhc + 2 * n
        if (c[0] + n_track > len(self._tr_t) or c[1] + n_events > len(self._b_t)
                or max(c[2], c[3], c[4]) + n_events > self._nis.shape[1]):  # fmt: skip
            self._reserve(n_track, n_events)
        x = self.kf.x
        vel_ok = np.ones(n, bool)
        bad = K.run_frames(
            self.t_imu, self.acc, self.gyr, x.p_n, x.v_n, x.R_n_b, x.accel_bias, x.gyro_bias, x.g_n,
            self.kf.P, self._clock, self.vo_scale, meas, self._const, self.R_b_v, self.p_b_v, self._q, self._off,
            self._tr_t, self._tr_p, self._tr_R, self._b_t, self._b, self._b_s,
            self._nis, self._acc, self._cnt, vel_ok,
        )  # fmt: skip
        self.t = float(self._clock[0])
        self.next_nhc = float(self._clock[1])
        if bad >= 0:
            from imuslam.errors import FilterDivergence

            raise FilterDivergence(
                f"filter diverged at t = {self._clock[0]:.3f} s after the start (frame mid-time "
                f"{meas[bad, K.M_T]:.3f} s): covariance not positive definite or state not finite; "
                "check the noise settings and the aiding"
            )
        return vel_ok

    def frame(
        self,
        t_s: float,
        vel_b: FloatArray | None = None,
        cov_vel: FloatArray | None = None,
        omega_b: FloatArray | None = None,
        cov_omega: FloatArray | None = None,
        t0_s: float = 0.0,
        t1_s: float = 0.0,
        cov_wv: FloatArray | None = None,
    ) -> bool:
        row = self.pack(t_s, vel_b, cov_vel, omega_b, cov_omega, t0_s, t1_s, cov_wv)
        return bool(self.frames(row[None])[0])

    def mark(self) -> None:
        from imuslam.vio.kernels import mark_state

        self._reserve(1, 1)
        x = self.kf.x
        mark_state(self.t, x.p_n, x.R_n_b, x.accel_bias, x.gyro_bias, self.kf.P, self._off,
                   self._tr_t, self._tr_p, self._tr_R, self._b_t, self._b, self._b_s, self._cnt)  # fmt: skip

    def gate_stats(self) -> dict[str, GateStats]:
        out: dict[str, GateStats] = {}
        for k, (name, dof) in enumerate(self._KINDS):
            n = int(self._cnt[2 + k])
            if n == 0:
                continue
            acc = self._acc[k, :n]
            out[name] = GateStats(dof, int(acc.sum()), int(n - acc.sum()), self._nis[k, :n].tolist(),
                                  acc.tolist())  # fmt: skip
        return out

    def trajectory(self, source: str) -> Trajectory:
        n = int(self._cnt[0])
        self._t, self._p, self._R = [self._tr_t[:n]], [self._tr_p[:n]], [self._tr_R[:n]]
        return super().trajectory(source)

    def biases(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        n = int(self._cnt[1])
        return self._b_t[:n].copy(), self._b[:n].copy(), self._b_s[:n].copy()


class StereoImuDataset(Protocol):
    """What :func:`run_vio` reads: an EuRoC folder, a bag, the simulator."""

    imu: ImuLog
    source: str

    def __len__(self) -> int: ...

    def rectification(self) -> Any: ...

    def skipped_frames(self) -> dict[str, int]: ...

    def frames(self) -> Iterator[tuple[int, U8Image | None, U8Image | None]]: ...


@dataclass
class VioResult:
    """Fused, VO-only and IMU-only trajectories (body poses), statistics and the per-update records."""

    fused: Trajectory
    vo: Trajectory
    imu: Trajectory
    gating: dict[str, GateStats]
    vo_stats: VoStats
    frames: dict[str, int]
    outliers: dict[str, int]
    bias_t_s: FloatArray
    bias: FloatArray
    bias_std: FloatArray
    config: VioConfig
    vo_measurements: list[VoMeasurement] = field(default_factory=list, repr=False)
    corrupted: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool), repr=False)
    vel_accepted: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool), repr=False)
    vo_scale: FloatArray = field(default_factory=lambda: np.ones(2), repr=False)
    """the online VO covariance scales [rate, velocity] at the end (``VioConfig.vo_cov_adapt_n``)"""

    def summary(self) -> dict[str, Any]:
        out = {
            "frames": self.frames,
            "vo": {
                "measurements": self.vo_stats.measurements,
                "skipped_few_features": self.vo_stats.skipped_few_features,
                "skipped_few_inliers": self.vo_stats.skipped_few_inliers,
                "mean_tracked": float(np.mean(self.vo_stats.tracked))
                if self.vo_stats.tracked
                else 0.0,
                "mean_inliers": float(np.mean(self.vo_stats.inliers))
                if self.vo_stats.inliers
                else 0.0,
                # where the front end's time went, per frame (VO runs pickled before the timing
                # existed have none)
                "ms_per_frame": {
                    k: 1e3 * v / max(self.vo_stats.frames, 1)
                    for k, v in getattr(self.vo_stats, "seconds", {}).items()
                },
            },
            "gating": {k: v.summary() for k, v in self.gating.items()},
            "outliers": self.outliers,
            "final_bias": {
                "accel": self.bias[-1, :3].tolist() if len(self.bias) else None,
                "gyro": self.bias[-1, 3:].tolist() if len(self.bias) else None,
            },
        }
        if self.config.vo_cov_adapt_n:
            out["vo_cov_adapted_scale"] = {
                "rate": float(self.vo_scale[0]),
                "velocity": float(self.vo_scale[1]),
            }
        return out


def vo_cov(m: VoMeasurement, cfg: VioConfig, M: FloatArray | None = None) -> FloatArray:
    """The (6, 6) covariance of ``[omega_b, vel_b]`` the filter uses for a VO measurement (see
    ``VioConfig.vo_cov_model``), reshaped by the correction ``M`` (6, 6) (``L M L^T``, see
    :mod:`imuslam.vio.covcal`), its rate and velocity blocks scaled by ``vo_rate_cov_scale`` and
    ``vo_cov_scale``."""
    if cfg.vo_cov_model == "residual" and m.cov_fit is not None:
        cov = m.cov_fit * m.var_factor
    else:
        cov = m.cov
    if M is not None:
        cov = apply_vo_cov_correction(cov, M)
    if cfg.vo_rate_cov_scale == 1.0 and cfg.vo_cov_scale == 1.0:
        return cov
    s = np.sqrt(np.r_[[cfg.vo_rate_cov_scale] * 3, [cfg.vo_cov_scale] * 3])
    return np.asarray(cov * np.outer(s, s), dtype=np.float64)


def _correction(cfg: VioConfig) -> FloatArray | None:
    """``cfg.vo_cov_correction`` as a (6, 6) array, checked symmetric positive definite."""
    if cfg.vo_cov_correction is None:
        return None
    M = np.asarray(cfg.vo_cov_correction, dtype=float)
    if M.shape != (6, 6) or not np.all(np.isfinite(M)) or not np.allclose(M, M.T, atol=1e-9):
        raise InputError(
            f"config: vo_cov_correction has shape {M.shape}; expected a finite symmetric 6x6 matrix"
        )
    if np.linalg.eigvalsh(M).min() <= 0:
        raise InputError("config: vo_cov_correction is not positive definite")
    return M


def _check_imu_span(imu: ImuLog, t_first: int, t_last: int, source: str) -> None:
    if len(imu) < 2 or imu.t_ns[-1] <= t_first or imu.t_ns[0] >= t_last:
        raise InputError(
            f"{source}: no IMU samples in the image time span "
            f"({t_first * 1e-9:.3f}-{t_last * 1e-9:.3f} s; IMU "
            f"{imu.t_ns[0] * 1e-9 if len(imu) else float('nan'):.3f}-"
            f"{imu.t_ns[-1] * 1e-9 if len(imu) else float('nan'):.3f} s)"
        )


@dataclass
class VoRun:
    """The front end's output over a run, reusable by several filter configurations: per used frame its
    time and the measurement since the previous one (None: first frame or skipped), and the counts."""

    frames: list[tuple[int, VoMeasurement | None]]
    stats: VoStats
    seen: int
    unreadable: int


def compute_vo(
    data: StereoImuDataset, cfg: VoConfig, progress: Callable[[int], None] | None = None
) -> VoRun:
    """The whole front end at once (see :class:`VoRun`)."""
    rect = data.rectification()
    vo = StereoVO(rect, cfg)
    frames: list[tuple[int, VoMeasurement | None]] = []
    seen = unreadable = 0
    for t_ns, left, right in data.frames():
        seen += 1
        if progress is not None:
            progress(1)
        if left is None or right is None:
            unreadable += 1
            continue
        lr, rr = rect.rectify(left, right)
        frames.append((t_ns, vo.process(t_ns, lr, rr)))
    return VoRun(frames, vo.stats, seen, unreadable)


def run_vio(
    data: StereoImuDataset,
    cfg: VioConfig | None = None,
    progress: Callable[[int], None] | None = None,
    vo_run: VoRun | None = None,
) -> VioResult:
    """VO on every stereo pair (or the given ``vo_run``) and the EKF over the IMU; ``progress(n)`` is
    called per frame."""
    cfg = cfg or VioConfig()
    imu = data.imu.to_si()
    if vo_run is None:
        vo_run = compute_vo(data, cfg.vo, progress)
    rng = np.random.default_rng(cfg.outlier_seed)
    M_cov = _correction(cfg)

    filt: VioFilter | None = None
    t_ref = 0
    imu_track: Trajectory | None = None
    T_vo = np.eye(4)
    vo_t: list[int] = []
    vo_T: list[FloatArray] = []
    meas_all: list[VoMeasurement] = []
    corrupted: list[bool] = []
    vel_acc: list[bool] = []
    batch: list[FloatArray] = []
    frames_seen = vo_run.seen
    unreadable = vo_run.unreadable
    if vo_run.frames:
        _check_imu_span(imu, vo_run.frames[0][0], vo_run.frames[-1][0], data.source)
    T_prev_rel = np.eye(4)

    for t_ns, m in vo_run.frames:
        # VO alone: chain the relative poses (a skipped pair keeps the last motion)
        if m is not None:
            T_prev_rel = m.T_b0_b1
        if vo_t:
            T_vo = T_vo @ T_prev_rel
        vo_t.append(t_ns)
        vo_T.append(T_vo.copy())
        if m is None:
            continue
        if cfg.vo_bias is not None:  # the learnt steady VO error, before any use of the measurement
            b = np.asarray(cfg.vo_bias, dtype=float)
            m = replace(m, omega_b=m.omega_b - b[:3], vel_b=m.vel_b - b[3:])
        if filt is None:
            # initial state at the first pair's mid-time: roll and pitch from the mean specific force,
            # yaw zero, velocity from the first VO velocity, the gyro bias from the first VO rate
            # against the mean gyro over the pair (a MEMS gyro's bias can be several deg/s, far outside
            # any gate around zero), the accelerometer bias zero
            t_ref = m.t0_ns
            t_imu = (imu.t_ns - t_ref) * 1e-9
            t_mid = (m.t_mid_ns - t_ref) * 1e-9
            win = (t_imu >= t_mid - cfg.level_window_s / 2) & (
                t_imu <= t_mid + cfg.level_window_s / 2
            )
            if win.sum() < 2:
                _check_imu_span(imu, m.t0_ns, m.t1_ns, data.source)
                win = np.abs(t_imu - t_mid) == np.min(np.abs(t_imu - t_mid))
            R0 = level_attitude(imu.accel[win])
            v0 = R0 @ m.vel_b
            i0, i1 = np.searchsorted(imu.t_ns, [m.t0_ns, m.t1_ns])
            bg0 = (imu.gyro[i0:i1].mean(axis=0) - m.omega_b) if i1 > i0 else np.zeros(3)
            x0 = InsState(np.zeros(3), v0, R0, np.zeros(3), bg0, np.array([0.0, 0.0, -cfg.g]))
            lay = ErrorLayout.full()
            P0 = np.zeros((lay.dim, lay.dim))
            P0[lay.TH, lay.TH] = np.diag([cfg.init_std_theta**2] * 2 + [cfg.init_std_yaw**2])
            P0[lay.P, lay.P] = np.eye(3) * 1e-8
            P0[lay.V, lay.V] = R0 @ m.cov[3:, 3:] @ R0.T + np.eye(3) * 1e-4
            P0[lay.BA, lay.BA] = np.eye(3) * cfg.init_std_ba**2
            P0[lay.BG, lay.BG] = m.cov[:3, :3] + np.eye(3) * (
                cfg.init_std_bg**2 + cfg.noise.gyro**2 / max(m.dt, 1e-3)
            )
            compiled = cfg.compiled and cfg.vo_model == "rate" and np.max(cfg.vo_error_std) == 0
            filt = (CompiledVioFilter if compiled else VioFilter)(imu, t_ref, x0, P0, t_mid, cfg)
            filt.mark()
            # the IMU alone from the same state
            sel = (t_imu > t_mid) & (imu.t_ns <= vo_run.frames[-1][0] + 50_000_000)
            a0, g0 = filt.sample_at(t_mid)
            ts = np.concatenate([[t_mid], t_imu[sel]])
            acc = np.concatenate([a0[None], imu.accel[sel]])
            gyr = np.concatenate([g0[None], imu.gyro[sel]])
            Pi, _, Ri = integrate_nominal(
                acc, gyr, np.diff(ts), x0.p_n, x0.v_n, R0, np.zeros(3), bg0, x0.g_n, np.zeros(3)
            )
            imu_track = Trajectory(t_ref + np.round(ts * 1e9).astype(np.int64), Pi, Ri, "IMU only")
            continue
        # corrupt a share of the measurements (simulation studies of the gate)
        bad = bool(cfg.outlier_fraction > 0 and rng.uniform() < cfg.outlier_fraction)
        if bad:
            dv = rng.normal(size=3)
            dw = rng.normal(size=3)
            m = VoMeasurement(
                m.t0_ns, m.t1_ns, m.omega_b + dw / np.linalg.norm(dw) * rng.uniform(*cfg.outlier_rate),
                m.vel_b + dv / np.linalg.norm(dv) * rng.uniform(*cfg.outlier_vel), m.cov, m.T_b0_b1,
                m.n_inliers, m.cov_fit, m.var_factor,
            )  # fmt: skip
        cov = vo_cov(m, cfg, M_cov)
        vel_b = m.vel_b
        if cfg.vo_model == "rate" and cfg.vo_velocity_model == "twist":
            vel_b, cov = twist_velocity(m.omega_b, m.vel_b, cov, m.dt)
        args = (
            (m.t_mid_ns - t_ref) * 1e-9,
            vel_b if cfg.vo_velocity else None, cov[3:, 3:],
            m.omega_b if cfg.vo_rate else None, cov[:3, :3],
            (m.t0_ns - t_ref) * 1e-9, (m.t1_ns - t_ref) * 1e-9,
            cov[:3, 3:] if cfg.vo_joint else None,
        )  # fmt: skip
        if isinstance(filt, CompiledVioFilter):  # the whole run in one compiled call, below
            batch.append(filt.pack(*args))
        else:
            vel_acc.append(filt.frame(*args))
        meas_all.append(m)
        corrupted.append(bad)

    if filt is None or imu_track is None:
        raise InputError(
            f"{data.source}: no VO measurement from {frames_seen} frames "
            f"({unreadable} unreadable, {vo_run.stats.skipped_few_features} with too few features); "
            "nothing to fuse"
        )
    if isinstance(filt, CompiledVioFilter):
        vel_acc = filt.frames(np.asarray(batch).reshape(-1, len(filt.pack(0.0)))).tolist()
    # to the last frame
    filt.frame((vo_t[-1] - t_ref) * 1e-9)
    fused = filt.trajectory("fused")
    # VO alone, expressed from the same initial state as the others (pose of the first mid-time)
    vo_arr = np.asarray(vo_T)
    vo_traj = Trajectory(np.asarray(vo_t), vo_arr[:, :3, 3] @ fused.R_w_b[0].T, fused.R_w_b[0] @ vo_arr[:, :3, :3],
                         "VO only")  # fmt: skip
    imu_end = imu_track.t_ns <= vo_t[-1]
    imu_track = imu_track.subset(np.flatnonzero(imu_end))
    cor = np.asarray(corrupted, bool)
    va = np.asarray(vel_acc, bool)
    skipped = data.skipped_frames()
    bt, b, bs = filt.biases()
    return VioResult(
        fused, vo_traj, imu_track, filt.gate_stats(), vo_run.stats,
        {"listed_or_rendered": frames_seen + skipped.get("missing", 0), "missing": skipped.get("missing", 0),
         "unreadable": unreadable, "used": frames_seen - unreadable},
        {"corrupted": int(cor.sum()), "corrupted_rejected": int((cor & ~va).sum()),
         "good": int((~cor).sum()), "good_rejected": int((~cor & ~va).sum())},
        bt, b, bs, cfg, meas_all, cor, va, filt.vo_scale.copy(),
    )  # fmt: skip
