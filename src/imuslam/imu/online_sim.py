"""A simulated robot for the online calibrator: the IMU on a simulated gimbal, errors drifting with working
time, still moments during normal operation; runs faster than real time."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.imu.history import CalibrationHistory
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.imu.online import OnlineCalibrator, OnlineConfig
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO, TriadErrors
from imuslam.sim.multipose import GimbalImuStream

FloatArray = NDArray[np.float64]
T0_NS = 1_700_000_000_000_000_000  # simulated clock starts at a plausible epoch


@dataclass
class Drift:
    """Linear drift per hour of the accelerometer bias (m/s^2, raw), gyro bias (rad/s) and of all scale
    factors (relative), starting from seed 000's table-2 errors."""

    accel_bias_per_h: FloatArray = field(default_factory=lambda: np.zeros(3))
    gyro_bias_per_h: FloatArray = field(default_factory=lambda: np.zeros(3))
    scale_per_h: float = 0.0

    def errors_at(self, t_s: float) -> tuple[TriadErrors, TriadErrors]:
        h = t_s / 3600.0
        a, g = SEED000_ACCEL, SEED000_GYRO
        return (
            TriadErrors(
                a.T, a.K * (1 + self.scale_per_h * h), a.b + self.accel_bias_per_h * h, a.bias_sign
            ),
            TriadErrors(
                g.T, g.K * (1 + self.scale_per_h * h), g.b + self.gyro_bias_per_h * h, g.bias_sign
            ),
        )

    def truth_at(self, t_s: float) -> ImuCalibration:
        ea, eg = self.errors_at(t_s)
        return ImuCalibration(TriadModel(ea.T, ea.K, ea.b), TriadModel(eg.T, eg.K, eg.b))


@dataclass
class OnlineRun:
    """The calibrator after the run, and for each accepted calibration its session's start and end (s)."""

    calibrator: OnlineCalibrator
    sessions: list[tuple[float, float]]


def run_simulated_robot(
    plan_deg: FloatArray,
    duration_s: float,
    drift: Drift,
    rng: np.random.Generator,
    config: OnlineConfig | None = None,
    history: CalibrationHistory | None = None,
    still_every_s: float = 300.0,
    still_s: float = 6.0,
    rate_hz: float = 100.0,
) -> OnlineRun:
    """Calibrate at start-up, then every ``still_every_s`` the robot stands still for ``still_s`` (the time
    between is skipped); a drift event starts a new gimbal session at once."""
    stream = GimbalImuStream(rng, drift.errors_at, rate_hz, t0_ns=T0_NS)
    cal = OnlineCalibrator(plan_deg, stream.command, config, history=history, rate_hz=rate_hz)
    sessions: list[tuple[float, float]] = []

    def run_session() -> None:
        t_start = stream.t_s
        cal.start_session(T0_NS + int(stream.t_s * 1e9))
        while cal.phase != "monitor" and stream.t_s < duration_s + 3600:
            t, a, w = stream.read(10)
            for i in range(10):
                cal.step(int(t[i]), a[i], w[i])
                if cal.phase == "monitor":
                    break
        sessions.append((t_start, stream.t_s))

    run_session()
    while stream.t_s < duration_s:
        stream.command(np.zeros(2))
        stream.skip(still_every_s - still_s)  # driving around, gimbal back home
        t, a, w = stream.read(int(still_s * rate_hz))
        n_events = len(cal.events)
        for i in range(len(t)):
            cal.step(int(t[i]), a[i], w[i])
        cal._end_still(int(t[-1]))  # the robot moves off: close the still moment
        if any(e.kind in ("drift", "schedule") for e in cal.events[n_events:]):
            run_session()
    return OnlineRun(cal, sessions)
