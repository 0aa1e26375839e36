"""The stereo VO + IMU filter for a ground robot (the fusion method of source 004, see the references).

:class:`VioFilter` wraps the shared inertial core's :class:`~imuslam.ins.core.Eskf` (error state
``[dtheta, dp, dv, db_a, db_g]``): it propagates with the core's kernel to any time (IMU samples
interpolated at block ends), applies the measurements of :mod:`imuslam.vio.measurements` through the
core's gated ``update`` (chi-square test per measurement kind, ``gate_prob``), counts accepted and rejected
updates and keeps their NIS, and records the trajectory. :class:`CompiledVioFilter` runs the same
measurement sequence in one compiled kernel per frame (``vio.kernels``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import exp
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
from imuslam.vio.config import VioConfig
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
)

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
        self.R_b_v = euler_to_matrix(np.deg2rad(cfg.vehicle_rpy_deg))
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
