"""Wheel odometry of a differential-drive robot (encoder ticks with per-wheel scale error and slip) and an
RTK-like position track with noise."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces.odometry import WheelOdometry
from imuslam.sim.trajectory import TrajectoryModel

FloatArray = NDArray[np.float64]


@dataclass
class WheelConfig:
    """Encoders and geometry; defaults after a small indoor robot (2000 ticks per turn as BreezySLAM's
    rover, 77 mm wheels, 330 mm track). scale_error: relative radius error per wheel [left, right];
    slip_std: relative white slip per sample."""

    ticks_per_rev: int = 2000
    wheel_radius: float = 0.077
    track: float = 0.33
    rate_hz: float = 50.0
    scale_error: tuple[float, float] = (0.01, -0.008)
    slip_std: float = 0.02


def simulate_wheels(
    traj: TrajectoryModel,
    duration_s: float,
    rng: np.random.Generator,
    cfg: WheelConfig | None = None,
    t0_s: float = 0.0,
) -> WheelOdometry:
    """Encoder ticks from the body's forward speed and yaw rate (wheel speeds v -+ w track / 2)."""
    c = cfg or WheelConfig()
    n = int(np.floor(duration_s * c.rate_hz)) + 1
    t = t0_s + np.arange(n) / c.rate_hz
    st = traj.state(t)
    v_b = np.einsum("nji,nj->ni", st.R_w_b, st.vel_w)[:, 0]
    w_z = st.omega_b[:, 2]
    wheel_v = np.stack([v_b - w_z * c.track / 2, v_b + w_z * c.track / 2], axis=1)
    dt = 1.0 / c.rate_hz
    # trapezoid of the wheel speed between samples, with slip and radius error
    dist = np.concatenate([np.zeros((1, 2)), 0.5 * (wheel_v[1:] + wheel_v[:-1]) * dt])
    dist = (
        dist
        * (1 + rng.normal(size=dist.shape) * c.slip_std)
        / (1 + np.asarray(c.scale_error))[None]
    )
    turns = np.cumsum(dist, axis=0) / (2 * np.pi * c.wheel_radius)
    ticks = np.floor(turns * c.ticks_per_rev).astype(np.int64)
    return WheelOdometry(
        np.round(t * 1e9).astype(np.int64),
        ticks,
        dead_reckoning(
            ticks, c, st.p_w[0, :2], float(np.arctan2(st.R_w_b[0, 1, 0], st.R_w_b[0, 0, 0]))
        ),
    )


def dead_reckoning(
    ticks: NDArray[np.int64], c: WheelConfig, xy0: FloatArray, yaw0: float
) -> FloatArray:
    """Integrate encoder ticks (N, 2) into planar poses (N, 3) [x, y, yaw] (midpoint heading)."""
    d = np.diff(ticks, axis=0, prepend=ticks[:1]) / c.ticks_per_rev * 2 * np.pi * c.wheel_radius
    ds = d.mean(axis=1)
    dyaw = (d[:, 1] - d[:, 0]) / c.track
    yaw = yaw0 + np.cumsum(dyaw)
    mid = yaw - dyaw / 2
    x = xy0[0] + np.cumsum(ds * np.cos(mid))
    y = xy0[1] + np.cumsum(ds * np.sin(mid))
    return np.stack([x, y, yaw], axis=1)


def simulate_rtk(traj: TrajectoryModel, duration_s: float, rng: np.random.Generator, rate_hz: float = 10.0,
                 std_h: float = 0.02, std_v: float = 0.04, t0_s: float = 0.0) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """RTK-like fixes: times (N,) and positions (N, 3) with white noise (horizontal, vertical std, m)."""
    n = int(np.floor(duration_s * rate_hz)) + 1
    t = t0_s + np.arange(n) / rate_hz
    p = traj.state(t).p_w + rng.normal(size=(n, 3)) * np.array([std_h, std_h, std_v])
    return t, p
