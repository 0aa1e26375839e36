"""What a 2D SLAM run's results folder holds besides the common files (``Slam2dPipeline.save``): the
summary written as metrics.json, the per-scan poses as a trajectory, map.pgm + map.yaml (ROS map_server)
and map.png (the map with the trajectory)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces import Trajectory
from imuslam.io.laserlog import LaserLog
from imuslam.io.mapfiles import write_map_server
from imuslam.slam2d.grid import ProbabilityGrid
from imuslam.slam2d.records import Slam2dResult

FloatArray = NDArray[np.float64]


def planar_trajectory(result: Slam2dResult) -> Trajectory:
    """The per-scan planar poses as a trajectory (z = 0, rotation about z), the log's own stamps."""
    P = result.pose_xy_yaw
    c, sn = np.cos(P[:, 2]), np.sin(P[:, 2])
    R = np.zeros((len(P), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -sn, sn, c, 1.0
    p = np.column_stack([P[:, :2], np.zeros(len(P))])
    return Trajectory(result.t_ns, p, R, result.source or "map2d")


def summary(result: Slam2dResult, log_: LaserLog, wall_s: float) -> dict[str, Any]:
    P = result.pose_xy_yaw
    return {
        "source": result.source,
        "scans": len(log_),
        "log_duration_s": log_.duration_s,
        "path_length_m": float(np.sum(np.hypot(*np.diff(P[:, :2], axis=0).T))),
        "nodes": len(result.node_scans),
        "submaps": result.n_submaps,
        "loop_constraints": len(result.loops),
        "loop_searches": result.loops_searched,
        # matches above the minimum score: all, rejected without a distinct peak, rejected as
        # inconsistent with their neighbours' (the rest are the loop constraints)
        **{k: int(v) for k, v in result.extra.items() if k.startswith("loop_")},
        "mean_match_score": result.mean_match_score,
        "wall_time_s": wall_s,
        "faster_than_real_time": log_.duration_s / wall_s if wall_s > 0 else float("inf"),
        "timing_s": result.timing_s,
        "warnings": result.warnings,
    }


def map_figure(grid: ProbabilityGrid, result: Slam2dResult, title: str):  # type: ignore[no-untyped-def]
    from matplotlib.figure import Figure

    pr, known, x0, y0 = grid.cropped_known()
    prob = np.where(known, pr, 0.5)
    r = grid.params.resolution
    H, W = prob.shape
    fig = Figure(figsize=(8, 8 * H / max(W, 1) + 0.5))
    ax = fig.add_subplot(111)
    ax.imshow(1.0 - prob, cmap="gray", origin="lower", vmin=0, vmax=1,
              extent=(x0, x0 + W * r, y0, y0 + H * r))  # fmt: skip
    P = result.pose_xy_yaw
    ax.plot(P[:, 0], P[:, 1], "-", color="tab:blue", lw=0.7, label="SLAM")
    for c in result.loops[:: max(1, len(result.loops) // 300)]:
        n = result.node_scans[c.node]
        ax.plot(P[n, 0], P[n, 1], ".", color="tab:red", ms=2)
    ax.plot(P[0, 0], P[0, 1], "o", color="tab:green", ms=5, label="start")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title(title)
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    return fig


def write_maps(out: Path, grid: ProbabilityGrid, result: Slam2dResult) -> None:
    """map.pgm / map.yaml (ROS map_server) and map.png (the map with the trajectory) into ``out``."""
    from imuslam.io.figures import save_figure

    pr, known, x0, y0 = grid.cropped_known()
    write_map_server(out, pr, known, x0, y0, grid.params.resolution)
    save_figure(map_figure(grid, result, Path(result.source).name), out / "map.png")
