"""The results folder of ``imuslam lio``: trajectory.tum, map.ply / map.pcd, config.yaml, scans.csv,
trajectory.png (top view over the map) and, against a reference, metrics.json (ATE / RPE / KITTI drift).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from imuslam.errors import InputError
from imuslam.interfaces import Trajectory
from imuslam.lio.pipeline import LioResult


def write_results(
    result: LioResult, out_dir: str | Path, gt: Trajectory | None = None
) -> dict[str, Any]:
    """The results folder through the one writer (:func:`imuslam.io.results.write_results`, all or
    nothing): trajectory.tum, config.yaml (the resolved configuration), metrics.json (the run's figures
    and, with ``gt``, ATE / RPE / KITTI drift), map.ply, map.pcd, scans.csv and trajectory.png. Returns
    the metrics against ``gt`` (empty without it)."""
    from imuslam.io import results
    from imuslam.io.atomic import write_atomic
    from imuslam.io.pointcloud import write_pcd, write_ply

    metrics: dict[str, Any] = {}
    if gt is not None:
        from imuslam.eval.metrics import KITTI_LENGTHS, evaluate

        res = evaluate(gt, result.trajectory, "se3", 1.0, "m", 0.02, KITTI_LENGTHS)
        metrics = res.to_dict()
    st = result.stats
    run = {
        "scans": len(st),
        "scans_per_s": result.scans_per_s,
        "path_length_m": result.trajectory.path_length,
        "map_points": len(result.map_points),
        "warnings": list(result.warnings),
    }
    if result.online_calibration is not None:
        run["online_calibration"] = result.online_calibration

    def extra(tmp: Path) -> None:
        write_ply(tmp / "map.ply", result.map_points)
        write_pcd(tmp / "map.pcd", result.map_points)
        rows = ["t_ns,n_points,n_dropped,n_used,iterations,n_corr,time_ms"] + [
            f"{s.t_ns},{s.n_points},{s.n_dropped},{s.n_used},{s.iterations},{s.n_corr},{s.time_s * 1e3:.3f}"
            for s in st
        ]
        write_atomic(tmp / "scans.csv", "\n".join(rows) + "\n")
        plot_top_view(result, tmp / "trajectory.png", gt)

    results.write_results(
        out_dir, config=result.config.resolved(), metrics={**metrics, "run": run},
        trajectories={"trajectory": result.trajectory}, extra=extra,
    )  # fmt: skip
    return metrics


def plot_top_view(result: LioResult, path: Path, gt: Trajectory | None = None) -> None:
    """Top view (x-y) of the map points and the trajectory (PNG)."""
    from matplotlib.figure import Figure

    from imuslam.io.figures import save_figure

    fig = Figure(figsize=(8, 7))
    ax = fig.add_subplot(1, 1, 1)
    m, p = result.map_points, result.trajectory.p_w
    if gt is not None:  # everything in the reference frame, by the SE(3) alignment of the estimate
        from imuslam.eval.align import align
        from imuslam.eval.associate import associate

        try:
            r, e = associate(gt, result.trajectory, 0.02)
            s, R, t = align(r, e, "se3")
            m, p = s * m @ R.T + t, s * p @ R.T + t
            ax.plot(gt.p_w[:, 0], gt.p_w[:, 1], "k--", lw=0.8, label="ground truth")
        except InputError:
            pass
    if len(m):
        z = m[:, 2]
        sel = z > np.percentile(z, 10) + 0.3  # drop the ground for a readable view
        ax.scatter(m[sel, 0], m[sel, 1], s=0.2, c="0.6", lw=0, rasterized=True)
    ax.plot(p[:, 0], p[:, 1], "C1-", lw=1.2, label="imuslam lio")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right")
    save_figure(fig, path)  # type: ignore[arg-type]
