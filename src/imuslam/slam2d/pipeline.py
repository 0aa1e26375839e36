"""The 2D SLAM over a laser log: ``Slam2dPipeline(log, config, imu=...).run() -> Slam2dResult``, then
``save(out)``; the log gives its IMU by ``imu()``, which ``imu=`` overrides (e.g. after calibration).

The pipeline turns the log into what the estimator (:class:`imuslam.slam2d.slam.Slam2d`) reads per scan:
the scan's points in the body frame with their firing times, the motion prior from the wheel odometry and
the IMU's yaw rate, the IMU's tilt, and whether a re-localisation may search the full angular window;
``render_map`` inserts every scan at the estimated poses into the output map.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import EstimatorError
from imuslam.interfaces.imu import ImuLog
from imuslam.io.laserlog import LaserLog
from imuslam.slam2d import pose2
from imuslam.slam2d.config import Slam2dConfig
from imuslam.slam2d.grid import GridParams, ProbabilityGrid
from imuslam.slam2d.records import Slam2dResult
from imuslam.slam2d.slam import Slam2d

FloatArray = NDArray[np.float64]


def scan_points(log_: LaserLog, cfg: Slam2dConfig, with_time: bool = False) -> list[FloatArray]:
    """Per scan, the valid hit points (P, 2) in the body frame, thinned by the voxel filter; with
    ``with_time`` (P, 3): the third column the beam's firing time after the scan's stamp, s."""
    ang = log_.angles
    ca, sa = np.cos(ang), np.sin(ang)
    r = log_.ranges.astype(float)
    ok = np.isfinite(r) & (r >= cfg.min_range) & (r <= cfg.max_range)
    T = log_.T_b_l
    c, s = np.cos(T[2]), np.sin(T[2])
    lx, ly = np.where(ok, r * ca, 0.0), np.where(ok, r * sa, 0.0)
    bx, by = c * lx - s * ly + T[0], s * lx + c * ly + T[1]
    out: list[FloatArray] = []
    v = cfg.voxel_size
    for k in range(len(log_)):
        m = ok[k]
        p = np.column_stack([bx[k, m], by[k, m]])
        if with_time:
            p = np.column_stack([p, np.flatnonzero(m) * log_.time_increment])
        if v > 0 and len(p) > 1:
            key = np.floor(p[:, :2] / v).astype(np.int64)
            _, first = np.unique(key[:, 0] * 1_000_003 + key[:, 1], return_index=True)
            p = p[np.sort(first)]
        out.append(p)
    return out


def imu_yaw_and_tilt(log_: LaserLog, imu: ImuLog | None) -> tuple[FloatArray, FloatArray] | None:
    """Integrated yaw (rad) of ``imu`` at each scan time of ``log_`` about the gravity direction, and the
    tilt of the IMU's z axis from gravity (deg) at each scan (the accelerometer averaged over 1 s); None
    without an IMU."""
    if imu is None or len(imu) < 2:
        return None
    t = (imu.t_ns - log_.t_ns[0]).astype(float) * 1e-9
    acc = imu.accel * (9.80665 if imu.accel_unit == "g" else 1.0)
    gyr = imu.gyro * (np.pi / 180 if imu.gyro_unit == "deg/s" else 1.0)
    dt_med = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
    w = max(1, int(round(1.0 / max(dt_med, 1e-4))))
    kern = np.ones(w) / w
    up = np.column_stack([np.convolve(acc[:, i], kern, mode="same") for i in range(3)])
    up /= np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-9)
    rate = np.einsum("ij,ij->i", gyr, up)  # rate about the up direction
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    ts = (log_.t_ns - log_.t_ns[0]).astype(float) * 1e-9
    tilt = np.rad2deg(np.arccos(np.clip(up[:, 2], -1, 1)))
    return np.interp(ts, t, yaw), np.interp(ts, t, tilt)


def _wide_search_scans(log_: LaserLog, cfg: Slam2dConfig, odometry: bool) -> NDArray[np.bool_]:
    """(N,) True at the scans whose wide search gets the full angular window (``MatcherConfig.recovery_when``)."""
    n = len(log_)
    m = cfg.matcher
    if m.recovery_when == "always" or not odometry:
        return np.ones(n, bool)
    start = np.zeros(n, bool)
    if log_.odom_jumped is not None:
        start |= log_.odom_jumped
    gap = np.diff(log_.t_ns).astype(float) * 1e-9 >= m.recovery_gap_s
    start[1:] |= gap
    # each suspect scan opens a window of recovery_suspect_scans scans (itself included)
    opened = np.cumsum(start)
    closed = np.concatenate(
        [np.zeros(m.recovery_suspect_scans, np.int64), opened[: -m.recovery_suspect_scans]]
    )
    return (opened - closed[:n]) > 0


@dataclass
class Slam2dStep:
    """What an observer of :meth:`Slam2dPipeline.run` receives after each scan: its index and stamp
    (ns), its local-SLAM pose (3,) x, y (m), yaw (rad), its hit points (P, 2) in the body frame, m,
    and the estimator (its submaps, nodes and loop constraints so far, read-only)."""

    index: int
    t_ns: int
    pose_xy_yaw: FloatArray
    points_b: FloatArray
    slam: Slam2d


@dataclass
class Slam2dRun:
    """A run's result with what its results folder shows: the output map and the wall time, s."""

    result: Slam2dResult
    grid: ProbabilityGrid
    wall_s: float


class Slam2dPipeline:
    """Drives :class:`Slam2d` over every scan of ``log_`` (``run``) and writes the results folder
    (``save``: trajectory.tum, map.pgm / map.yaml, map.png, config.yaml, metrics.json); ``imu``
    overrides the log's IMU (e.g. after calibration), as the LIO and VIO pipelines take it."""

    def __init__(
        self, log_: LaserLog, cfg: Slam2dConfig | None = None, imu: ImuLog | None = None
    ) -> None:
        self.log = log_
        self.cfg = cfg or Slam2dConfig()
        self.imu = imu if imu is not None else log_.imu()

    def run(
        self,
        progress: Callable[[int], None] | None = None,
        observer: Callable[[Slam2dStep], None] | None = None,
    ) -> Slam2dResult:
        """The SLAM over every scan; ``progress(k)`` is called after scan k, ``observer`` sees each
        scan's :class:`Slam2dStep`."""
        slam = Slam2d(self.cfg)
        try:
            return self._run(slam, progress, observer)
        except EstimatorError as exc:
            raise EstimatorError(f"{self.log.source}: {exc}") from None
        finally:
            slam.close()

    def _run(
        self,
        slam: Slam2d,
        progress: Callable[[int], None] | None,
        observer: Callable[[Slam2dStep], None] | None = None,
    ) -> Slam2dResult:
        log_, cfg = self.log, self.cfg
        pts_all = scan_points(log_, cfg, with_time=True)
        deskew = log_.time_increment > 0
        odo = log_.odom_xy_yaw if (cfg.use_odometry and log_.odom_xy_yaw is not None) else None
        imu = imu_yaw_and_tilt(log_, self.imu) if cfg.use_imu else None
        t_s = (log_.t_ns - log_.t_ns[0]).astype(float) * 1e-9
        slam.sensor_b = log_.T_b_l[None, :2].copy()
        wide_ok = _wide_search_scans(log_, cfg, odo is not None)
        for k in range(len(log_)):
            step = dyaw = dt = None
            if k > 0:
                step = pose2.between(odo[k - 1], odo[k]) if odo is not None else None
                if imu is not None:
                    dyaw = float(pose2.wrap(imu[0][k] - imu[0][k - 1]))
                if deskew:
                    dt = max(float(log_.t_ns[k] - log_.t_ns[k - 1]) * 1e-9, 1e-3)
            tilted = imu is not None and imu[1][k] > cfg.max_tilt_deg
            est = slam.add_scan(pts_all[k], t_s[k], step, dyaw, dt, bool(tilted), bool(wide_ok[k]))
            if observer is not None:
                observer(Slam2dStep(k, int(log_.t_ns[k]), est, pts_all[k][:, :2], slam))
            if progress is not None:
                progress(k)
        slam.finish()
        warnings = dict(log_.warnings)
        c = slam.counts
        for key, text in (("empty", "scans with fewer than 3 valid readings (pose from the prior)"),
                          ("recovered", "scans re-localised by the wide search (the prior was off)"),
                          ("poor", "scans far below the run's match score, not inserted"),
                          ("tilt", "scans rejected by the IMU tilt (pose from the prior)")):  # fmt: skip
            if c[key]:
                warnings[text] = c[key]
        return Slam2dResult(
            log_.t_ns.copy(), slam.scan_poses(), np.array(slam.scan_local),
            None if log_.odom_xy_yaw is None else log_.odom_xy_yaw.copy(),
            np.array(slam.node_scan), len(slam.submaps), slam.loops, slam.loops_searched,
            dict(slam.timing), warnings, float(np.mean(slam.scores)) if slam.scores else 0.0, cfg,
            log_.source, c["tilt"], match_score=np.array(slam.scan_score),
            extra={f"loop_{k}": float(v) for k, v in slam.loop_stats.items()},
        )  # fmt: skip

    def run_and_render(
        self,
        progress: Callable[[int], None] | None = None,
        observer: Callable[[Slam2dStep], None] | None = None,
    ) -> Slam2dRun:
        """``run``, then the output map at the estimated poses; the wall time covers both."""
        t0 = time.perf_counter()
        res = self.run(progress, observer)
        grid = render_map(self.log, res.pose_xy_yaw, self.cfg)
        return Slam2dRun(res, grid, time.perf_counter() - t0)

    def save(
        self,
        run: Slam2dRun,
        out: str | Path,
        metrics: dict[str, Any] | None = None,
        reference_xy: FloatArray | None = None,
    ) -> dict[str, Any]:
        """The results folder through the one writer (:func:`imuslam.io.results.write_results`):
        trajectory.tum, config.yaml, metrics.json (the run's summary, with ``metrics`` against a
        reference), map.pgm / map.yaml and map.png (with ``reference_xy`` (N, 2), the reference's
        positions in the map's frame, drawn). Returns the summary."""
        from imuslam.io.results import write_results
        from imuslam.slam2d.output import planar_trajectory, summary, write_maps

        s = summary(run.result, self.log, run.wall_s)
        if metrics:
            s["metrics"] = metrics
        write_results(
            out, config=run.result.config, metrics=s,
            trajectories={"trajectory": planar_trajectory(run.result)},
            extra=lambda d: write_maps(d, run.grid, run.result, reference_xy),
        )  # fmt: skip
        return s


def run_slam2d(
    log_: LaserLog,
    cfg: Slam2dConfig | None = None,
    progress: Callable[[int], None] | None = None,
    imu: ImuLog | None = None,
) -> Slam2dResult:
    """Run the 2D SLAM over every scan of ``log_`` (:class:`Slam2dPipeline`; ``imu`` overrides the log's)."""
    return Slam2dPipeline(log_, cfg, imu).run(progress)


def render_map(
    log_: LaserLog, poses_xy_yaw: FloatArray, cfg: Slam2dConfig, stride: int = 1
) -> ProbabilityGrid:
    """All scans (every ``stride``-th) inserted at the given poses into one probability grid (scans
    unwarped with the motion between consecutive poses when the log gives beam times)."""
    P = np.asarray(poses_xy_yaw)
    pts_all = scan_points(log_, cfg, with_time=True)
    for k in range(len(P)):
        q = pts_all[k]
        if log_.time_increment > 0 and k > 0:
            dt = max(float(log_.t_ns[k] - log_.t_ns[k - 1]) * 1e-9, 1e-3)
            step_k = pose2.between(P[k - 1], P[k])
            pts_all[k] = pose2.act_each(step_k[None] * (q[:, 2] / dt)[:, None], q[:, :2])
        else:
            pts_all[k] = q[:, :2]
    grid = ProbabilityGrid(GridParams(resolution=cfg.map_resolution), P[0, :2], 10.0)
    allp = np.concatenate(
        [pose2.act(P[k], pts_all[k]) for k in range(0, len(P), stride)] or [P[:1, :2]]
    )
    grid.ensure_contains(
        np.minimum(allp.min(axis=0), P[:, :2].min(axis=0)),
        np.maximum(allp.max(axis=0), P[:, :2].max(axis=0)),
    )
    for k in range(0, len(P), stride):
        if len(pts_all[k]):
            grid.insert(pose2.act(P[k], log_.T_b_l[None, :2])[0], pose2.act(P[k], pts_all[k]))
    return grid
