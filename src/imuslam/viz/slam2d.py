"""The 2D SLAM in a recording: per scan (timelines ``sensor_time``, ``scan``) the body pose
``world/body`` (local SLAM), its hits ``world/body/scan``, the match score ``scan/match_score``; every
``grid_every`` scans the growing submaps ``world/submaps/<k>`` (occupancy grids placed at their global
pose); the loop edges ``world/loops`` (node to submap origin) as they are added; at the end (static) the
trajectory of trajectory.tum ``world/trajectory``, the map of map.pgm / map.yaml ``world/map`` and the
optimised loop edges ``world/loop_edges``. Grids use ROS OccupancyGrid values (0 free ... 100
occupied, 255 unknown), rows of increasing y from the lower-left corner."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from imuslam.viz.recording import set_time

if TYPE_CHECKING:
    from imuslam.slam2d.pipeline import Slam2dRun, Slam2dStep
    from imuslam.slam2d.slam import Slam2d

FloatArray = NDArray[np.float64]


def pose3(xy_yaw: FloatArray) -> tuple[FloatArray, FloatArray]:
    """A planar pose (3,) as a translation (3,) and a rotation matrix (3, 3) about z."""
    c, s = np.cos(xy_yaw[2]), np.sin(xy_yaw[2])
    return np.array([xy_yaw[0], xy_yaw[1], 0.0]), np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def occupancy_from_pgm(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """map_saver's image (rows = decreasing y; 0 occupied, 254 free, 205 unknown) as OccupancyGrid
    values (rows = increasing y; 100, 0, 255)."""
    occ = np.full(img.shape, 255, np.uint8)
    occ[img == 0] = 100
    occ[img == 254] = 0
    return np.ascontiguousarray(occ[::-1])


def log_grid(rr: Any, rec: Any, path: str, occ: NDArray[np.uint8], res: float, x0: float, y0: float,
             pose: FloatArray | None = None, static: bool = False) -> None:  # fmt: skip
    """An occupancy grid (H, W) whose cell (0, 0) has its lower-left corner at (x0, y0), m, in the
    frame ``pose`` (x, y, yaw) places in the world (None: the world's)."""
    p, R = pose3(np.zeros(3) if pose is None else pose)
    h, w = occ.shape
    rec.log(path, rr.GridMap(
        data=np.ascontiguousarray(occ).tobytes(),
        format=rr.components.ImageFormat(width=w, height=h, color_model="L", channel_datatype="U8"),
        cell_size=res, translation=p + R @ np.array([x0, y0, 0.0]),
        rotation_axis_angle=rr.RotationAxisAngle(axis=[0, 0, 1], radians=float(np.arctan2(R[1, 0], R[0, 0]))),
        colormap=rr.components.Colormap.RvizMap,
    ), static=static)  # fmt: skip


def loop_strips(slam: Slam2d) -> list[FloatArray]:
    """Each loop constraint as a segment from its node to its submap's origin, global frame, z = 0."""
    out = []
    for c in slam.loops:
        a, b = slam.node_global[c.node], slam.submap_global(c.submap)
        out.append(np.array([[a[0], a[1], 0.0], [b[0], b[1], 0.0]]))
    return out


class Slam2dLogger:
    """The observer of :meth:`imuslam.slam2d.pipeline.Slam2dPipeline.run` writing to ``rec``. The
    per-scan rows go out in batches of ``grid_every`` scans (as columns: one call per entity instead of
    one per scan, a third of the run's time otherwise), so a live viewer trails by at most that many."""

    def __init__(self, rec: Any, grid_every: int = 20) -> None:
        import rerun as rr

        self.rr, self.rec, self.grid_every = rr, rec, grid_every
        self.n_loops = 0
        self.n_submaps = 0
        self._rows: list[tuple[int, int, FloatArray, FloatArray, float]] = []
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("world/body", rr.TransformAxes3D(0.3), static=True)
        rec.log(
            "world/body/scan",
            rr.Points3D.from_fields(radii=0.02, colors=[230, 60, 60]),
            static=True,
        )

    def flush(self) -> None:
        """Send the buffered scans' poses, hits and match scores as columns."""
        from imuslam.viz.recording import time_column

        rr, rec, rows = self.rr, self.rec, self._rows
        if not rows:
            return
        t = np.array([r[0] for r in rows], np.int64)
        k = np.array([r[1] for r in rows], np.int64)
        P = np.array([r[2] for r in rows])
        c, s = np.cos(P[:, 2]), np.sin(P[:, 2])
        R = np.zeros((len(P), 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
        xyz = np.column_stack([P[:, :2], np.zeros(len(P))])
        idx = [time_column(rr, t), rr.TimeColumn("scan", sequence=k)]
        rec.send_columns("world/body", indexes=idx,
                         columns=rr.Transform3D.columns(translation=xyz, mat3x3=R))  # fmt: skip
        pts = [r[3] for r in rows]
        allp = np.concatenate(pts) if pts else np.zeros((0, 2))
        allp = np.column_stack([allp, np.zeros(len(allp))])
        rec.send_columns("world/body/scan", indexes=idx,
                         columns=rr.Points3D.columns(positions=allp).partition([len(p) for p in pts]))  # fmt: skip
        score = np.array([r[4] for r in rows])
        ok = np.isfinite(score)
        if ok.any():
            rec.send_columns("scan/match_score", indexes=[time_column(rr, t[ok]), rr.TimeColumn("scan", sequence=k[ok])],
                             columns=rr.Scalars.columns(scalars=score[ok]))  # fmt: skip
        rows.clear()

    def __call__(self, step: Slam2dStep) -> None:
        rr, rec, slam = self.rr, self.rec, step.slam
        score = slam.scan_score[-1] if slam.scan_score else float("nan")
        self._rows.append((step.t_ns, step.index, step.pose_xy_yaw, step.points_b, score))
        grids = step.index % self.grid_every == 0 or len(slam.submaps) != self.n_submaps
        loops = len(slam.loops) != self.n_loops
        if len(self._rows) < self.grid_every and not grids and not loops:
            return
        self.flush()
        set_time(rec, step.t_ns, step.index)
        if grids:
            self.n_submaps = len(slam.submaps)
            res = slam.params.resolution
            for s in slam.active:
                g = slam.submaps[s].grid
                occ = np.where(g.known(), np.round(g.prob * 100), 255).astype(np.uint8)
                log_grid(rr, rec, f"world/submaps/{s}", occ, res, g.x0, g.y0, slam.submap_global(s))
        if loops:
            self.n_loops = len(slam.loops)
            rec.log("world/loops", rr.LineStrips3D(loop_strips(slam), colors=[40, 160, 40]))
            rec.log("scan/loops", rr.Scalars(float(self.n_loops)))

    def finish(self, run: Slam2dRun) -> None:
        """The final trajectory and map (static), as trajectory.tum and map.pgm / map.yaml hold them,
        and each loop edge between its node's scan and its submap's first scan, optimised poses."""
        from imuslam.io.mapfiles import occupancy_image

        self.flush()
        rr, rec = self.rr, self.rec
        P = run.result.pose_xy_yaw
        xyz = np.column_stack([P[:, :2], np.zeros(len(P))])
        rec.log("world/trajectory", rr.LineStrips3D([xyz], colors=[255, 140, 0]), static=True)
        pr, known, x0, y0 = run.grid.cropped_known()
        occ = occupancy_from_pgm(occupancy_image(pr, known))
        log_grid(rr, rec, "world/map", occ, run.grid.params.resolution, x0, y0, static=True)
        ns = run.result.node_scans
        edges = [xyz[[ns[c.node], ns[c.anchor]]] for c in run.result.loops]
        rec.log("world/loop_edges", rr.LineStrips3D(edges, colors=[40, 160, 40]), static=True)
