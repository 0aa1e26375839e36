"""Which calibration method the online calibrator can use: tests/imu/test_online.py's drifting robot
(z accelerometer bias 0.05 m/s^2 per hour, gyro bias 0.001 rad/s per hour, scales 2e-4 per hour; seed 2,
40 poses, one hour) run once per method; per calibration version the accelerometer and gyro NEES
against the truth at the middle of its session (chi-square 9 dof: 99.9 % bound 27.9), the largest
normalised accelerometer error, and CPU time.

Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python bench/online_methods.py  (about 1 minute of CPU)
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.imu.calibrate import CalibrationConfig
from imuslam.imu.history import CalibrationHistory
from imuslam.imu.online import OnlineConfig
from imuslam.imu.online_sim import Drift, run_simulated_robot
from imuslam.sim.multipose import sphere_plan_deg

METHODS = {
    "tedaldi (online default)": {"method": "tedaldi"},
    "joint (offline default)": {},
    "joint + accel bias drift (forced)": {"accel_bias_drift": True},
}


def main() -> None:
    drift = Drift(
        accel_bias_per_h=np.array([0.0, 0.0, 0.05]),
        gyro_bias_per_h=np.full(3, 0.001),
        scale_per_h=2e-4,
    )
    table = Table(
        title="Online calibrator on the drifting robot of tests/imu/test_online.py (seed 2)"
    )
    for c in ("method", "version", "session (s)", "NEES accel", "NEES gyro", "worst accel error (sigma)",
              "drift events", "CPU (s)"):  # fmt: skip
        table.add_column(c)
    for name, kw in METHODS.items():
        c0 = time.process_time()
        with tempfile.TemporaryDirectory() as tmp:
            rng = np.random.default_rng(2)
            cfg = OnlineConfig(calibration=CalibrationConfig(**kw), cv_folds=0)
            hist = CalibrationHistory(Path(tmp))
            run = run_simulated_robot(sphere_plan_deg(40, rng), 3600.0, drift, rng, cfg, hist)
            n_drift = sum(e.kind == "drift" for e in run.calibrator.events)
            cpu = time.process_time() - c0
            for v, (t0, t1) in zip(hist.versions(), run.sessions, strict=True):
                cal = hist.load(v)
                truth = drift.truth_at(0.5 * (t0 + t1))
                assert cal.cov_accel is not None and cal.cov_gyro is not None
                ea = cal.accel_params - truth.accel_params
                eg = cal.gyro_params - truth.gyro_params
                z = np.abs(ea) / np.sqrt(np.diag(cal.cov_accel))
                table.add_row(name, str(v), f"{t0:.0f}-{t1:.0f}",
                              f"{ea @ np.linalg.solve(cal.cov_accel, ea):.1f}",
                              f"{eg @ np.linalg.solve(cal.cov_gyro, eg):.1f}", f"{z.max():.1f}",
                              str(n_drift), f"{cpu:.0f}")  # fmt: skip
    Console(width=160).print(table)


if __name__ == "__main__":
    main()
