"""A simulated 2-axis gimbal turning an IMU through static poses: the log of a multi-position calibration.

Gimbal kinematics: the outer joint turns about the world x axis (roll), the inner joint about the
rotated y axis (pitch), so ``R_w_i = Rx(roll) Ry(pitch)`` and the body rate is
``omega_i = Ry(pitch)^T [roll_rate, 0, 0] + [0, pitch_rate, 0]``. The specific force at rest is
``f_i = R_i_w [0, 0, g]`` (ENU, z up). Every reachable "up" direction in the IMU frame,
``u = [-sin(p) cos(r), sin(r), cos(p) cos(r)]``, is reached with roll in [-90, 90] deg and pitch in
[-180, 180] deg (a 360 deg serial-bus servo of 4096 steps per turn: 0.088 deg, as in seed 000).
Joints move with a minimum-jerk profile (Flash & Hogan 1985), so rates are smooth and exact.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import quat_to_matrix
from imuslam.interfaces.gimbal import GIMBAL_RESOLUTION_DEG, PITCH_LIMITS_DEG, ROLL_LIMITS_DEG
from imuslam.interfaces.imu import ImuLog
from imuslam.sim.imu_errors import (
    BWT901CL_ACCEL_DENSITY,
    BWT901CL_GYRO_DENSITY,
    SEED000_ACCEL,
    SEED000_GYRO,
    TriadErrors,
    add_sensor_noise,
    raw_from_errors,
)

FloatArray = NDArray[np.float64]


def up_to_gimbal_deg(up_i: FloatArray) -> FloatArray:
    """Gimbal angles (N, 2) [roll, pitch] in deg that put the unit 'up' direction ``up_i`` (N, 3) in z."""
    u = np.asarray(up_i, dtype=float)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    roll = np.arcsin(np.clip(u[..., 1], -1.0, 1.0))
    pitch = np.arctan2(-u[..., 0], u[..., 2])
    return np.rad2deg(np.stack([roll, pitch], axis=-1))


def gimbal_up_i(angles_deg: FloatArray) -> FloatArray:
    """The 'up' unit vector in the IMU frame (N, 3) for gimbal angles (N, 2) [roll, pitch] in deg."""
    a = np.deg2rad(np.asarray(angles_deg, dtype=float))
    r, p = a[..., 0], a[..., 1]
    return np.stack([-np.sin(p) * np.cos(r), np.sin(r), np.cos(p) * np.cos(r)], axis=-1)


def sphere_plan_deg(n_poses: int, rng: np.random.Generator | None = None) -> FloatArray:
    """A standard plan: ``n_poses`` up-directions spread over the sphere (Fibonacci lattice), as gimbal angles.

    With ``rng`` the lattice is randomly rotated (a different but equally spread plan per run).
    """
    k = np.arange(n_poses) + 0.5
    z = 1.0 - 2.0 * k / n_poses
    phi = np.pi * (1.0 + 5.0**0.5) * k
    rho = np.sqrt(1.0 - z**2)
    up = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=-1)
    if rng is not None:
        q = rng.normal(size=4)
        up = up @ quat_to_matrix(q / np.linalg.norm(q)).T
    return up_to_gimbal_deg(up)


def gimbal_kinematics(
    angles_deg: FloatArray, rates_dps: FloatArray, g: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """R_w_i (N, 3, 3), specific force f_i (N, 3) and body rate omega_i (N, 3) of the gimbal's IMU from
    joint angles and rates (N, 2) [roll, pitch] in deg and deg/s; the IMU sits on the rotation centre."""
    n = angles_deg.shape[0]
    r, p = np.deg2rad(angles_deg[:, 0]), np.deg2rad(angles_deg[:, 1])
    dr, dp = np.deg2rad(rates_dps[:, 0]), np.deg2rad(rates_dps[:, 1])
    cr, sr, cp, sp = np.cos(r), np.sin(r), np.cos(p), np.sin(p)
    Rx = np.zeros((n, 3, 3))
    Rx[:, 0, 0] = 1.0
    Rx[:, 1, 1], Rx[:, 1, 2], Rx[:, 2, 1], Rx[:, 2, 2] = cr, -sr, sr, cr
    Ry = np.zeros((n, 3, 3))
    Ry[:, 1, 1] = 1.0
    Ry[:, 0, 0], Ry[:, 0, 2], Ry[:, 2, 0], Ry[:, 2, 2] = cp, sp, -sp, cp
    accel_i = g * np.stack([-sp * cr, sr, cp * cr], axis=-1)
    omega_i = np.stack([cp * dr, dp, sp * dr], axis=-1)  # Ry^T [dr, 0, 0] + [0, dp, 0]
    return Rx @ Ry, accel_i, omega_i


def min_jerk(tau: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Minimum-jerk position s(tau) and ds/dtau on tau in [0, 1] (Flash & Hogan 1985)."""
    t = np.clip(tau, 0.0, 1.0)
    return 10 * t**3 - 15 * t**4 + 6 * t**5, 30 * t**2 - 60 * t**3 + 30 * t**4


def move_duration_s(delta_deg: FloatArray, joint_speed_dps: float, min_move_s: float) -> float:
    """Duration of a min-jerk move whose peak joint rate (1.875x the mean) stays within the speed."""
    return max(float(np.max(np.abs(delta_deg))) / joint_speed_dps * 1.875, min_move_s)


class GimbalImuStream:
    """A closed-loop simulated IMU on the gimbal: ``command`` a pose, ``read`` the next samples.

    errors_at: function of time (s) giving the (accel, gyro) error parameters then, so that errors can
    drift with working time (seed 000); BWT901CL-class white noise.
    """

    def __init__(
        self,
        rng: np.random.Generator,
        errors_at: Callable[[float], tuple[TriadErrors, TriadErrors]] | None = None,
        rate_hz: float = 100.0,
        g: float = 9.80665,
        joint_speed_dps: float = 90.0,
        min_move_s: float = 1.0,
        resolution_deg: float = GIMBAL_RESOLUTION_DEG,
        t0_ns: int = 0,
    ) -> None:
        self.rng, self.rate, self.g = rng, rate_hz, g
        self.errors_at = errors_at or (lambda t: (SEED000_ACCEL, SEED000_GYRO))
        self.speed, self.min_move, self.res = joint_speed_dps, min_move_s, resolution_deg
        self.k = 0  # next sample index
        self.t0_ns = t0_ns
        self.angles = np.zeros(2)
        self._move: tuple[FloatArray, FloatArray, float, float] | None = (
            None  # start, target, t_start, T
        )

    @property
    def t_s(self) -> float:
        return self.k / self.rate

    def quantise(self, angles_deg: FloatArray) -> FloatArray:
        a = np.asarray(angles_deg, dtype=float)
        a = np.array([np.clip(a[0], *ROLL_LIMITS_DEG), np.clip(a[1], *PITCH_LIMITS_DEG)])
        return np.round(a / self.res) * self.res

    def command(self, target_deg: FloatArray) -> float:
        """Start moving to ``target_deg``; returns the move's duration, s."""
        start = self._angles_at(np.array([self.t_s]))[0][0]
        tgt = self.quantise(target_deg)
        T = move_duration_s(tgt - start, self.speed, self.min_move)
        self._move = (start, tgt, self.t_s, T)
        return T

    def skip(self, seconds: float) -> None:
        """Let time pass without reading samples (the robot does something else)."""
        a, _ = self._angles_at(np.array([self.t_s + seconds]))
        self.angles = a[0]
        self._move = None
        self.k += int(round(seconds * self.rate))

    def _angles_at(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        if self._move is None:
            return np.tile(self.angles, (len(t), 1)), np.zeros((len(t), 2))
        a, b, t0, T = self._move
        s, ds = min_jerk((t - t0) / T)
        return a + s[:, None] * (b - a), (ds / T)[:, None] * (b - a)

    def read(self, n: int) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
        """The next ``n`` raw samples: t_ns (n,), accel (n, 3) m/s^2, gyro (n, 3) rad/s."""
        t = (self.k + np.arange(n)) / self.rate
        ang, rate = self._angles_at(t)
        _, f, w = gimbal_kinematics(ang, rate, self.g)
        ea, eg = self.errors_at(float(t[0]))
        acc = add_sensor_noise(
            raw_from_errors(f, ea), self.rng, BWT901CL_ACCEL_DENSITY * np.sqrt(self.rate)
        )
        gyr = add_sensor_noise(
            raw_from_errors(w, eg), self.rng, BWT901CL_GYRO_DENSITY * np.sqrt(self.rate)
        )
        self.k += n
        if self._move is not None and t[-1] >= self._move[2] + self._move[3]:
            self.angles = self._move[1]
            self._move = None
        return self.t0_ns + np.round(t * 1e9).astype(np.int64), acc, gyr


@dataclass
class MultiPoseTruth:
    """Ground truth of a multi-pose log.

    t_s: (N,) s; angles_deg: (N, 2) gimbal roll/pitch; R_w_i: (N, 3, 3); accel_i: (N, 3) true specific
    force, m/s^2; omega_i: (N, 3) true rate, rad/s; static: (N,) bool, True while the gimbal holds;
    accel/gyro: the error parameters used; g: gravity magnitude, m/s^2.
    """

    t_s: FloatArray
    angles_deg: FloatArray
    R_w_i: FloatArray
    accel_i: FloatArray
    omega_i: FloatArray
    static: NDArray[np.bool_]
    accel: TriadErrors
    gyro: TriadErrors
    g: float


@dataclass
class MultiPoseSim:
    """A simulated calibration log (``log``, raw units) and its ground truth (``truth``)."""

    log: ImuLog
    truth: MultiPoseTruth


def simulate_multipose(
    plan_deg: FloatArray,
    rng: np.random.Generator,
    *,
    rate_hz: float = 100.0,
    t_init_s: float = 50.0,
    t_wait_s: float = 3.0,
    joint_speed_dps: float = 90.0,
    min_move_s: float = 1.0,
    accel: TriadErrors = SEED000_ACCEL,
    gyro: TriadErrors = SEED000_GYRO,
    accel_noise_std: float | None = None,
    gyro_noise_std: float | None = None,
    accel_quant: float | None = None,
    gyro_quant: float | None = None,
    g: float = 9.80665,
    resolution_deg: float = GIMBAL_RESOLUTION_DEG,
) -> MultiPoseSim:
    """Simulate the IMU on a gimbal: still for ``t_init_s`` at the first pose, then each pose held ``t_wait_s``.

    plan_deg: (P, 2) gimbal [roll, pitch] targets, deg (clipped to the joint limits and rounded to the
        servo resolution). Noise std default to BWT901CL-class densities at ``rate_hz``.
    Returns the raw log (accel in m/s^2, gyro in rad/s, with the error model applied) and the truth.
    """
    plan = np.asarray(plan_deg, dtype=float).reshape(-1, 2)
    plan = np.stack(
        [np.clip(plan[:, 0], *ROLL_LIMITS_DEG), np.clip(plan[:, 1], *PITCH_LIMITS_DEG)], axis=-1
    )
    plan = np.round(plan / resolution_deg) * resolution_deg
    dist = np.max(np.abs(np.diff(plan, axis=0)), axis=1) if len(plan) > 1 else np.zeros(0)
    move_s = np.maximum(
        dist / joint_speed_dps * 1.875, min_move_s
    )  # min-jerk peak rate 1.875x mean
    # Timeline: [init hold][move 1][hold 1][move 2][hold 2]...
    seg_start = [0.0]
    for m in move_s:
        seg_start.append(seg_start[-1] + (t_init_s if len(seg_start) == 1 else t_wait_s) + m)
    seg_start_arr = np.array(seg_start)  # time each hold (after the first) begins
    total = seg_start_arr[-1] + (t_wait_s if len(plan) > 1 else t_init_s)
    n = int(np.floor(total * rate_hz)) + 1
    t = np.arange(n) / rate_hz

    # For each sample: which move it belongs to and where in the move.
    move_end = seg_start_arr[1:]
    move_begin = move_end - move_s
    idx = np.searchsorted(move_end, t, side="right")  # moves completed
    idx_c = np.minimum(idx, len(move_s) - 1) if len(move_s) else idx
    angles = plan[np.minimum(idx, len(plan) - 1)].copy()
    rates = np.zeros((n, 2))
    if len(move_s):
        in_move = (idx < len(move_s)) & (t >= move_begin[idx_c])
        k = idx_c[in_move]
        T = move_s[k]
        tau = (t[in_move] - move_begin[k]) / T
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        ds = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T
        delta = plan[k + 1] - plan[k]
        angles[in_move] = plan[k] + s[:, None] * delta
        rates[in_move] = ds[:, None] * delta
        static = ~in_move
    else:
        static = np.ones(n, dtype=bool)

    R_w_i, accel_i, omega_i = gimbal_kinematics(angles, rates, g)

    a_std = (
        BWT901CL_ACCEL_DENSITY * np.sqrt(rate_hz) if accel_noise_std is None else accel_noise_std
    )
    g_std = BWT901CL_GYRO_DENSITY * np.sqrt(rate_hz) if gyro_noise_std is None else gyro_noise_std
    acc_raw = add_sensor_noise(raw_from_errors(accel_i, accel), rng, a_std, accel_quant)
    gyr_raw = add_sensor_noise(raw_from_errors(omega_i, gyro), rng, g_std, gyro_quant)
    t_ns = np.round(t * 1e9).astype(np.int64)
    log = ImuLog(t_ns, acc_raw, gyr_raw, "m/s^2", "rad/s", source="simulated gimbal")
    truth = MultiPoseTruth(t, angles, R_w_i, accel_i, omega_i, static, accel, gyro, g)
    return MultiPoseSim(log, truth)
