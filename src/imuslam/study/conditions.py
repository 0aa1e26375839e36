"""IMU conditions of a study: what sensor the estimator gets, and how it was corrected.

All but ``ideal`` carry seed 000's table-2 errors (``ImuErrorSpec.bwt901cl``), aged by the study's
drift (``DriftSpec``: the errors move with working time, seed 000), with BWT901CL-class noise:

ideal     no systematic errors (noise and bias random walk only): what a perfect calibration gives
raw       the aged errors, uncorrected
offline   corrected with a calibration made ``age_h`` hours before the run (a gimbal log with the errors
          as they were then): what is left is the drift since
online    corrected with a calibration made just before the run (the online calibrator's gimbal session,
          errors as they are now)
drifting  online-calibrated at the start, but the errors keep moving during the run as much as they
          moved in ``age_h`` hours (a warm-up): what a calibration that is not kept current leaves

Calibrations are the multi-position method (``imu.calibrate``, Tedaldi et al. 2014) on a simulated
40-pose gimbal log (``sim.multipose``), never the truth.
"""

from __future__ import annotations

import numpy as np

from imuslam.imu.calibrate import calibrate
from imuslam.imu.model import ImuCalibration
from imuslam.sim.imu import IDEAL, ImuErrorSpec
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO, TriadErrors
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg
from imuslam.study.config import DriftSpec


def aged_errors(drift: DriftSpec, age_h: float) -> tuple[TriadErrors, TriadErrors]:
    """Seed 000's table-2 errors after ``age_h`` hours of drift (accelerometer, gyro)."""
    a, g = SEED000_ACCEL, SEED000_GYRO
    s = 1.0 + drift.scale_per_h * age_h
    ba = a.b + np.asarray(drift.accel_bias_per_h) * age_h
    bg = g.b + np.deg2rad(np.asarray(drift.gyro_bias_per_h_dps)) * age_h
    return TriadErrors(a.T, a.K * s, ba, a.bias_sign), TriadErrors(g.T, g.K * s, bg, g.bias_sign)


def sensor_spec(condition: str, drift: DriftSpec, run_s: float) -> ImuErrorSpec:
    """The simulated sensor of ``condition`` for a run of ``run_s`` seconds (alignment included)."""
    base = ImuErrorSpec.bwt901cl()
    if condition == "ideal":
        return ImuErrorSpec(IDEAL, IDEAL, base.accel_density, base.gyro_density,
                            base.accel_bias_rw, base.gyro_bias_rw)  # fmt: skip
    ea, eg = aged_errors(drift, drift.age_h)
    spec = ImuErrorSpec(ea, eg, base.accel_density, base.gyro_density, base.accel_bias_rw,
                        base.gyro_bias_rw)  # fmt: skip
    if condition == "drifting":
        # the change of age_h hours, squeezed into this run (per hour rates scaled)
        f = drift.age_h * 3600.0 / run_s
        spec.bias_drift_per_h = np.array(
            [np.asarray(drift.accel_bias_per_h) * f, np.deg2rad(drift.gyro_bias_per_h_dps) * f]
        )
        spec.scale_drift_per_h = drift.scale_per_h * f
    return spec


_CAL_CACHE: dict[tuple[bytes, int], ImuCalibration] = {}


def gimbal_calibration(drift: DriftSpec, age_h: float, seed: int) -> ImuCalibration:
    """Calibrate from a simulated 40-pose gimbal log with the errors as they were at ``age_h``
    (kept per process: the cells of one seed share it)."""
    ea, eg = aged_errors(drift, age_h)
    key = (np.concatenate([ea.T.ravel(), ea.K, ea.b, eg.T.ravel(), eg.K, eg.b]).tobytes(), seed)
    if key not in _CAL_CACHE:
        rng = np.random.default_rng(seed)
        sim = simulate_multipose(sphere_plan_deg(40, rng), rng, accel=ea, gyro=eg)
        if len(_CAL_CACHE) > 64:
            _CAL_CACHE.clear()
        _CAL_CACHE[key] = calibrate(sim.log).calibration
    return _CAL_CACHE[key]


def calibration_age_h(condition: str, drift: DriftSpec) -> float | None:
    """Age of the errors the condition's calibration was made with; None: no calibration."""
    return {"offline": 0.0, "online": drift.age_h, "drifting": drift.age_h}.get(condition)
