"""Throughput of the strapdown mechanisation and of the alignment filters (targets: >= 1e6 samples/s
for the strapdown, >= 50k IMU samples/s for each filter; pyins' EKF spends about 3 ms per sample).

Run: .venv/bin/python bench/strapdown.py
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.ins.align import Aiding, run_alignment
from imuslam.ins.kf import KfNoise
from imuslam.ins.rwnn import run_rwnn
from imuslam.ins.strapdown import integrate
from imuslam.interfaces.nav import NavState
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.trajectory import Handheld
from imuslam.threads import configure_process


def main() -> None:
    traj = Handheld()
    log, tr = simulate_imu(traj, 300.0, np.random.default_rng(0), ImuErrorSpec.bwt901cl(), 400.0)
    init = NavState(tr.p_w[0], tr.vel_w[0], tr.R_w_i[0])
    ta = np.arange(0.1, 300.0, 0.1)
    aid = Aiding(ta, "position", traj.state(ta).p_w, 0.01)
    table = Table(title=f"Throughput on {len(log):,} samples (400 Hz, 300 s), after JIT warm-up")
    for c in ("stage", "samples/s", "time [s]"):
        table.add_column(c, justify="right")
    runs = {
        "strapdown": lambda: integrate(log.t_s, log.accel, log.gyro, init),
        "KF (15 states, position 10 Hz)": lambda: run_alignment(log, aid, init, "kf", KfNoise()),
        "STKF": lambda: run_alignment(log, aid, init, "stkf", KfNoise()),
        "RWNN observer": lambda: run_rwnn(
            log.t_s, log.accel, log.gyro, ta, aid.values, "position", init.p_n, init.v_n, init.R_n_b
        ),  # fmt: skip
    }
    for name, fn in runs.items():
        fn()  # compile
        t = time.perf_counter()
        fn()
        dt = time.perf_counter() - t
        table.add_row(name, f"{len(log) / dt:,.0f}", f"{dt:.3f}")
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
