"""The results folder of a 2D SLAM run: trajectory.tum (one pose per scan, the log's own stamps),
map.pgm + map.yaml (ROS map_server), map.png (the map with the trajectory), config.yaml, summary.json."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from imuslam.io.atomic import write_atomic
from imuslam.io.laserlog import LaserLog
from imuslam.io.mapfiles import write_map_server
from imuslam.slam2d.grid import ProbabilityGrid
from imuslam.slam2d.slam import Slam2dResult

FloatArray = NDArray[np.float64]


def tum_text(t_ns: NDArray[np.int64], xy_yaw: FloatArray) -> str:
    """TUM lines ``t x y z qx qy qz qw`` for planar poses (z = 0, rotation about z)."""
    whole = t_ns // 1_000_000_000
    frac = t_ns - whole * 1_000_000_000
    half = xy_yaw[:, 2] / 2
    lines = [
        f"{w}.{f:09d} {x:.6f} {y:.6f} 0 0 0 {qz:.9f} {qw:.9f}"
        for w, f, x, y, qz, qw in zip(
            whole, frac, xy_yaw[:, 0], xy_yaw[:, 1], np.sin(half), np.cos(half), strict=True
        )
    ]
    return "# t x y z qx qy qz qw\n" + "\n".join(lines) + "\n"


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


def write_outputs(
    out: Path, log_: LaserLog, result: Slam2dResult, grid: ProbabilityGrid, wall_s: float,
    metrics: dict[str, Any] | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Write every file into ``out`` (a temporary folder renamed by the caller on success)."""
    from imuslam.io.figures import save_figure

    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "trajectory.tum", tum_text(result.t_ns, result.pose_xy_yaw))
    pr, known, x0, y0 = grid.cropped_known()
    write_map_server(out, pr, known, x0, y0, grid.params.resolution)
    save_figure(map_figure(grid, result, Path(result.source).name), out / "map.png")
    write_atomic(out / "config.yaml", yaml.safe_dump(result.config.model_dump(), sort_keys=False))
    s = summary(result, log_, wall_s)
    if metrics:
        s["metrics"] = metrics
    write_atomic(out / "summary.json", json.dumps(s, indent=2, default=float) + "\n")
    return s
