"""Speed of the multi-position calibration on the imu_tk xsens log (51,175 samples, sweep k = 2..10 + gyro).

The comparison with imu_tk's C++, timed in the same run, is bench/calibrate_vs_imutk.py (it builds imu_tk
from source). Run: .venv/bin/python bench/calibrate.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.io.load import load_imu
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg
from imuslam.threads import configure_process

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "imu_tk_xsens"


def best_of(fn, n: int = 5) -> tuple[float, object]:  # type: ignore[no-untyped-def]
    times, out = [], None
    for _ in range(n):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main() -> None:
    table = Table(title="Multi-position calibration, in-process (best of 5, after JIT warm-up)")
    for c in (
        "log",
        "samples",
        "load [s]",
        "calibrate [s]",
        "accel [s]",
        "gyro [s]",
    ):
        table.add_column(c, justify="right")
    if DATA.is_dir():
        t_load, log = best_of(lambda: load_imu(DATA / "xsens_acc.mat", DATA / "xsens_gyro.mat"), 3)
        cfg = CalibrationConfig(g=9.81744, bias_sign="minus")
        calibrate(log, cfg)  # compile
        t_cal, res = best_of(lambda: calibrate(log, cfg))
        table.add_row("imu_tk xsens", str(len(log)), f"{t_load:.3f}", f"{t_cal:.3f}",
                      f"{res.timings_s['accel']:.3f}", f"{res.timings_s['gyro']:.3f}")  # type: ignore[attr-defined]  # fmt: skip
    rng = np.random.default_rng(0)
    sim = simulate_multipose(sphere_plan_deg(40, rng), rng)
    t_cal, res = best_of(lambda: calibrate(sim.log, CalibrationConfig()))
    table.add_row("simulated 40 poses", str(len(sim.log)), "-", f"{t_cal:.3f}",
                  f"{res.timings_s['accel']:.3f}", f"{res.timings_s['gyro']:.3f}")  # type: ignore[attr-defined]  # fmt: skip
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
