"""The wheel-odometry filter's measurements (:mod:`imuslam.vio.wheel`), each linearising itself for the
shared inertial core (:class:`imuslam.ins.core.Measurement`): the non-holonomic constraint, the wheels'
forward speed and yaw rate; and :func:`twist_velocity`, how the VIO reads a VO pair's mean velocity.
(The VIO filter's own measurement models are compiled, in :mod:`imuslam.vio.kernels`.)

The error state is the core's ``[dtheta, dp, dv, db_a, db_g]`` with the right perturbation
``R_true = R exp(dtheta)``, so a body velocity ``R^T v = exp(-dtheta)^ R_hat^T v ~ R_hat^T v +
[R_hat^T v]x dtheta`` has ``H_v = R^T`` and ``H_theta = [R^T v]x`` (seed 004 writes the VO velocity
measurement as ``v^b = C_n^b v^n``). The vehicle frame ``v`` (x forward, y left, z up) is given in the
body by ``R_b_v`` and its origin (the point that does not slide, e.g. the rear axle's centre) by
``p_b_v``; its velocity is ``v_v = R_b_v^T (R^T v_n + omega_b x p_b_v)``, with ``omega_b`` the
bias-corrected gyro rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.ins.core import ErrorLayout, InsState
from imuslam.vio.kernels import vehicle_velocity

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


def _vehicle_velocity(
    x: InsState, layout: ErrorLayout, gyro: FloatArray, R_b_v: FloatArray, p_b_v: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Vehicle-frame velocity (3,) and its Jacobian (3, dim) (:func:`imuslam.vio.kernels.vehicle_velocity`,
    the VIO's constraint)."""
    f64 = np.float64
    vv, Hc = vehicle_velocity(
        np.ascontiguousarray(x.R_n_b, f64), np.ascontiguousarray(x.v_n, f64),
        np.ascontiguousarray(gyro - x.gyro_bias, f64), np.ascontiguousarray(R_b_v, f64),
        np.ascontiguousarray(p_b_v, f64),
    )  # fmt: skip
    H = np.zeros((3, layout.dim))
    H[:, layout.TH] = Hc[:, 0:3]
    H[:, layout.V] = Hc[:, 3:6]
    H[:, layout.BG] = Hc[:, 6:9]
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
