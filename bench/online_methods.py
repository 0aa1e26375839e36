"""Which calibration method the online calibrator can use: tests/imu/test_online.py's drifting robot
(z accelerometer bias 0.05 m/s^2 per hour, gyro bias 0.001 rad/s per hour, scales 2e-4 per hour; seed 2,
40 poses, one hour) run once per method and pose order; per calibration version the accelerometer and
gyro NEES against the truth at the time its bias refers to (with a drift term the mean of its poses' times,
else the middle of its session; chi-square 9 dof: 99.9 % bound 27.9), the
largest normalised accelerometer error, the reported 1-sigma of the z accelerometer scale, the fitted
accelerometer bias drift (when the fit kept it), the time of the first drift event, and CPU time.

Two pose orders of the same 40 poses: the Fibonacci lattice's own order (its z component falls
monotonically with time, so a z bias that drifts linearly in the session looks exactly like a z scale
error), and the order ``imuslam online`` flies (:func:`imuslam.imu.poseplan.optimise_order`, 1000
iterations), under which a drift term separates from the scales.

Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python bench/online_methods.py  (about 1 minute of CPU)
Other robots: ``--seeds 1 3 4 --orders "imuslam online"``; the last table sums each method's accelerometer
NEES over all its versions (chi-square with 9 x versions degrees of freedom when the covariances hold).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.special import chdtri

from imuslam.imu.calibrate import CalibrationConfig
from imuslam.imu.history import CalibrationHistory
from imuslam.imu.online import OnlineConfig
from imuslam.imu.online_sim import T0_NS, Drift, run_simulated_robot
from imuslam.imu.poseplan import PlanModel, optimise_order
from imuslam.sim.multipose import sphere_plan_deg
from imuslam.threads import configure_process

METHODS = {
    "tedaldi": {"method": "tedaldi"},
    "joint, drift if significant (offline default)": {},
    "joint + accel bias drift (online default)": {"accel_bias_drift": True},
}
ORDERS = ("lattice", "imuslam online")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2])
    ap.add_argument("--orders", nargs="+", choices=ORDERS, default=list(ORDERS))
    args = ap.parse_args()
    drift = Drift(
        accel_bias_per_h=np.array([0.0, 0.0, 0.05]),
        gyro_bias_per_h=np.full(3, 0.001),
        scale_per_h=2e-4,
    )
    table = Table(title="Online calibrator on the drifting robot of tests/imu/test_online.py")
    for c in ("seed", "pose order", "method", "version", "session (s)", "NEES accel", "NEES gyro",
              "worst accel error (sigma)", "1-sigma s_az", "fitted z bias drift (m/s^2/h)",
              "first drift event (s)", "CPU (s)"):  # fmt: skip
        table.add_column(c)
    c_all, t_all = time.process_time(), time.perf_counter()
    sums: dict[tuple[str, str], list[float]] = {}
    for seed, order, (name, kw) in (
        (s, o, m) for s in args.seeds for o in args.orders for m in METHODS.items()
    ):
        c0 = time.process_time()
        with tempfile.TemporaryDirectory() as tmp:
            rng = np.random.default_rng(seed)
            plan = sphere_plan_deg(40, rng)
            if order == "imuslam online":
                plan = optimise_order(PlanModel.seed000(), plan, iterations=1000)
            cfg = OnlineConfig(calibration=CalibrationConfig(**kw), cv_folds=0)
            hist = CalibrationHistory(Path(tmp))
            run = run_simulated_robot(plan, 3600.0, drift, rng, cfg, hist)
            ev = [e for e in run.calibrator.events if e.kind == "drift"]
            first = f"{(ev[0].t_ns - T0_NS) * 1e-9:.0f}" if ev else "never"
            cpu = time.process_time() - c0
            for v, (t0, t1) in zip(hist.versions(), run.sessions, strict=True):
                cal = hist.load(v)
                # the truth at the time the calibration's bias refers to: with a drift term, the mean
                # of its poses' times (session-relative); without one, the session's middle
                t_ref = cal.notes.get("accel_bias_drift_t_ref_s")
                truth = drift.truth_at(0.5 * (t0 + t1) if t_ref is None else t0 + float(t_ref))
                assert cal.cov_accel is not None and cal.cov_gyro is not None
                ea = cal.accel_params - truth.accel_params
                eg = cal.gyro_params - truth.gyro_params
                z = np.abs(ea) / np.sqrt(np.diag(cal.cov_accel))
                d = cal.notes.get("accel_bias_drift_per_s")
                nees_a = float(ea @ np.linalg.solve(cal.cov_accel, ea))
                sums.setdefault((order, name), []).append(nees_a)
                table.add_row(str(seed), order, name, str(v), f"{t0:.0f}-{t1:.0f}",
                              f"{nees_a:.1f}",
                              f"{eg @ np.linalg.solve(cal.cov_gyro, eg):.1f}", f"{z.max():.1f}",
                              f"{np.sqrt(cal.cov_accel[5, 5]):.1e}",
                              "-" if d is None else f"{3600 * float(d[2]):.3f}",
                              first, f"{cpu:.0f}")  # fmt: skip
    Console(width=220).print(table)
    summary = Table(title="accelerometer NEES summed over every version")
    for c in ("pose order", "method", "versions", "sum", "99.9 % point of chi-square"):
        summary.add_column(c)
    for (order, name), v in sums.items():
        summary.add_row(
            order, name, str(len(v)), f"{sum(v):.0f}", f"{chdtri(9 * len(v), 0.001):.0f}"
        )
    Console(width=220).print(summary)
    print(f"CPU {time.process_time() - c_all:.0f} s, wall {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
