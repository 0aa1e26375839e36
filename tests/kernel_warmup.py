"""numba's kernels compiled once per test run, in shares: each pytest-xdist worker compiles one share of
the kernel families (a tiny run of each estimator) before its first test.

numba writes a compiled kernel to its on-disk cache and a second process loads it from there, but two
workers that reach the same family at the same moment both compile it (cold, the VIO filter takes about
100 s of CPU, the LiDAR odometry about 45 s). With the families dealt out, each is compiled by one worker
while the other compiles another family, and every later test loads them. On a warm cache a share takes
a few seconds. ``tests/conftest.py`` runs it; without xdist the tests compile what they use as before.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def _command(args: list[str]) -> None:
    """One ``imuslam`` command in this process, into a temporary folder; it must succeed."""
    import tempfile

    from typer.testing import CliRunner

    from imuslam.cli import app

    with tempfile.TemporaryDirectory() as tmp:
        res = CliRunner().invoke(app, [*args, "--out", f"{tmp}/out"])
        if res.exit_code != 0:
            raise RuntimeError(f"warm-up 'imuslam {' '.join(args)}' failed: {res.output}")


def vio() -> None:
    """The VIO's front end (ZNCC tracking, stereo matching) and filter (every VO model runs the same
    kernel): ``imuslam vio`` on one second of the rendered robot."""
    _command(["vio", "sim", "--sim-duration", "1", "--sim-rate", "5"])


def align() -> None:
    """The alignment's Kalman filter: ``imuslam align`` on three seconds of a still IMU."""
    import tempfile

    rng = np.random.default_rng(0)
    n = 300
    rows = np.column_stack([1000.0 + np.arange(n) / 100.0,
                            rng.normal(0.0, 0.02, (n, 3)) + [0.0, 0.0, 9.81],
                            rng.normal(0.0, 0.002, (n, 3))])  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        log = f"{tmp}/imu.txt"
        np.savetxt(log, rows, fmt="%.6f")
        _command(["align", log, "--no-plots"])


def lio() -> None:
    """The LiDAR odometry's front ends (features, direct) and its filter."""
    from imuslam.io.lidarsets import MemoryDataset
    from imuslam.lio.config import ExtrinsicConfig, FrontEndConfig, LioConfig
    from imuslam.lio.pipeline import LioPipeline
    from imuslam.sim.drive import simulate_lidar_drive

    d = simulate_lidar_drive("street", 1.0, seed=11)
    for mode in ("features", "direct"):
        cfg = LioConfig(extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])),  # type: ignore[arg-type]
                        frontend=FrontEndConfig(mode=mode))  # type: ignore[arg-type]  # fmt: skip
        LioPipeline(MemoryDataset(d.scans, d.imu, "sim"), cfg, progress=False).run()


def rwnn() -> None:
    """The RWNN observer's loop."""
    from imuslam.ins.rwnn import run_rwnn

    t = np.arange(0.0, 1.0, 1.0 / 200.0)
    acc = np.tile([0.0, 0.0, 9.80665], (len(t), 1))
    for kind in ("position", "velocity"):
        run_rwnn(t, acc, np.zeros_like(acc), t[::2], np.zeros((len(t[::2]), 3)), kind,
                 np.zeros(3), np.zeros(3), np.eye(3))  # fmt: skip


def slam2d() -> None:
    """The 2D SLAM's scan matching."""
    from imuslam.sim.imu import ImuErrorSpec
    from imuslam.sim.robot2d import simulate_robot2d
    from imuslam.sim.trajectory import SquareLoopCcwCw
    from imuslam.slam2d.pipeline import run_slam2d

    sim = simulate_robot2d(SquareLoopCcwCw(), 3.0, np.random.default_rng(7), ImuErrorSpec.ideal())
    run_slam2d(sim.log)


# each family with its cold compile time on a 2-core machine (CPU seconds; only the shares' balance uses it)
FAMILIES: tuple[tuple[Callable[[], None], float], ...] = (
    (vio, 130.0), (align, 65.0), (lio, 45.0), (rwnn, 45.0), (slam2d, 20.0))  # fmt: skip


def shares(workers: int) -> list[list[Callable[[], None]]]:
    """The families dealt out to ``workers`` workers, longest first, each to the least loaded worker."""
    load = [0.0] * workers
    out: list[list[Callable[[], None]]] = [[] for _ in range(workers)]
    for family, cost in sorted(FAMILIES, key=lambda fc: -fc[1]):
        k = load.index(min(load))
        out[k].append(family)
        load[k] += cost
    return out


def warm_share(worker: int, workers: int) -> None:
    """Compile the families of worker ``worker`` (0-based) of ``workers`` (nothing for one worker)."""
    if workers < 2:
        return
    for family in shares(workers)[worker]:
        family()
