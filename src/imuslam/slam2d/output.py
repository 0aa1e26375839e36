"""What a 2D SLAM run's results folder holds besides the common files (``Slam2dPipeline.save``): the
summary written as metrics.json, the per-scan poses as a trajectory, map.pgm + map.yaml (ROS map_server)
and map.png (the map with the trajectory)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces import Trajectory
from imuslam.io.laserlog import LaserLog
from imuslam.io.mapfiles import write_map_server
from imuslam.slam2d.grid import ProbabilityGrid
from imuslam.slam2d.records import Slam2dResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure

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


def view_limits(
    grid: ProbabilityGrid, xy: FloatArray, share: float = 0.99, margin: float = 1.0
) -> tuple[float, float, float, float]:
    """``(x0, x1, y0, y1)`` of map.png's view, m: the positions ``xy`` (N, 2) (trajectory, reference) and
    the central ``share`` of the occupied cells in x and in y, plus ``margin``. The free space a
    long ray crosses (a 20 m beam through a door) does not widen it, so the walls keep their size."""
    occ = grid.known() & (grid.prob > 0.5)
    r = grid.params.resolution
    pts = [np.asarray(xy, dtype=float).reshape(-1, 2)]
    if occ.any():
        iy, ix = np.nonzero(occ)
        cells = np.column_stack([grid.x0 + (ix + 0.5) * r, grid.y0 + (iy + 0.5) * r])
        q = 50.0 * (1.0 - share)
        pts.append(np.percentile(cells, [q, 100.0 - q], axis=0))
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0) - margin, allp.max(axis=0) + margin
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def map_figure(
    grid: ProbabilityGrid,
    result: Slam2dResult,
    title: str,
    reference_xy: FloatArray | None = None,
) -> Figure:
    """The occupancy map (grey: unknown) with the SLAM trajectory, its start, the nodes where loop
    closures were found and, if given, the reference positions in the map's frame (N, 2), viewed over
    the occupied extent (:func:`view_limits`)."""
    from matplotlib.figure import Figure

    pr, known, x0, y0 = grid.cropped_known()
    prob = np.where(known, pr, 0.5)
    r = grid.params.resolution
    H, W = prob.shape
    P = result.pose_xy_yaw
    ref = np.asarray(reference_xy, dtype=float).reshape(-1, 2) if reference_xy is not None else None
    has_ref = ref is not None and len(ref) > 0
    shown = np.vstack([P[:, :2], ref]) if ref is not None and has_ref else P[:, :2]
    vx0, vx1, vy0, vy1 = view_limits(grid, shown)
    fig = Figure(figsize=(8, 8 * (vy1 - vy0) / max(vx1 - vx0, 1e-9) + 0.5))
    ax = fig.add_subplot(111)
    ax.imshow(1.0 - prob, cmap="gray", origin="lower", vmin=0, vmax=1,
              extent=(x0, x0 + W * r, y0, y0 + H * r))  # fmt: skip
    if ref is not None and has_ref:
        ax.plot(
            ref[:, 0], ref[:, 1], "-", color="tab:orange", lw=0.7, label="reference (SE(2) aligned)"
        )
    ax.plot(P[:, 0], P[:, 1], "-", color="tab:blue", lw=0.7, label="SLAM")
    if result.loops:
        nodes = [
            result.node_scans[c.node] for c in result.loops[:: max(1, len(result.loops) // 300)]
        ]
        ax.plot(P[nodes, 0], P[nodes, 1], ".", color="tab:red", ms=3, ls="none",
                label=f"loop closure ({len(result.loops)})")  # fmt: skip
    ax.plot(P[0, 0], P[0, 1], "o", color="tab:green", ms=5, label="start")
    ax.set_xlim(vx0, vx1)
    ax.set_ylim(vy0, vy1)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="upper right", fontsize=8)
    return fig


def write_maps(
    out: Path, grid: ProbabilityGrid, result: Slam2dResult, reference_xy: FloatArray | None = None
) -> None:
    """map.pgm / map.yaml (ROS map_server) and map.png (the map with the trajectory and the reference
    positions ``reference_xy`` in the map's frame, if given) into ``out``."""
    from imuslam.io.figures import save_figure

    pr, known, x0, y0 = grid.cropped_known()
    write_map_server(out, pr, known, x0, y0, grid.params.resolution)
    save_figure(map_figure(grid, result, Path(result.source).name, reference_xy), out / "map.png")
