"""C2-smooth trajectories with exact derivatives: position, velocity and acceleration in the world (ENU,
z up, REP-103), attitude ``R_w_b`` and body rate ``omega_b`` (body x forward, y left, z up).

Attitude is built from Z-Y-X Euler angles ``R_w_b = Rz(yaw) Ry(pitch) Rx(roll)``; body rates from their
derivatives: ``omega_b = [droll - dyaw s(p), dpitch c(r) + dyaw s(r) c(p), -dpitch s(r) + dyaw c(r) c(p)]``
(e.g. Titterton & Weston, "Strapdown Inertial Navigation Technology", eq. 3.46, inverted).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, Field

from imuslam.geometry.euler import euler_rates_to_body, euler_to_matrix

FloatArray = NDArray[np.float64]


@dataclass
class TrajectoryState:
    """States at times t_s (N,): p_w, vel_w, acc_w (N, 3) in m, m/s, m/s^2; R_w_b (N, 3, 3);
    omega_b (N, 3) body angular rate, rad/s."""

    t_s: FloatArray
    p_w: FloatArray
    vel_w: FloatArray
    acc_w: FloatArray
    R_w_b: FloatArray
    omega_b: FloatArray


class TrajectoryModel(Protocol):
    """Anything that gives the exact state at any times (a model of motion, not a record of poses:
    the record is :class:`imuslam.interfaces.Trajectory`)."""

    def state(self, t_s: ArrayLike) -> TrajectoryState: ...


def __getattr__(name: str) -> object:
    # the Protocol's old name, kept for imports written before the rename
    if name == "Trajectory":
        return TrajectoryModel
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class EulerTrajectory(ABC):
    """A trajectory given by analytic position and Euler-angle functions and their derivatives."""

    @abstractmethod
    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """p, v, a (N, 3)."""

    @abstractmethod
    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """[roll, pitch, yaw] (N, 3) and their rates (N, 3)."""

    def state(self, t_s: ArrayLike) -> TrajectoryState:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        p, v, a = self.position(t)
        ang, rate = self.euler(t)
        return TrajectoryState(t, p, v, a, euler_to_matrix(ang), euler_rates_to_body(ang, rate))


def _sines(
    t: FloatArray, amp: FloatArray, freq: FloatArray, phase: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sum-of-sines columns and their first two derivatives: amp, freq, phase (3, K)."""
    arg = freq[None] * t[:, None, None] + phase[None]  # (N, 3, K)
    x = np.sum(amp * np.sin(arg), axis=2)
    dx = np.sum(amp * freq * np.cos(arg), axis=2)
    ddx = -np.sum(amp * freq**2 * np.sin(arg), axis=2)
    return x, dx, ddx


class _HeadingFromVelocity(EulerTrajectory):
    """Planar vehicles: yaw along the horizontal velocity (non-holonomic), small roll/pitch from the ground."""

    def __init__(self, tilt_amp: float, tilt_freq: tuple[float, float]) -> None:
        self.tilt_amp = tilt_amp
        self.tilt_freq = tilt_freq

    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        _, v, a = self.position(t)
        yaw = np.arctan2(v[:, 1], v[:, 0])
        dyaw = (v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]) / (v[:, 0] ** 2 + v[:, 1] ** 2)
        f1, f2 = self.tilt_freq
        roll = self.tilt_amp * np.sin(f1 * t)
        pitch = self.tilt_amp * np.sin(f2 * t + 1.0)
        droll = self.tilt_amp * f1 * np.cos(f1 * t)
        dpitch = self.tilt_amp * f2 * np.cos(f2 * t + 1.0)
        return np.stack([roll, pitch, yaw], axis=1), np.stack([droll, dpitch, dyaw], axis=1)


class DiffDriveFigureEight(_HeadingFromVelocity):
    """A differential-drive robot driving a figure eight in the 8 m x 8 m room (seed 000): both turning
    directions, as the seed's counter-clockwise then clockwise runs. Speed about 0.3-0.5 m/s."""

    def __init__(
        self, half_x: float = 2.6, half_y: float = 1.8, period_s: float = 60.0, height: float = 0.15
    ) -> None:
        super().__init__(tilt_amp=0.005, tilt_freq=(3.1, 2.3))
        self.ax, self.ay, self.w, self.h = half_x, half_y, 2 * np.pi / period_s, height

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        w = self.w
        s1, c1, s2, c2 = np.sin(w * t), np.cos(w * t), np.sin(2 * w * t), np.cos(2 * w * t)
        z = np.zeros_like(t)
        p = np.stack([self.ax * s1, self.ay * s2, z + self.h], axis=1)
        v = np.stack([self.ax * w * c1, 2 * self.ay * w * c2, z], axis=1)
        a = np.stack([-self.ax * w**2 * s1, -4 * self.ay * w**2 * s2, z], axis=1)
        return p, v, a


class CarLoop(_HeadingFromVelocity):
    """A car on a rounded-rectangle street loop around a block (seed 001's drive), about 8 m/s."""

    def __init__(
        self,
        half_x: float = 45.0,
        half_y: float = 31.0,
        squareness: float = 0.1,
        speed: float = 8.0,
        height: float = 1.8,
    ) -> None:
        super().__init__(tilt_amp=0.01, tilt_freq=(1.3, 0.7))
        self.ax, self.ay, self.c, self.h = half_x, half_y, squareness, height
        self.w = speed / (0.5 * (half_x + half_y) * (1 + 3 * squareness * 0.5))

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        w, c = self.w, self.c
        u = w * t
        z = np.zeros_like(t)
        p = np.stack(
            [
                self.ax * (np.cos(u) - c * np.cos(3 * u)),
                self.ay * (np.sin(u) + c * np.sin(3 * u)),
                z + self.h,
            ],
            axis=1,
        )
        v = w * np.stack(
            [
                self.ax * (-np.sin(u) + 3 * c * np.sin(3 * u)),
                self.ay * (np.cos(u) + 3 * c * np.cos(3 * u)),
                z,
            ],
            axis=1,
        )
        a = w**2 * np.stack(
            [
                self.ax * (-np.cos(u) + 9 * c * np.cos(3 * u)),
                self.ay * (-np.sin(u) - 9 * c * np.sin(3 * u)),
                z,
            ],
            axis=1,
        )
        return p, v, a


class Handheld(EulerTrajectory):
    """A device carried by hand: 6-DoF sums of sines around a centre (tens of degrees, tens of cm)."""

    def __init__(self, centre: tuple[float, float, float] = (0.0, 0.0, 1.4)) -> None:
        self.centre = np.asarray(centre)
        self.pa = np.array([[0.6, 0.1], [0.5, 0.08], [0.15, 0.05]])
        self.pf = np.array([[0.45, 2.1], [0.65, 1.7], [1.05, 2.9]])
        self.pp = np.array([[0.0, 1.0], [0.5, 0.2], [1.0, 0.0]])
        self.aa = np.array([[0.25, 0.05], [0.2, 0.05], [0.9, 0.1]])
        self.af = np.array([[0.55, 2.3], [0.35, 1.9], [0.25, 1.3]])
        self.ap = np.array([[0.0, 0.3], [1.0, 0.7], [0.0, 2.0]])

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        p, v, a = _sines(t, self.pa, self.pf, self.pp)
        return p + self.centre, v, a

    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        ang, rate, _ = _sines(t, self.aa, self.af, self.ap)
        return ang, rate


class Static(EulerTrajectory):
    """A body at rest."""

    def __init__(
        self,
        p_w: tuple[float, float, float] = (0.0, 0.0, 0.0),
        rpy: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.p = np.asarray(p_w, float)
        self.rpy = np.asarray(rpy, float)

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        z = np.zeros((len(t), 3))
        return z + self.p, z.copy(), z.copy()

    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        return np.zeros((len(t), 3)) + self.rpy, np.zeros((len(t), 3))


class TrajectoryConfig(BaseModel):
    """A trajectory from YAML: ``kind`` and its main sizes."""

    kind: Literal["diff_drive", "car_loop", "handheld", "static"] = "diff_drive"
    period_s: float = Field(60.0, gt=0, description="diff_drive: time of one figure eight, s")
    speed: float = Field(8.0, gt=0, description="car_loop: mean speed, m/s")


def make_trajectory(cfg: TrajectoryConfig) -> EulerTrajectory:
    if cfg.kind == "diff_drive":
        return DiffDriveFigureEight(period_s=cfg.period_s)
    if cfg.kind == "car_loop":
        return CarLoop(speed=cfg.speed)
    if cfg.kind == "handheld":
        return Handheld()
    return Static()


class CorridorDrive(_HeadingFromVelocity):
    """A robot weaving gently down the corridor world along +x at ``speed`` m/s."""

    def __init__(self, speed: float = 0.5, weave: float = 0.3, x0: float = 1.0) -> None:
        super().__init__(tilt_amp=0.005, tilt_freq=(2.9, 2.1))
        self.v, self.a, self.x0 = speed, weave, x0

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        w = 0.4
        z = np.zeros_like(t)
        p = np.stack([self.x0 + self.v * t, self.a * np.sin(w * t), z + 0.15], axis=1)
        v = np.stack([z + self.v, self.a * w * np.cos(w * t), z], axis=1)
        a = np.stack([z, -self.a * w**2 * np.sin(w * t), z], axis=1)
        return p, v, a


def _smooth_progress(t: FloatArray, T: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Quintic smoothstep s(t) from 0 to 1 over [0, T] (zero speed and acceleration at both ends), with
    its first two derivatives; constant outside."""
    tau = np.clip(t / T, 0.0, 1.0)
    inside = (t > 0) & (t < T)
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    ds = np.where(inside, (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T, 0.0)
    dds = np.where(inside, (60 * tau - 180 * tau**2 + 120 * tau**3) / T**2, 0.0)
    return s, ds, dds


class SquareLoopCcwCw(EulerTrajectory):
    """Seed 000's validation drive: once round a rounded square inside the 8 m x 8 m room counter-
    clockwise from point A, a turn on the spot by 180 degrees at A, then once round clockwise back to A.

    The path is ``p(u) = a (cos u - c cos 3u, sin u + c sin 3u)`` (a squircle, ``c`` its squareness),
    A = p(0); each lap follows ``u`` with a quintic smoothstep in time (the robot starts and stops at
    rest), yaw along the direction of travel (the differential drive cannot slide). C2-smooth.
    """

    def __init__(
        self, half_size: float = 3.0, squareness: float = 0.1, lap_s: float = 60.0,
        turn_s: float = 8.0, height: float = 0.15,
    ) -> None:  # fmt: skip
        self.a, self.c, self.lap, self.turn, self.h = half_size, squareness, lap_s, turn_s, height

    @property
    def duration_s(self) -> float:
        return 2 * self.lap + self.turn

    def _curve(self, u: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        a, c = self.a, self.c
        p = a * np.stack([np.cos(u) - c * np.cos(3 * u), np.sin(u) + c * np.sin(3 * u)], axis=1)
        dp = a * np.stack(
            [-np.sin(u) + 3 * c * np.sin(3 * u), np.cos(u) + 3 * c * np.cos(3 * u)], axis=1
        )
        ddp = a * np.stack(
            [-np.cos(u) + 9 * c * np.cos(3 * u), -np.sin(u) - 9 * c * np.sin(3 * u)], axis=1
        )
        return p, dp, ddp

    def _param(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """u(t), du/dt, d2u/dt2: 0 -> 2 pi in lap 1, held during the turn, 2 pi -> 0 in lap 2."""
        s1, d1, dd1 = _smooth_progress(t, self.lap)
        s2, d2, dd2 = _smooth_progress(t - self.lap - self.turn, self.lap)
        two_pi = 2 * np.pi
        return two_pi * (s1 - s2), two_pi * (d1 - d2), two_pi * (dd1 - dd2)

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        u, du, ddu = self._param(t)
        p, dp, ddp = self._curve(u)
        z = np.zeros_like(t)
        v = dp * du[:, None]
        acc = ddp * du[:, None] ** 2 + dp * ddu[:, None]
        return (
            np.column_stack([p, z + self.h]),
            np.column_stack([v, z]),
            np.column_stack([acc, z]),
        )

    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        u, du, _ = self._param(t)
        _, dp, ddp = self._curve(u)
        tangent = np.arctan2(dp[:, 1], dp[:, 0])
        dtangent_du = (dp[:, 0] * ddp[:, 1] - dp[:, 1] * ddp[:, 0]) / (
            dp[:, 0] ** 2 + dp[:, 1] ** 2
        )
        # lap 2 drives the curve backwards: heading = tangent + pi; the turn blends between the two
        sb, dsb, _ = _smooth_progress(t - self.lap, self.turn)
        yaw = tangent + np.pi * sb
        dyaw = dtangent_du * du + np.pi * dsb
        z = np.zeros_like(t)
        return np.stack([z, z, yaw], axis=1), np.stack([z, z, dyaw], axis=1)


class ExcitedHandheld(Handheld):
    """A LiDAR-IMU rig waved by hand to calibrate it (LI-Init's excitation, Zhu et al. 2022, Sec. V):
    roll, pitch and yaw swing by 15-30 degrees at 0.15-0.6 Hz and the rig moves by decimetres on all
    three axes around ``centre``; peak rates about 1 rad/s, angular accelerations about 3 rad/s^2. The
    same sums of sines as :class:`Handheld`, with larger, faster terms."""

    def __init__(self, centre: tuple[float, float, float] = (0.0, 0.0, 1.3)) -> None:
        self.centre = np.asarray(centre, float)
        self.pa = np.array([[0.4, 0.06], [0.4, 0.05], [0.15, 0.04]])
        self.pf = np.array([[0.8, 2.4], [1.1, 2.9], [1.7, 3.3]])
        self.pp = np.array([[0.0, 1.0], [0.7, 0.2], [1.3, 0.4]])
        self.aa = np.array([[0.3, 0.08], [0.3, 0.08], [0.5, 0.08]])
        self.af = np.array([[2.2, 3.7], [1.9, 3.1], [0.9, 2.6]])
        self.ap = np.array([[0.0, 0.5], [1.2, 0.3], [0.4, 2.2]])
