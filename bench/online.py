"""Per-sample cost of the online calibrator outside the solve (target < 50 us per sample, so that a
Raspberry Pi 4 keeps up at 200 Hz), and of a whole simulated gimbal session.

Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python bench/online.py  (the joint default, then tedaldi;
wall time per sample, wall and CPU time of the solve)
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.imu.online import OnlineCalibrator, OnlineConfig
from imuslam.sim.multipose import GimbalImuStream, sphere_plan_deg
from imuslam.threads import configure_process


def main() -> None:
    for method in ("joint", "tedaldi"):  # the online default, then the two steps
        run(method)


def run(method: str) -> None:
    rng = np.random.default_rng(0)
    stream = GimbalImuStream(rng)
    cfg = OnlineConfig()  # seed 000: T_init 50 s
    cfg.calibration.method = method  # type: ignore[assignment]
    cal = OnlineCalibrator(sphere_plan_deg(40), stream.command, cfg)
    cal.start_session(0)
    t_step = 0.0
    n_step = 0
    t_solve = c_solve = 0.0
    while cal.phase != "monitor":
        t, a, w = stream.read(100)
        for i in range(100):
            before = cal.phase
            t0, c0 = time.perf_counter(), time.process_time()
            cal.step(int(t[i]), a[i], w[i])
            dt = time.perf_counter() - t0
            if before == "hold" and cal.phase == "monitor":
                t_solve, c_solve = dt, time.process_time() - c0
            else:
                t_step += dt
                n_step += 1
            if cal.phase == "monitor":
                break
    t, a, w = stream.read(20_000)
    t0 = time.perf_counter()
    for i in range(len(t)):
        cal.step(int(t[i]), a[i], w[i])
    t_mon = (time.perf_counter() - t0) / len(t)
    table = Table(
        title="Online calibrator, per-sample cost measured on this machine (target < 50 us)"
    )
    for c in ("phase", "samples", "per sample [us]", "note"):
        table.add_column(c, justify="right")
    table.add_row(
        "session (init, move, hold)",
        f"{n_step:,}",
        f"{1e6 * t_step / n_step:.1f}",
        "detector + buffer + state",
    )
    table.add_row(
        "solve (once per session)",
        "1",
        f"{1e6 * t_solve:,.0f}",
        f"offline solver on the session ({cfg.calibration.method}; CPU {1e6 * c_solve:,.0f} us,"
        " 5-fold CV included)",
    )
    table.add_row("monitor", f"{len(t):,}", f"{1e6 * t_mon:.1f}", "detector + drift statistics")
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
