"""The VIO filter's Python reference: every VO model written as measurement objects that linearise
themselves, applied by one core ``Eskf`` call per event (:class:`imuslam.vio.filter.EventFilter`).

The product runs the same filter in one compiled call per frame (:class:`imuslam.vio.filter.VioFilter`,
:mod:`imuslam.vio.kernels`: sparse covariance products, the standard-form update); this slower form,
written from the equations independently of it, is what ``test_vio_filter.py`` compares it with
(:func:`reference_filter` makes ``run_vio`` use it), and ``bench/vio.py speed`` times it as the anchor.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from unittest import mock

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import exp, hat, log, right_jacobian
from imuslam.ins.core import ErrorLayout, InsState, Measurement
from imuslam.interfaces.imu import ImuLog
from imuslam.vio.config import VioConfig
from imuslam.vio.filter import EventFilter, VoFrame, augmented_covariance
from imuslam.vio.kernels import adapt_scale
from imuslam.vio.measurements import NonHolonomic

FloatArray = NDArray[np.float64]


@dataclass
class VoVelocity:
    """Mean body velocity over a frame interval, m/s, body frame at mid-interval, covariance (3, 3)."""

    vel_b: FloatArray
    cov: FloatArray
    kind: str = "vo_velocity"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        vb = x.R_n_b.T @ x.v_n
        H = np.zeros((3, layout.dim))
        H[:, layout.V] = x.R_n_b.T
        H[:, layout.TH] = hat(vb)
        return self.vel_b - vb, H, self.cov


@dataclass
class VoRate:
    """Mean body rate over a frame interval from VO, rad/s, covariance (3, 3), against the mean raw gyro
    over the same interval ``gyro_mean`` (3,): ``gyro_mean - b_g`` is the true mean rate, so this observes
    the gyro bias. ``gyro_var`` adds the gyro white noise averaged over the interval (density^2 / T)."""

    omega_b: FloatArray
    cov: FloatArray
    gyro_mean: FloatArray
    gyro_var: float
    kind: str = "vo_rate"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        H = np.zeros((3, layout.dim))
        H[:, layout.BG] = -np.eye(3)
        r = self.omega_b - (self.gyro_mean - x.gyro_bias)
        return r, H, self.cov + np.eye(3) * self.gyro_var


@dataclass
class VoVelocityGivenRate:
    """VO body velocity conditioned on the VO rate of the same frame pair (applied after the rate).

    One motion fit gives both, and their errors are strongly correlated (a forward-looking camera
    confuses a turn with a sideways shift: correlation coefficients of 0.9 and more between the rate
    about one axis and the velocity along another, in the fit's covariance and against the truth alike).
    Two independent updates would count that shared error twice. With the joint covariance
    ``[[C_ww, C_wv], [C_vw, C_vv]]`` (``C_ww`` including the averaged gyro noise) and
    ``G = C_vw C_ww^-1``, the transformed measurement ``z_v - G z_w`` has the noise ``n_v - G n_w``,
    independent of the rate's (the block LDL^T decorrelation of a measurement vector before sequential
    processing, as in Grewal and Andrews, *Kalman Filtering: Theory and Practice*, on correlated
    measurement noise): so the rate update followed by this one equals the joint 6-dof update,
    and each keeps its own gate and NIS. Residual ``r_v - G r_w``, Jacobian ``H_v - G H_w``, covariance
    ``C_vv - G C_wv``."""

    vel_b: FloatArray
    cov: FloatArray  # the conditional covariance C_vv - G C_wv (3, 3)
    gain: FloatArray  # G (3, 3)
    omega_b: FloatArray
    gyro_mean: FloatArray
    kind: str = "vo_velocity"

    @classmethod
    def from_joint(
        cls,
        vel_b: FloatArray,
        omega_b: FloatArray,
        gyro_mean: FloatArray,
        cov_ww: FloatArray,
        cov_wv: FloatArray,
        cov_vv: FloatArray,
    ) -> VoVelocityGivenRate:
        """From the joint blocks (``cov_ww`` with the gyro noise already added)."""
        G = np.asarray(np.linalg.solve(cov_ww, cov_wv).T, dtype=np.float64)  # C_vw C_ww^-1
        cov = cov_vv - G @ cov_wv
        return cls(vel_b, 0.5 * (cov + cov.T), G, omega_b, gyro_mean)

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        r_v, H_v, _ = VoVelocity(self.vel_b, self.cov).linearize(x, layout)
        r_w = self.omega_b - (self.gyro_mean - x.gyro_bias)
        H = H_v.copy()
        H[:, layout.BG] += self.gain  # - G H_w with H_w = -I on the gyro bias
        return r_v - self.gain @ r_w, H, self.cov


@dataclass
class WithVoError:
    """A VO velocity measurement (:class:`VoVelocity` or :class:`VoVelocityGivenRate`) whose error has,
    besides its white part, a slowly varying part ``e`` (3,) m/s, body frame, kept in the error state at
    index ``offset`` (a first-order Gauss-Markov process, propagated by its owner): the residual is
    taken against ``v_b + e`` and the Jacobian gains the identity on ``e``.

    The rendered VO's velocity errors are correlated over about three frame pairs (autocorrelation
    0.05-0.15 at lags of 1-3 pairs, near zero from 5; features tracked through several frames are one
    candidate cause, not measured), which white noise does not describe (Bar-Shalom, Li and Kirubarajan,
    *Estimation with Applications to Tracking and Navigation*, 2001, sec. 8.2: state augmentation for
    autocorrelated measurement noise)."""

    inner: VoVelocity | VoVelocityGivenRate
    error: FloatArray
    offset: int
    kind: str = "vo_velocity"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        r, H, R = self.inner.linearize(x, layout)
        H = H.copy()
        o = self.offset
        H[:, o : o + 3] += np.eye(3)
        return r - self.error, H, R


@dataclass
class VoClone:
    """The pose at a frame pair's start kept in the error state (stochastic cloning: Roumeliotis and
    Burdick, "Stochastic cloning: a generalized framework for processing relative state measurements",
    ICRA 2002): nominal ``R_n_b`` (3, 3) and ``p_n`` (3,), its error ``[dtheta_c, dp_c]`` at index
    ``offset`` of the error state (attitude right-perturbed, position additive, as the core's)."""

    R_n_b: FloatArray
    p_n: FloatArray
    offset: int

    @property
    def TH(self) -> slice:
        return slice(self.offset, self.offset + 3)

    @property
    def P(self) -> slice:
        return slice(self.offset + 3, self.offset + 6)


def _relative_rotation(
    omega_b: FloatArray, dt: float, clone: VoClone, x: InsState, layout: ErrorLayout
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Residual (3,) in rate units, Jacobian (3, dim) and the right Jacobian of the measured rotation
    ``z = omega_b dt`` (its noise ``e`` enters as ``Exp(z + dz) ~ Exp(z) Exp(J_r(z) dz)``)."""
    dR = clone.R_n_b.T @ x.R_n_b
    z = omega_b * dt
    r = log(dR.T @ exp(z)) / dt
    H = np.zeros((3, layout.dim))
    H[:, layout.TH] = np.eye(3) / dt
    H[:, clone.TH] = -dR.T / dt
    return r, H, right_jacobian(z)


@dataclass
class VoRelativeRotation:
    """The rotation between a frame pair's two frames from VO (``omega_b`` rad/s, the mean body rate
    over ``dt`` s, covariance (3, 3)) against the filter's attitude change since the clone taken at the
    pair's start. With the right perturbation ``R = R_hat Exp(dtheta)``,
    ``R_c^T R ~ dR_hat Exp(dtheta - dR_hat^T dtheta_c)``, so the residual ``Log(dR_hat^T Exp(omega_b dt))``
    has ``H_theta = I`` and ``H_theta_c = -dR_hat^T`` (divided by ``dt``: rate units). Unlike
    :class:`VoRate` it corrects the attitude itself, not only the gyro bias: the gyro's white noise over
    the interval is process noise of the attitude here, not measurement noise."""

    omega_b: FloatArray
    cov: FloatArray
    dt: float
    clone: VoClone
    kind: str = "vo_rate"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        r, H, Jr = _relative_rotation(self.omega_b, self.dt, self.clone, x, layout)
        return r, H, Jr @ self.cov @ Jr.T


def _relative_translation(
    vel_b: FloatArray,
    omega_b: FloatArray,
    dt: float,
    clone: VoClone,
    x: InsState,
    layout: ErrorLayout,
) -> tuple[FloatArray, FloatArray]:
    """VO's mean velocity over the pair, in the body frame at mid-interval: ``Exp(-z / 2) R_c^T (p - p_c)
    / dt`` with the measured rotation ``z = omega_b dt``. Residual (3,) and Jacobian (3, dim):
    ``H_p = A / dt``, ``H_p_c = -A / dt``, ``H_theta_c = Exp(-z / 2) [R_c^T (p - p_c)]x / dt``
    (``A = Exp(-z / 2) R_c^T``; ``Exp(-dtheta_c) R_c^T d ~ R_c^T d + [R_c^T d]x dtheta_c``)."""
    d = x.p_n - clone.p_n
    half = exp(-0.5 * omega_b * dt)
    A = half @ clone.R_n_b.T
    H = np.zeros((3, layout.dim))
    H[:, layout.P] = A / dt
    H[:, clone.P] = -A / dt
    H[:, clone.TH] = half @ hat(clone.R_n_b.T @ d) / dt
    return vel_b - A @ d / dt, H


@dataclass
class VoRelativeTranslation:
    """VO's mean body velocity over a frame pair (m/s, body frame at mid-interval, covariance (3, 3)) as
    the translation since the clone at the pair's start (:func:`_relative_translation`), alone."""

    vel_b: FloatArray
    cov: FloatArray
    omega_b: FloatArray
    dt: float
    clone: VoClone
    kind: str = "vo_velocity"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        r, H = _relative_translation(self.vel_b, self.omega_b, self.dt, self.clone, x, layout)
        return r, H, self.cov


@dataclass
class VoRelativeTranslationGivenRotation:
    """:class:`VoRelativeTranslation` conditioned on the :class:`VoRelativeRotation` of the same pair
    (applied after it), as :class:`VoVelocityGivenRate` does for the rate form: with the joint noise of
    ``[J_r e_w, e_v]`` and ``G = C_vw J_r^T (J_r C_ww J_r^T)^-1``, residual ``r_v - G r_w``, Jacobian
    ``H_v - G H_w``, covariance ``C_vv - G J_r C_wv``; both residuals at the current state."""

    vel_b: FloatArray
    omega_b: FloatArray
    cov_ww: FloatArray
    cov_wv: FloatArray
    cov_vv: FloatArray
    dt: float
    clone: VoClone
    kind: str = "vo_velocity"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        r_w, H_w, Jr = _relative_rotation(self.omega_b, self.dt, self.clone, x, layout)
        r_v, H_v = _relative_translation(self.vel_b, self.omega_b, self.dt, self.clone, x, layout)
        c_wv = Jr @ self.cov_wv
        G = np.linalg.solve(Jr @ self.cov_ww @ Jr.T, c_wv).T
        cov = self.cov_vv - G @ c_wv
        return r_v - G @ r_w, H_v - G @ H_w, 0.5 * (cov + cov.T)


# the row of vo_scale that a measurement kind's NIS adapts
_ADAPT_ROW = {"vo_rate": 0, "vo_velocity": 1}


class ReferenceVioFilter(EventFilter):
    """:class:`imuslam.vio.filter.VioFilter`'s frames, one Python call per event."""

    def __init__(
        self, imu: ImuLog, t_ref_ns: int, x0: InsState, P0: FloatArray, t0_s: float, cfg: VioConfig
    ) -> None:
        lay, Pa = augmented_covariance(P0, cfg)
        super().__init__(imu, t_ref_ns, x0, Pa, t0_s, cfg)
        extra = lay.dim - lay.base_dim
        self.clone: VoClone | None = None
        self.vo_error: FloatArray | None = np.zeros(3) if extra == 3 else None
        self.vo_error_var = np.broadcast_to(np.asarray(cfg.vo_error_std, float) ** 2, (3,)).copy()
        if extra == 6:
            self._clone()

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

    def advance(self, t: float) -> FloatArray | None:
        ts = super().advance(t)
        if ts is not None and self.vo_error is not None:
            # the Gauss-Markov error's own transition (the core's is identity)
            o = self.kf.layout.base_dim
            phi = float(np.exp(-(ts[-1] - ts[0]) / self.cfg.vo_error_tau_s))
            P = self.kf.P
            P[o:, :] *= phi
            P[:, o:] *= phi
            P[o:, o:] += np.diag(self.vo_error_var) * (1.0 - phi**2)
            self.vo_error = self.vo_error * phi
        return ts

    def update(self, meas: Measurement, dof: int) -> tuple[bool, float, FloatArray]:
        if self.vo_error is not None and isinstance(meas, VoVelocity | VoVelocityGivenRate):
            meas = WithVoError(meas, self.vo_error, self.kf.layout.base_dim)
        ok, nis, dx = super().update(meas, dof)
        if ok and self.vo_error is not None:  # the VO error's share of the correction
            o = self.kf.layout.base_dim
            self.vo_error = self.vo_error + dx[o : o + 3]
        if ok and self.clone is not None:  # the clone's share of the correction
            c = self.clone
            c.R_n_b = c.R_n_b @ exp(dx[c.TH])
            c.p_n = c.p_n + dx[c.P]
        row = _ADAPT_ROW.get(meas.kind)
        if ok and self.cfg.vo_cov_adapt_n and row is not None and self.t < self.adapt_until:
            self.vo_scale[row] = adapt_scale(self.vo_scale[row], nis, 3.0, self.cfg.vo_cov_adapt_n)
        return ok, nis, dx

    def frames(self, frames: Sequence[VoFrame]) -> NDArray[np.bool_]:
        return np.array([self.frame(f) for f in frames], bool)

    def frame(self, f: VoFrame) -> bool:
        """Everything up to one VO frame; whether its velocity update was accepted (True without
        one)."""
        cov_omega, cov_vel, cov_wv = f.cov_omega, f.cov_vel, f.cov_wv
        if self.cfg.vo_cov_adapt_n:  # the online scales in force now
            s_w, s_v = self.vo_scale
            cov_omega = None if cov_omega is None else cov_omega * s_w
            cov_vel = None if cov_vel is None else cov_vel * s_v
            cov_wv = None if cov_wv is None else cov_wv * np.sqrt(s_w * s_v)
        vel_b, omega_b = f.vel_b, f.omega_b
        if self.clone is not None:
            return self._frame_relative(f, vel_b, cov_vel, omega_b, cov_omega, cov_wv)
        self._nhc_until(f.t_s)
        self.advance(f.t_s)
        ok_v = ok_w = True
        rate = None
        if omega_b is not None and cov_omega is not None:
            g_mean = self.gyro_mean(f.t0_s, f.t1_s)
            gv = self.noise.gyro**2 / (f.t1_s - f.t0_s)
            rate = VoRate(omega_b, cov_omega, g_mean, gv)
            ok_w = self.update(rate, 3)[0]
        if vel_b is not None and cov_vel is not None:
            if rate is not None and ok_w and cov_wv is not None:
                ok_v = self.update(
                    VoVelocityGivenRate.from_joint(
                        vel_b, rate.omega_b, rate.gyro_mean, rate.cov + np.eye(3) * rate.gyro_var,
                        cov_wv, cov_vel,
                    ), 3,
                )[0]  # fmt: skip
            else:
                ok_v = self.update(VoVelocity(vel_b, cov_vel), 3)[0]
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
        f: VoFrame,
        vel_b: FloatArray | None,
        cov_vel: FloatArray | None,
        omega_b: FloatArray | None,
        cov_omega: FloatArray | None,
        cov_wv: FloatArray | None,
    ) -> bool:
        """``vo_model: relative``: to the pair's start (clone there), to its end, then the VO rotation
        and translation against the clone. A pair that starts before the filter's current time only
        moves the filter to its end. Without a measurement: to the mid-time."""
        if omega_b is None and vel_b is None:
            self._nhc_until(f.t_s)
            self.advance(f.t_s)
            self.mark()
            return True
        usable = self.t <= f.t0_s + 1e-9
        if usable:
            self._nhc_until(f.t0_s)
            self.advance(f.t0_s)
            self._clone()
        self._nhc_until(f.t1_s)
        self.advance(f.t1_s)
        ok_v = ok_w = True
        if usable:
            assert self.clone is not None
            dt = f.t1_s - f.t0_s
            w = omega_b if omega_b is not None else np.zeros(3)
            if omega_b is not None and cov_omega is not None:
                ok_w = self.update(VoRelativeRotation(omega_b, cov_omega, dt, self.clone), 3)[0]
            if vel_b is not None and cov_vel is not None:
                if omega_b is not None and cov_omega is not None and ok_w and cov_wv is not None:
                    meas: Measurement = VoRelativeTranslationGivenRotation(
                        vel_b, omega_b, cov_omega, cov_wv, cov_vel, dt, self.clone
                    )
                else:
                    meas = VoRelativeTranslation(vel_b, cov_vel, w, dt, self.clone)
                ok_v = self.update(meas, 3)[0]
        self.mark()
        return ok_v


@contextmanager
def reference_filter() -> Iterator[None]:
    """Within it, ``run_vio`` runs :class:`ReferenceVioFilter` in place of the product's filter."""
    with mock.patch("imuslam.vio.pipeline.VioFilter", ReferenceVioFilter):
        yield
