"""Simulator speed: 60 s of a 16-beam LiDAR at 10 Hz (600 scans x 28,800 rays) in the urban block, and the
IMU simulation. Target: the LiDAR in under 60 s on 2 cores. Run: .venv/bin/python bench/sim.py [seconds]
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.lidar import Lidar3dConfig, simulate_lidar3d_scan
from imuslam.sim.trajectory import CarLoop
from imuslam.sim.world import urban_block
from imuslam.threads import configure_process


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    world, traj, cfg = urban_block(), CarLoop(), Lidar3dConfig()
    rng = np.random.default_rng(0)

    def pose(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        st = traj.state(t)
        return st.R_w_b, st.p_w + st.R_w_b @ np.array([0.0, 0.0, 0.2])

    simulate_lidar3d_scan(world, pose, 0.0, cfg, rng)  # JIT warm-up
    n = int(seconds * cfg.rate_hz)
    t = time.perf_counter()
    pts = sum(
        len(simulate_lidar3d_scan(world, pose, k / cfg.rate_hz, cfg, rng).points_l)
        for k in range(n)
    )
    t_lidar = time.perf_counter() - t
    rays = n * cfg.columns * len(cfg.elevations_deg)
    t = time.perf_counter()
    log, _ = simulate_imu(traj, seconds, rng, ImuErrorSpec.bwt901cl(), 200.0)
    t_imu = time.perf_counter() - t
    table = Table(title=f"Simulation of {seconds:g} s ({len(world)} rectangles in the world)")
    for c in ("sensor", "items", "time [s]", "rate", "real-time factor"):
        table.add_column(c, justify="right")
    table.add_row("VLP-16 10 Hz", f"{n} scans, {rays:,} rays, {pts:,} points", f"{t_lidar:.2f}",
                  f"{rays / t_lidar / 1e6:.2f} Mrays/s", f"{seconds / t_lidar:.1f}x")  # fmt: skip
    table.add_row("IMU 200 Hz", f"{len(log):,} samples", f"{t_imu:.3f}", f"{len(log) / t_imu / 1e6:.2f} Msamples/s",
                  f"{seconds / t_imu:.0f}x")  # fmt: skip
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
