"""The stereo VO + IMU filter for a ground robot (the fusion method of source 004, see the references).

:class:`VioFilter` is the product path of every VO model: per VO frame (:class:`VoFrame`) one compiled
call (:mod:`imuslam.vio.kernels`) runs the non-holonomic updates due before it, the core's prediction
over the IMU samples, the gated VO updates and the records, on the state arrays of the shared inertial
core's :class:`~imuslam.ins.core.Eskf` (error state ``[dtheta, dp, dv, db_a, db_g]``, plus the VO
error or the pose clone as extra states). :class:`EventFilter` drives the same core by one Python call
per event (predict to a time, gated update of any :class:`~imuslam.ins.core.Measurement`, record): the
wheel-odometry filter (:mod:`imuslam.vio.wheel`) runs on it, and ``tests/vio`` builds the VIO's Python
reference filter on it. Both count accepted and rejected updates per measurement kind, keep their NIS
and record the trajectory (:class:`InertialFilter`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry.euler import euler_to_matrix
from imuslam.ins.core import (
    ErrorLayout,
    Eskf,
    InsState,
    KfNoise,
    Measurement,
    chi2_threshold,
    gate,
)
from imuslam.interfaces.imu import ImuLog
from imuslam.io.trajectory import Trajectory
from imuslam.vio import kernels
from imuslam.vio.config import VioConfig

FloatArray = NDArray[np.float64]
U8Image = NDArray[np.uint8]
log_ = logging.getLogger(__name__)


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


@dataclass(slots=True)
class VoFrame:
    """What the filter reads of one VO frame pair: its mid-time ``t_s`` and interval [``t0_s``,
    ``t1_s``] (s since the filter's reference time), the body velocity ``vel_b`` (3,) m/s with its
    covariance ``cov_vel`` (3, 3), the body rate ``omega_b`` (3,) rad/s with ``cov_omega`` (3, 3), and
    their cross-covariance ``cov_wv`` (3, 3) (None: the velocity is applied alone). A frame without a
    velocity and a rate only moves the filter to ``t_s`` and records the state there."""

    t_s: float
    vel_b: FloatArray | None = None
    cov_vel: FloatArray | None = None
    omega_b: FloatArray | None = None
    cov_omega: FloatArray | None = None
    t0_s: float = 0.0
    t1_s: float = 0.0
    cov_wv: FloatArray | None = None


def augmented_covariance(P0: FloatArray, cfg: VioConfig) -> tuple[ErrorLayout, FloatArray]:
    """The error layout and initial covariance of the VIO filter for ``cfg``: the core's 15 states, plus
    the slowly varying VO velocity error (3, at its stationary variance ``vo_error_std^2``) with
    ``vo_model: rate`` and ``vo_error_std`` > 0, or the pose clone (6, zero until the first clone)
    with ``vo_model: relative``."""
    var = np.broadcast_to(np.asarray(cfg.vo_error_std, float) ** 2, (3,))
    extra = (
        3 if cfg.vo_model == "rate" and var.max() > 0 else 6 if cfg.vo_model == "relative" else 0
    )
    if extra == 0:
        return ErrorLayout.full(), P0
    lay = ErrorLayout(True, True, False, extra=extra)
    Pa = np.zeros((lay.dim, lay.dim))
    Pa[: lay.base_dim, : lay.base_dim] = P0
    if extra == 3:
        Pa[lay.base_dim :, lay.base_dim :] = np.diag(var)
    return lay, Pa


class InertialFilter:
    """The core's ESKF over an IMU log, with per-kind gating statistics and a recorded track.

    Times are float seconds since ``t_ref_ns``. IMU samples (SI, body frame) are interpolated linearly at
    the ends of each prediction block, so an update happens exactly at its measurement's time. ``P0``
    may carry extra states after the core's 15 (:func:`augmented_covariance`)."""

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
        base = ErrorLayout.full()
        lay = (
            base
            if len(P0) == base.dim
            else ErrorLayout(True, True, False, extra=len(P0) - base.dim)
        )
        self.kf = Eskf(x0, P=P0, noise=noise, layout=lay)
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
        self.R_b_v = euler_to_matrix(np.deg2rad(cfg.vehicle_rpy_deg))
        self.p_b_v = np.asarray(cfg.vehicle_p_b, float)

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


class EventFilter(InertialFilter):
    """:class:`InertialFilter` driven by one Python call per event: :meth:`advance` (the core's
    prediction to a time), :meth:`update` (the core's gated update of a measurement object that
    linearises itself) and :meth:`mark` (a record)."""

    def advance(self, t: float) -> FloatArray | None:
        """Predict from the current time to ``t`` (no-op when ``t`` is not later); returns the block's
        sample times (None when nothing was predicted)."""
        if t <= self.t:
            return None
        i0, i1 = np.searchsorted(self.t_imu, [self.t, t], side="right")
        a0, g0 = self.sample_at(self.t)
        a1, g1 = self.sample_at(t)
        ts = np.concatenate([[self.t], self.t_imu[i0:i1], [t]])
        keep = np.concatenate([[True], np.diff(ts) > 1e-9])
        acc = np.concatenate([a0[None], self.acc[i0:i1], a1[None]])[keep]
        gyr = np.concatenate([g0[None], self.gyr[i0:i1], g1[None]])[keep]
        ts = ts[keep]
        if len(ts) < 2:
            return None
        Ps, _, Rs = self.kf.predict(acc, gyr, ts)
        self._t.append(ts[1:-1])
        self._p.append(Ps[1:-1])
        self._R.append(Rs[1:-1])
        self.t = t
        return ts

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

    def update(self, meas: Measurement, dof: int) -> tuple[bool, float, FloatArray]:
        """Gated update through the core; returns whether it was accepted, its NIS and the correction
        (zeros when rejected)."""
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
        if res.accepted:
            st.accepted += 1
        else:
            st.rejected += 1
        return res.accepted, nis, res.dx


class VioFilter(InertialFilter):
    """The VIO filter: each VO frame (:class:`VoFrame`) in the compiled frame step of
    :mod:`imuslam.vio.kernels` (:meth:`frames` runs a batch in one call), updating the core filter's
    state arrays in place; records go to growing buffers. Every VO model and option runs here
    (``vo_model`` rate or relative, ``vo_error_std``, ``vo_joint``, ``vo_cov_adapt_n``, the NHC)."""

    _KINDS = (("nhc", 2), ("vo_velocity", 3), ("vo_rate", 3))

    def __init__(
        self, imu: ImuLog, t_ref_ns: int, x0: InsState, P0: FloatArray, t0_s: float, cfg: VioConfig
    ) -> None:
        lay, Pa = augmented_covariance(P0, cfg)
        super().__init__(imu, t_ref_ns, x0, Pa, t0_s, cfg)
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
        # the first record (the initial state)
        self._tr_t[0], self._tr_p[0], self._tr_R[0] = t0_s, x0.p_n, x0.R_n_b
        self._cnt[0] = 1
        gate_on = cfg.gate_prob is not None
        thr2 = chi2_threshold(cfg.gate_prob, 2) if cfg.gate_prob is not None else np.inf
        thr3 = chi2_threshold(cfg.gate_prob, 3) if cfg.gate_prob is not None else np.inf
        self._off = self.kf.layout.offsets
        K = kernels
        mode = {0: K.MODE_RATE, 3: K.MODE_VO_ERROR, 6: K.MODE_RELATIVE}[lay.dim - lay.base_dim]
        std_z = cfg.nhc_std if cfg.nhc_std_vertical is None else cfg.nhc_std_vertical
        var = np.broadcast_to(np.asarray(cfg.vo_error_std, float) ** 2, (3,))
        self._const = np.array(
            [float(cfg.nhc), cfg.nhc_std, 1.0 / cfg.nhc_rate_hz, self.noise.gyro**2,
             float(gate_on), thr2, thr3, std_z, float(cfg.vo_cov_adapt_n), self.adapt_until,
             float(mode), float(lay.base_dim), cfg.vo_error_tau_s, *var],
            dtype=np.float64,
        )  # fmt: skip
        assert len(self._const) == K.C_LEN
        # the extra states' nominal values: the VO error (3,), or the clone's R_c (9,) and p_c (3,)
        self._xe = np.zeros(12)
        if mode == K.MODE_RELATIVE:  # the pose at the start, cloned
            K.clone_pose(self.kf.P, x.R_n_b, x.p_n, self._xe, self._off, lay.base_dim)
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

    @staticmethod
    def pack(f: VoFrame) -> FloatArray:
        """One frame as the kernel's packed row (M_LEN,)."""
        K = kernels
        meas = np.zeros(K.M_LEN)
        meas[K.M_T], meas[K.M_T0], meas[K.M_T1] = f.t_s, f.t0_s, f.t1_s
        if f.vel_b is not None and f.cov_vel is not None:
            meas[K.M_VEL : K.M_VEL + 3] = f.vel_b
            meas[K.M_COV_V : K.M_COV_V + 9] = f.cov_vel.reshape(9)
            meas[K.M_VEL_ON] = 1.0
        if f.omega_b is not None and f.cov_omega is not None:
            meas[K.M_OMEGA : K.M_OMEGA + 3] = f.omega_b
            meas[K.M_COV_W : K.M_COV_W + 9] = f.cov_omega.reshape(9)
            meas[K.M_RATE_ON] = 1.0
            if f.cov_wv is not None:
                meas[K.M_COV_WV : K.M_COV_WV + 9] = f.cov_wv.reshape(9)
                meas[K.M_JOINT] = 1.0
        return meas

    def frames(self, frames: Sequence[VoFrame]) -> NDArray[np.bool_]:
        """The frames, in time order, in one compiled call (:func:`imuslam.vio.kernels.run_frames`).
        Returns per frame whether its velocity update was accepted (True without one)."""
        K = kernels
        cfg = self.cfg
        n = len(frames)
        if n == 0:
            return np.zeros(0, bool)
        meas = np.stack([self.pack(f) for f in frames])
        t_now, t_nhc = float(self._clock[0]), float(self._clock[1])
        t_last = float(max(meas[:, K.M_T].max(), meas[:, K.M_T1].max()))
        n_nhc = (
            int(np.ceil((t_last - t_nhc) * cfg.nhc_rate_hz)) + 2
            if cfg.nhc and t_last > t_nhc
            else 0
        )
        i0, i1 = self.t_imu.searchsorted((t_now, t_last), side="right")
        # per frame at most: its IMU samples, two interpolated block ends per NHC and per advance
        n_track = max(int(i1 - i0), 0) + 2 * n_nhc + 6 * n
        c = self._cnt
        n_events = n_nhc + 2 * n
        if (c[0] + n_track > len(self._tr_t) or c[1] + n_events > len(self._b_t)
                or max(c[2], c[3], c[4]) + n_events > self._nis.shape[1]):  # fmt: skip
            self._reserve(n_track, n_events)
        x = self.kf.x
        vel_ok = np.ones(n, bool)
        bad = K.run_frames(
            self.t_imu, self.acc, self.gyr, x.p_n, x.v_n, x.R_n_b, x.accel_bias, x.gyro_bias, x.g_n,
            self.kf.P, self._clock, self.vo_scale, self._xe, meas, self._const, self.R_b_v,
            self.p_b_v, self.noise.q, self._off, self._tr_t, self._tr_p, self._tr_R, self._b_t,
            self._b, self._b_s, self._nis, self._acc, self._cnt, vel_ok,
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

    def frame(self, f: VoFrame) -> bool:
        """One frame (:meth:`frames`); whether its velocity update was accepted."""
        return bool(self.frames([f])[0])

    def mark(self) -> None:
        """Record the current (posterior) state at the current time."""
        self._reserve(1, 1)
        x = self.kf.x
        kernels.mark_state(self.t, x.p_n, x.R_n_b, x.accel_bias, x.gyro_bias, self.kf.P, self._off,
                           self._tr_t, self._tr_p, self._tr_R, self._b_t, self._b, self._b_s,
                           self._cnt)  # fmt: skip

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
