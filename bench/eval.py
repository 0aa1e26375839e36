"""Speed of APE + RPE on a 5000-pose pair, in-process, against evo measured in the same run.

Run: .venv/bin/python bench/eval.py
"""

from __future__ import annotations

import copy
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.eval.metrics import evaluate
from imuslam.geometry import exp, quat_from_matrix
from imuslam.interfaces.trajectory import Trajectory
from imuslam.threads import configure_process


def make_pair(n: int = 5000) -> tuple[Trajectory, Trajectory]:
    rng = np.random.default_rng(0)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    s = np.linspace(0, 20 * np.pi, n)
    p = np.stack([50 * np.cos(s), 30 * np.sin(s), np.sin(3 * s)], axis=1)
    R = exp(np.cumsum(rng.normal(size=(n, 3)) * 0.01, axis=0))
    ref = Trajectory(t, p, R, "ref")
    est = Trajectory(
        t,
        p + np.cumsum(rng.normal(size=(n, 3)) * 0.01, axis=0),
        R @ exp(rng.normal(size=(n, 3)) * 0.01),
        "est",
    )
    return ref, est


def ours(ref: Trajectory, est: Trajectory, align: str) -> float:
    t = time.perf_counter()
    evaluate(ref, est, align, 1, "frames")  # type: ignore[arg-type]
    return time.perf_counter() - t


def evo_time(ref: Trajectory, est: Trajectory, correct_scale: bool) -> float:
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D

    def to_evo(tr: Trajectory) -> PoseTrajectory3D:
        return PoseTrajectory3D(tr.p_w, quat_from_matrix(tr.R_w_b), tr.t_s)

    r, e = to_evo(ref), to_evo(est)
    t = time.perf_counter()
    r2, e2 = sync.associate_trajectories(r, e, max_diff=0.01)
    e2 = copy.deepcopy(e2)
    e2.align(r2, correct_scale=correct_scale)
    for rel in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
        a = metrics.APE(rel)
        a.process_data((r2, e2))
        a.get_all_statistics()
        p = metrics.RPE(rel, delta=1, delta_unit=metrics.Unit.frames)
        p.process_data((r2, e2))
        p.get_all_statistics()
    return time.perf_counter() - t


def main() -> None:
    ref, est = make_pair()
    ours(ref, est, "se3")  # JIT warm-up
    table = Table(title="APE + RPE (translation and rotation), 5000 poses, in-process, best of 3")
    for c in ("alignment", "imuslam [s]", "evo [s]", "speed-up"):
        table.add_column(c, justify="right")
    for align, scale in (("se3", False), ("sim3", True)):
        a = min(ours(ref, est, align) for _ in range(3))
        try:
            b = min(evo_time(ref, est, scale) for _ in range(3))
            table.add_row(align, f"{a:.4f}", f"{b:.4f}", f"{b / a:.0f}x")
        except ImportError:
            table.add_row(align, f"{a:.4f}", "not installed", "-")
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
