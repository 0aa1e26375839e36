"""What a calibration buys an INS: the same simulated robot navigated with the raw IMU, the calibrated IMU,
and the calibrated IMU after a Kalman / RWNN alignment.

The vehicle (by default the car of seed 001's street loop, ``sim/trajectory.py``) carries an IMU with
known errors. Its first ``t_align_s`` seconds come with position fixes (RTK-like, ``fix_std_m`` at 10 Hz);
then the INS runs free for ``t_free_s`` seconds, as after losing RTK. (On the slow figure-eight robot the
heading is barely observable from position fixes: its centripetal acceleration, nearly fixed in the body,
looks like an accelerometer bias; every alignment there leaves heading errors of several degrees.) Each variant starts its free run from the true position and velocity at the end
of the fixes, with the attitude it has there (the truth for the raw and calibrated runs, which had no
alignment; its own estimate for the aligned runs) and reports the attitude and position error at the end.

An experiment on the simulator, not a metric: it lives above ``eval`` (which computes metrics of
trajectories and imports no estimator or simulator) and under the ``demo`` command that shows it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import log as so3_log
from imuslam.imu.model import ImuCalibration
from imuslam.ins.align import Aiding, run_alignment
from imuslam.ins.kf import KfNoise
from imuslam.ins.strapdown import integrate
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.nav import NavState
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.trajectory import CarLoop, EulerTrajectory

FloatArray = NDArray[np.float64]


@dataclass
class InsRun:
    """One variant: name, attitude error (deg) and position error (m) at the end of the free run, and
    the position error over the free run (t_s (K,), err_m (K,))."""

    name: str
    attitude_err_deg: float
    position_err_m: float
    t_s: FloatArray
    err_m: FloatArray


def _free_run(
    name: str,
    log: ImuLog,
    t0_s: float,
    start: NavState,
    truth_p: FloatArray,
    truth_R_end: FloatArray,
    g: float,
) -> InsRun:
    """Free inertial navigation from sample time ``t0_s`` on, against the truth positions (from there on)."""
    t = log.t_s
    k0 = int(np.searchsorted(t, t0_s))
    P, _, R = integrate(t[k0:], log.accel[k0:], log.gyro[k0:], start, g)
    err = np.linalg.norm(P - truth_p[k0:], axis=1)
    att = float(np.rad2deg(np.linalg.norm(so3_log(truth_R_end.T @ R[-1]))))
    return InsRun(name, att, float(err[-1]), t[k0:] - t[k0], err)


def ins_benefit(
    calibration: ImuCalibration,
    spec: ImuErrorSpec,
    rng: np.random.Generator,
    t_align_s: float = 60.0,
    t_free_s: float = 30.0,
    fix_std_m: float = 0.02,
    rate_hz: float = 100.0,
    g: float = 9.80665,
    traj: EulerTrajectory | None = None,
) -> list[InsRun]:
    """Navigate the simulated robot with an IMU of errors ``spec`` four ways; see the module docstring."""
    traj = traj or CarLoop()
    raw, tr = simulate_imu(traj, t_align_s + t_free_s, rng, spec, rate_hz, g=g)
    cal = calibration.correct(raw)
    t = raw.t_s
    k0 = int(np.searchsorted(t, t_align_s))
    truth_at = NavState(tr.p_w[k0], tr.vel_w[k0], tr.R_w_i[k0])

    runs = [
        _free_run(
            f"{name}, free from the true state", log, t_align_s, truth_at, tr.p_w, tr.R_w_i[-1], g
        )
        for name, log in (("raw IMU", raw), ("calibrated IMU", cal))
    ]
    ta = np.arange(0.1, t_align_s + 1e-9, 0.1)
    aid = Aiding(
        ta, "position", traj.state(ta).p_w + rng.normal(size=(len(ta), 3)) * fix_std_m, fix_std_m
    )
    init = NavState(tr.p_w[0], tr.vel_w[0], tr.R_w_i[0])
    noise = KfNoise(spec.accel_density, spec.gyro_density, max(spec.accel_bias_rw, 1e-5),
                    max(spec.gyro_bias_rw, 1e-6))  # fmt: skip
    for name, log, method in (
        ("raw IMU", raw, "kf"),
        ("calibrated IMU", cal, "kf"),
        ("calibrated IMU", cal, "rwnn"),
    ):
        res = run_alignment(log.slice(0, k0 + 1), aid, init, method, noise, g=g)  # type: ignore[arg-type]
        start = NavState(tr.p_w[k0], tr.vel_w[k0], res.final.R_n_b)
        label = f"{name}, {method.upper()}-aligned"
        runs.append(_free_run(label, res.corrected(log), t_align_s, start, tr.p_w, tr.R_w_i[-1], g))
    return runs
