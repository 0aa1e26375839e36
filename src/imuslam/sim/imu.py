"""A simulated IMU on a trajectory: the error model, noise, bias random walk, slow drift, quantisation,
saturation, time-stamp jitter, and optionally a platform rotating about a body axis (seed 001).

True specific force in the IMU frame (at the body origin): ``f_i = R_i_b R_b_w (a_w - g_w)`` with
``g_w = [0, 0, -g]`` (ENU, REP-103), and ``omega_i = R_i_b omega_b + omega_platform``. The raw output is
the inverse of the correction ``x_O = T K(t) (x_S + b(t))`` (``sim/imu_errors.py``) plus noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import exp
from imuslam.interfaces.imu import ImuLog
from imuslam.sim.imu_errors import (
    BWT901CL_ACCEL_DENSITY,
    BWT901CL_GYRO_DENSITY,
    SEED000_ACCEL,
    SEED000_GYRO,
    TriadErrors,
)
from imuslam.sim.trajectory import TrajectoryModel

FloatArray = NDArray[np.float64]
IDEAL = TriadErrors(np.eye(3), np.ones(3), np.zeros(3))


@dataclass
class ImuErrorSpec:
    """Everything that makes a simulated IMU imperfect. Densities are per sqrt(Hz); drifts per hour.

    accel_bias_rw / gyro_bias_rw: bias random walk, m/s^3/sqrt(Hz) and rad/s^2/sqrt(Hz).
    bias_drift_per_h: (2, 3) deterministic bias change per hour [accel m/s^2, gyro rad/s] (working time /
    temperature, seed 000). scale_drift_per_h: relative scale change per hour of both triads.
    """

    accel: TriadErrors = field(default_factory=lambda: IDEAL)
    gyro: TriadErrors = field(default_factory=lambda: IDEAL)
    accel_density: float = 0.0
    gyro_density: float = 0.0
    accel_bias_rw: float = 0.0
    gyro_bias_rw: float = 0.0
    bias_drift_per_h: FloatArray = field(default_factory=lambda: np.zeros((2, 3)))
    scale_drift_per_h: float = 0.0
    accel_quant: float | None = None
    gyro_quant: float | None = None
    accel_range: float | None = None
    gyro_range: float | None = None
    stamp_jitter_std_s: float = 0.0

    @classmethod
    def ideal(cls) -> ImuErrorSpec:
        return cls()

    @classmethod
    def bwt901cl(cls) -> ImuErrorSpec:
        """Seed 000's table-2 errors with MPU-9250-class noise and bias instability of a consumer MEMS."""
        return cls(
            SEED000_ACCEL, SEED000_GYRO, BWT901CL_ACCEL_DENSITY, BWT901CL_GYRO_DENSITY,
            accel_bias_rw=1e-4, gyro_bias_rw=2e-5,
        )  # fmt: skip


@dataclass
class ImuTruth:
    """Truth at each sample: t_s (N,) true sampling times; accel_i, omega_i (N, 3) true values; accel_bias,
    gyro_bias (N, 3) raw-unit biases; R_w_i (N, 3, 3); R_b_i (N, 3, 3) platform rotation."""

    t_s: FloatArray
    accel_i: FloatArray
    omega_i: FloatArray
    accel_bias: FloatArray
    gyro_bias: FloatArray
    R_w_i: FloatArray
    R_b_i: FloatArray
    p_w: FloatArray
    vel_w: FloatArray


def simulate_imu(
    traj: TrajectoryModel,
    duration_s: float,
    rng: np.random.Generator,
    errors: ImuErrorSpec | None = None,
    rate_hz: float = 100.0,
    g: float = 9.80665,
    t0_s: float = 0.0,
    R_b_i: FloatArray | None = None,
    rotating_platform_hz: float = 0.0,
    rotation_axis_b: tuple[float, float, float] = (0.0, 0.0, 1.0),
    t0_ns: int = 0,
) -> tuple[ImuLog, ImuTruth]:
    """Raw IMU samples (m/s^2, rad/s) along ``traj`` for ``duration_s`` and their truth.

    R_b_i: fixed mounting of the IMU in the body (identity by default); with ``rotating_platform_hz``, the
    IMU turns about ``rotation_axis_b`` at that rate on top of the mounting.
    """
    e = errors or ImuErrorSpec()
    n = int(np.floor(duration_s * rate_hz)) + 1
    t = t0_s + np.arange(n) / rate_hz
    st = traj.state(t)
    mount = np.eye(3) if R_b_i is None else np.asarray(R_b_i, float)
    axis = np.asarray(rotation_axis_b, float)
    axis /= np.linalg.norm(axis)
    if rotating_platform_hz:
        w_p = 2 * np.pi * rotating_platform_hz
        R_b_i_t = exp(axis[None] * (w_p * (t - t0_s))[:, None]) @ mount
        omega_plat_b = axis * w_p
    else:
        R_b_i_t = np.broadcast_to(mount, (n, 3, 3)).copy()
        omega_plat_b = np.zeros(3)
    R_i_b = np.swapaxes(R_b_i_t, 1, 2)
    f_b = np.einsum("nji,nj->ni", st.R_w_b, st.acc_w + np.array([0.0, 0.0, g]))
    accel_i = np.einsum("nij,nj->ni", R_i_b, f_b)
    omega_i = np.einsum("nij,nj->ni", R_i_b, st.omega_b + omega_plat_b)
    hours = (t - t0_s) / 3600.0
    dt = 1.0 / rate_hz

    def bias(b0: FloatArray, rw: float, drift: FloatArray) -> FloatArray:
        walk = np.cumsum(rng.normal(size=(n, 3)) * rw * np.sqrt(dt), axis=0) if rw > 0 else 0.0
        return b0[None] + walk + hours[:, None] * drift[None]

    b_a = bias(e.accel.b, e.accel_bias_rw, e.bias_drift_per_h[0])
    b_g = bias(e.gyro.b, e.gyro_bias_rw, e.bias_drift_per_h[1])
    scale = 1.0 + e.scale_drift_per_h * hours[:, None]

    def raw(
        true: FloatArray,
        tri: TriadErrors,
        b: FloatArray,
        density: float,
        q: float | None,
        rng_: float | None,
    ) -> FloatArray:
        x = np.linalg.solve(tri.T, true.T).T / (tri.K[None] * scale)
        x = x - b if tri.bias_sign == "plus" else x + b
        if density > 0:
            x = x + rng.normal(size=x.shape) * density * np.sqrt(rate_hz)
        if rng_ is not None:
            x = np.clip(x, -rng_, rng_)
        if q:
            x = np.round(x / q) * q
        return x

    acc_raw = raw(accel_i, e.accel, b_a, e.accel_density, e.accel_quant, e.accel_range)
    gyr_raw = raw(omega_i, e.gyro, b_g, e.gyro_density, e.gyro_quant, e.gyro_range)
    stamps = t + (rng.normal(size=n) * e.stamp_jitter_std_s if e.stamp_jitter_std_s > 0 else 0.0)
    stamps = np.maximum.accumulate(stamps)
    t_ns = t0_ns + np.round(stamps * 1e9).astype(np.int64)
    t_ns = np.maximum(t_ns, t_ns[0] + np.arange(n))  # strictly increasing even with jitter
    log = ImuLog(t_ns, acc_raw, gyr_raw, "m/s^2", "rad/s", "simulated IMU")
    truth = ImuTruth(t, accel_i, omega_i, b_a, b_g, st.R_w_b @ R_b_i_t, R_b_i_t, st.p_w, st.vel_w)
    return log, truth
