"""The VIO filter's measurements, each linearising itself for the shared inertial core
(:class:`imuslam.ins.core.Measurement`): VO body velocity (alone, or conditioned on the VO rate of the
same frame pair), VO body rate, the non-holonomic constraint and a wheel speed.

The error state is the core's ``[dtheta, dp, dv, db_a, db_g]`` with the right perturbation
``R_true = R exp(dtheta)``. Seed 004 writes the velocity measurement as ``v^b = C_n^b v^n``; with the right
perturbation ``R^T v = exp(-dtheta)^ R_hat^T v ~ R_hat^T v + [R_hat^T v]x dtheta``, so
``H_v = R^T`` and ``H_theta = [R^T v]x``. The vehicle frame ``v`` (x forward, y left, z up) is given in the
body by ``R_b_v`` and its origin (the point that does not slide, e.g. the rear axle's centre) by
``p_b_v``; its velocity is ``v_v = R_b_v^T (R^T v_n + omega_b x p_b_v)``, with ``omega_b`` the
bias-corrected gyro rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import exp, hat, log, right_jacobian
from imuslam.ins.core import ErrorLayout, InsState

FloatArray = NDArray[np.float64]


def twist_velocity(
    omega_b: FloatArray, vel_mean_b: FloatArray, cov: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:
    """The body velocity of a frame pair under a constant twist, from the VO's mean velocity.

    The front end reports the pair's displacement seen from mid-interval over its duration,
    ``v_mean = exp(-phi/2) p_01 / dt`` with ``phi = omega_b dt``: the chord of the path, shorter than
    the arc. A body moving with constant rate and constant body velocity ``v_b`` travels
    ``p_01 = dt J_l(phi) v_b`` (``J_l`` the left Jacobian of SO(3), the mean of ``exp(s phi)`` over s in
    [0, 1]; Sola et al. 2018, "A micro Lie theory", eq. 145). ``J_l(phi) = exp(phi/2) S`` with ``S`` the
    mean of ``exp(u phi)`` over u in [-1/2, 1/2], which by Rodrigues' formula is ``I + a [phi]x^2``,
    ``1 - a theta^2 = sinc(theta/2)``: so ``v_mean = S v_b``, and ``v_b`` keeps the component of
    ``v_mean`` along the rotation axis and divides the one across it by ``sinc(theta/2)``. The chord
    is short by about ``|v| (|omega| dt)^2 / 24`` in a turn, a steady shortfall of speed that would
    integrate into an along-track lag.

    ``cov`` (6, 6) is that of ``[omega_b, vel_mean_b]``; returns ``v_b`` (3,) and the (6, 6) covariance
    of ``[omega_b, v_b]`` through the map's Jacobian (analytic)."""
    v_b, cov_b = _twist_velocity_nb(
        np.ascontiguousarray(omega_b, dtype=np.float64),
        np.ascontiguousarray(vel_mean_b, dtype=np.float64),
        np.ascontiguousarray(cov, dtype=np.float64),
        float(dt),
    )
    return v_b, cov_b


@numba.njit(cache=True)
def _twist_velocity_nb(
    w: FloatArray, v: FloatArray, cov: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    phi = w * dt
    th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    th = np.sqrt(th2)
    # v_b = (1 + c) v - d phi (phi . v), c = 1 / sinc(theta/2) - 1, d = c / theta^2
    if th < 1e-2:  # series (the closed forms lose digits as theta -> 0)
        c = th2 / 24.0 + 7.0 * th2 * th2 / 5760.0
        dc_th = 1.0 / 12.0 + 7.0 * th2 / 1440.0  # c'(theta) / theta
        d = 1.0 / 24.0 + 7.0 * th2 / 5760.0
        dd_th = 7.0 / 2880.0  # d'(theta) / theta
    else:
        h = 0.5 * th
        sh = np.sin(h)
        c = h / sh - 1.0
        dc = 0.5 * (sh - h * np.cos(h)) / (sh * sh)
        dc_th = dc / th
        d = c / th2
        dd_th = (dc / th2 - 2.0 * c / (th2 * th)) / th
    pv = phi[0] * v[0] + phi[1] * v[1] + phi[2] * v[2]
    v_b = (1.0 + c) * v - d * pv * phi
    J = np.eye(6)
    for r in range(3):
        for k in range(3):
            J[3 + r, 3 + k] = (1.0 + c) * (r == k) - d * phi[r] * phi[k]
            # d v_b / d phi, times dt for omega
            J[3 + r, k] = dt * (
                dc_th * v[r] * phi[k]
                - d * (pv * (r == k) + phi[r] * v[k])
                - dd_th * pv * phi[r] * phi[k]
            )
    out = J @ cov @ J.T
    return v_b, 0.5 * (out + out.T)


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


def _vehicle_velocity(
    x: InsState, layout: ErrorLayout, gyro: FloatArray, R_b_v: FloatArray, p_b_v: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Vehicle-frame velocity (3,) and its Jacobian (3, dim)."""
    vb = x.R_n_b.T @ x.v_n
    w = gyro - x.gyro_bias
    vv = R_b_v.T @ (vb + np.cross(w, p_b_v))
    H = np.zeros((3, layout.dim))
    H[:, layout.V] = R_b_v.T @ x.R_n_b.T
    H[:, layout.TH] = R_b_v.T @ hat(vb)
    H[:, layout.BG] = R_b_v.T @ hat(p_b_v)  # d(w x p)/d(b_g) = -d(p x w)... = [p]x
    return vv, H


@dataclass
class NonHolonomic:
    """The vehicle neither slides nor jumps: lateral and vertical vehicle-frame velocity are zero with
    1-sigma ``std`` m/s (seed 004), the vertical with ``std_vertical`` when given (the body pitches on
    uneven ground while the path stays level). ``gyro`` (3,) is the raw rate at the time (for the
    lever arm)."""

    std: float
    gyro: FloatArray = field(default_factory=lambda: np.zeros(3))
    R_b_v: FloatArray = field(default_factory=lambda: np.eye(3))
    p_b_v: FloatArray = field(default_factory=lambda: np.zeros(3))
    std_vertical: float | None = None
    kind: str = "nhc"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        vv, H = _vehicle_velocity(x, layout, self.gyro, self.R_b_v, self.p_b_v)
        sz = self.std if self.std_vertical is None else self.std_vertical
        return -vv[1:], H[1:], np.diag([self.std**2, sz**2])


@dataclass
class WheelSpeed:
    """Forward speed of the vehicle frame from wheel odometry, m/s, 1-sigma ``std``."""

    speed: float
    std: float
    gyro: FloatArray = field(default_factory=lambda: np.zeros(3))
    R_b_v: FloatArray = field(default_factory=lambda: np.eye(3))
    p_b_v: FloatArray = field(default_factory=lambda: np.zeros(3))
    kind: str = "wheel"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        vv, H = _vehicle_velocity(x, layout, self.gyro, self.R_b_v, self.p_b_v)
        return np.array([self.speed - vv[0]]), H[:1], np.array([[self.std**2]])


@dataclass
class WheelYawRate:
    """Yaw rate of the vehicle from wheel odometry, rad/s, 1-sigma ``std``, against the mean raw gyro
    (3,) over the same interval: the vehicle-z component of ``gyro_mean - b_g`` (observes the gyro
    bias about the vehicle's vertical, as VO's rate does about every axis)."""

    yaw_rate: float
    std: float
    gyro_mean: FloatArray
    R_b_v: FloatArray = field(default_factory=lambda: np.eye(3))
    kind: str = "wheel_yaw_rate"

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        ez = self.R_b_v[:, 2]  # vehicle z in the body
        H = np.zeros((1, layout.dim))
        H[0, layout.BG] = -ez
        r = self.yaw_rate - ez @ (self.gyro_mean - x.gyro_bias)
        return np.array([r]), H, np.array([[self.std**2]])


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
