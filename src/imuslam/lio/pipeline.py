"""The LiDAR(-inertial) odometry pipeline: reads a dataset, cleans each scan, drives the pure estimator
(:class:`~imuslam.lio.lidar_only.LidarOdometry` or :class:`~imuslam.lio.estimator.LioEstimator`), keeps
timing, builds the global map and returns a :class:`LioResult` (KISS-ICP's ``OdometryPipeline`` beside
``KissICP``). The results folder is written by :func:`imuslam.lio.report.write_results` through the
one writer, :func:`imuslam.io.results.write_results`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import EstimatorError, InputError
from imuslam.interfaces import Scan3d
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.sources import LidarSource
from imuslam.io.trajectory import Trajectory
from imuslam.lio.config import LioConfig
from imuslam.lio.features import voxel_downsample
from imuslam.lio.frontend import valid_points
from imuslam.lio.guards import AXES
from imuslam.lio.lidar_only import LidarOdometry
from imuslam.lio.voxelmap import VoxelMap

if TYPE_CHECKING:
    from imuslam.ins.align import AlignmentResult

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


class LidarDataset(LidarSource, Protocol):
    """What the pipeline reads: scans in time order (``LidarSource``), the IMU when the dataset has one
    (a folder of scans has none), a name and a scan count."""

    name: str

    def imu(self) -> ImuLog | None: ...

    def __len__(self) -> int: ...


@dataclass
class ScanStats:
    """Per scan: stamp of its end (ns), points read, dropped (NaN / zero), registered, iterations,
    correspondences, the wall time of the estimator step, s, and its CPU time (process), s."""

    t_ns: int
    n_points: int
    n_dropped: int
    n_used: int
    iterations: int
    n_corr: int
    time_s: float
    cpu_s: float = 0.0


@dataclass
class LioStep:
    """What an observer of :meth:`LioPipeline.run` receives per registered scan, in the result's
    world frame: the scan's statistics, the pose ``T_w_b`` (4, 4) the trajectory holds at ``stats.t_ns``
    (IMU frame; LiDAR frame without an IMU), the registered points deskewed to the scan end in the frame
    of that pose (M, 3), m, the position covariance (3, 3), m^2, when the estimator has one, the
    local map's points (K, 3), world frame, on demand (None while the start's frame is provisional),
    and the RMS point-to-map distance of the matched points at the pose, m (NaN where not known)."""

    index: int
    stats: ScanStats
    T_w_b: FloatArray
    points_b: FloatArray
    cov_p: FloatArray | None = None
    local_map_w: Callable[[], FloatArray] | None = None
    residual_rms: float = float("nan")


#: Called after each registered scan; the steps of the start come once its world frame is settled.
LioObserver = Callable[[LioStep], None]


@dataclass
class LioResult:
    """Poses of the IMU frame (LiDAR frame when there is no IMU) at each scan end, per-scan statistics,
    the downsampled global map (world frame), warnings, the effective configuration, the start's
    alignment (``ins.align.AlignmentResult``; None with ``align none`` or without an IMU), and with
    ``filter.estimate_extrinsic`` / ``estimate_time_offset`` the final extrinsic and offset with their
    1-sigma and what the motion excited (``OnlineCalibration.report``)."""

    trajectory: Trajectory
    stats: list[ScanStats]
    map_points: FloatArray
    config: LioConfig
    warnings: list[str] = field(default_factory=list)
    peak_map_points: int = 0
    wall_s: float = 0.0
    alignment: AlignmentResult | None = None
    online_calibration: dict[str, Any] | None = None

    @property
    def scans_per_s(self) -> float:
        t = sum(s.time_s for s in self.stats)
        return len(self.stats) / t if t > 0 else float("nan")

    @property
    def scans_per_cpu_s(self) -> float:
        """Scans per second of CPU time of the estimator step (all threads of the process)."""
        t = sum(s.cpu_s for s in self.stats)
        return len(self.stats) / t if t > 0 else float("nan")


def clean_scan(
    scan: Scan3d, index: int
) -> tuple[FloatArray, FloatArray, NDArray[np.uint16] | None, int]:
    """Points (N, 3) float64, point times (N,) s after the scan stamp, rings or None, and the number of
    NaN / infinite / zero points dropped."""
    p = np.asarray(scan.points_l)
    t = np.asarray(scan.t_offset_s)
    if p.ndim != 2 or p.shape[1] != 3 or t.shape != (len(p),):
        raise ValueError(
            f"scan {index}: expected points (N, 3) and times (N,), got {p.shape} and {t.shape}"
        )
    ok = valid_points(p, t)
    n_ok = int(np.count_nonzero(ok))
    ring = np.asarray(scan.ring) if len(scan.ring) == len(p) and len(p) else None
    if n_ok < len(p):  # a copy only when something is dropped (a dense scan is 130k points)
        p, t, ring = p[ok], t[ok], (None if ring is None else ring[ok])
    return p.astype(np.float64), t.astype(np.float64), ring, int(len(ok) - n_ok)


def imu_gaps(t_s: FloatArray, limit_s: float = 0.1) -> str:
    """A warning (or "") counting the IMU gaps longer than ``limit_s`` in the sample times ``t_s`` (s):
    the filter propagates across them on interpolated samples, so the prior there is weaker."""
    dt = np.diff(np.asarray(t_s, dtype=np.float64))
    big = np.flatnonzero(dt > limit_s)
    if not len(big):
        return ""
    i = int(big[np.argmax(dt[big])])
    return (f"{len(big)} IMU gaps longer than {limit_s:g} s (longest {dt[i]:.2f} s at t = {t_s[i]:.2f} s)")  # fmt: skip


def guard_notes(est: Any) -> list[str]:
    """The estimator's repairs of the IMU and its degenerate scans (``lio.guards``), one line each."""
    notes = list(est.repair.notes) if getattr(est, "repair", None) is not None else []
    deg = getattr(est, "degenerate_scans", [])
    if deg:
        dirs = sorted({d for _, _, ds, _ in deg for d in ds}, key=AXES.index)
        kept = (
            "kept at the IMU's prediction" if est.config.filter.degeneracy_guard else "not guarded"
        )
        notes.append(f"{len(deg)} degenerate scans (scan {deg[0][0]} at t = {deg[0][1]:.2f} s to scan "
                     f"{deg[-1][0]} at t = {deg[-1][1]:.2f} s; weakest 1-sigma up to "
                     f"{max(s for *_, s in deg):.2g} m): {', '.join(dirs)} {kept}")  # fmt: skip
    return notes


class LioPipeline:
    """Run the odometry over ``dataset``; ``imu`` overrides the dataset's IMU (e.g. after calibration)."""

    def __init__(
        self,
        dataset: LidarDataset,
        config: LioConfig | None = None,
        imu: ImuLog | None = None,
        progress: bool = True,
        map_voxel: float = 0.2,
        max_scans: int | None = None,
    ) -> None:
        self.dataset = dataset
        self.config = config or LioConfig()
        self.imu = imu if imu is not None else dataset.imu()
        self.progress = progress
        self.map_voxel = map_voxel
        self.max_scans = max_scans

    def _estimator(self) -> Any:
        if self.config.use_imu and self.imu is not None:
            from imuslam.lio.estimator import LioEstimator

            return LioEstimator(self.config, self.imu)
        if self.config.use_imu:
            log.warning(
                "%s: no IMU; LiDAR-only odometry (constant-velocity model)", self.dataset.name
            )
        return LidarOdometry(self.config)

    def run(self, observer: LioObserver | None = None) -> LioResult:
        """The odometry over the dataset; ``observer`` sees each registered scan (:class:`LioStep`)."""
        from imuslam.threads import blas_threads

        with blas_threads(1):
            return self._run(observer)

    @staticmethod
    def _observe(observer: LioObserver, est: Any, step: LioStep, pending: list[LioStep]) -> None:
        """Hand ``step`` to ``observer``; a step taken before the filter's world exists waits in
        ``pending`` and goes out moved into that world, as the result's trajectory moves it."""
        if getattr(est, "eskf", True) is None:
            pending.append(step)
            return
        if pending:
            start = getattr(est, "start_poses", None)
            if start is None or len(start) != len(pending):  # not refined: the poses as returned
                start = [s.T_w_b for s in pending]
            for i, s in enumerate(pending):
                s.T_w_b = est.T_w_i0 @ start[i]
                observer(s)
            pending.clear()
        cov = getattr(est, "covariance", None)
        if cov is not None:
            sl = est.layout.P
            step.cov_p = cov[sl, sl]
        m = est.map
        step.local_map_w = lambda: np.vstack([m.surf.points, m.edge.points])
        if hasattr(est, "last_residual_rms"):
            step.residual_rms = est.last_residual_rms()
        observer(step)

    def _run(self, observer: LioObserver | None = None) -> LioResult:
        from tqdm import tqdm

        est = self._estimator()
        lidar_only = isinstance(est, LidarOdometry)
        T_l_i = np.linalg.inv(self.config.extrinsic.T_i_l()) if lidar_only else np.eye(4)
        offset_ns = int(round(self.config.extrinsic.time_offset_s * 1e9))
        gmap = VoxelMap(self.map_voxel, 1, np.inf)
        t_ns: list[int] = []
        poses: list[FloatArray] = []
        stats: list[ScanStats] = []
        warnings: list[str] = []
        n_empty = n_back = n_dropped = n_outside = 0
        span = None if lidar_only else (int(self.imu.t_ns[0]), int(self.imu.t_ns[-1]))  # type: ignore[union-attr]
        lidar_span: list[int] = []
        t_ref: int | None = None if lidar_only else int(self.imu.t_ns[0])  # type: ignore[union-attr]
        last_end: int | None = None
        pending: list[LioStep] = []
        total = (
            len(self.dataset) if self.max_scans is None else min(len(self.dataset), self.max_scans)
        )
        bar = tqdm(total=total, unit="scan", desc="lio", disable=not self.progress)
        wall0 = time.perf_counter()
        for k, scan in enumerate(self.dataset.lidar_scans()):
            if self.max_scans is not None and k >= self.max_scans:
                break
            bar.update(1)
            pts, toff, ring, dropped = clean_scan(scan, k)
            n_dropped += dropped
            if len(pts) < 100:
                n_empty += 1
                continue
            stamp = int(scan.t_ns) + offset_ns
            if t_ref is None:
                t_ref = stamp
            end_ns = stamp + int(round(float(toff.max()) * 1e9))
            start_ns = stamp + int(round(float(toff.min()) * 1e9))
            lidar_span = [lidar_span[0] if lidar_span else start_ns, end_ns]
            if span is not None and (start_ns < span[0] or end_ns > span[1]):
                n_outside += 1  # points before the first or after the last IMU sample
                continue
            if last_end is not None and end_ns <= last_end:
                n_back += 1
                continue
            t_s = (stamp - t_ref) * 1e-9 + toff
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                T = est.register_scan(pts, t_s, ring)
            except EstimatorError:
                raise
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            if not np.all(np.isfinite(T)):
                from imuslam.errors import FilterDivergence

                raise FilterDivergence(
                    f"scan {k} (t = {end_ns * 1e-9:.3f} s): the pose is not finite"
                )
            last_end = end_ns
            T_w = T @ T_l_i
            t_ns.append(end_ns)
            poses.append(T_w)
            stats.append(ScanStats(end_ns, len(pts) + dropped, dropped, est.last_n_used, est.last_iterations,
                                   est.last_n_corr, dt, dc))  # fmt: skip
            if observer is not None:
                pb = np.vstack(est.last_points)
                if lidar_only:  # LiDAR frame -> the IMU frame of T_w
                    pb = pb @ T_l_i[:3, :3] - T_l_i[:3, :3].T @ T_l_i[:3, 3]
                self._observe(observer, est, LioStep(k, stats[-1], T_w, pb), pending)
            if (
                k % 5 == 0
            ):  # at most 32k points of a scan (a dense scan fills the 0.2 m voxels anyway)
                sub = pts[:: max(1, len(pts) // 32768)]
                used = sub[voxel_downsample(sub, self.map_voxel)]
                gmap.add(used @ T[:3, :3].T + T[:3, 3])
            if self.progress and k % 10 == 0:
                bar.set_postfix(
                    scans_per_s=f"{len(stats) / max(sum(s.time_s for s in stats), 1e-9):.1f}"
                )
        bar.close()
        for s in pending:  # the filter never started: the steps in the first IMU frame
            observer(s)  # type: ignore[misc]  # pending stays empty without an observer
        if n_dropped:
            warnings.append(f"{n_dropped} NaN / infinite / zero points dropped")
        if n_empty:
            warnings.append(f"{n_empty} scans with fewer than 100 valid points skipped")
        if n_outside:
            warnings.append(f"{n_outside} scans outside the IMU's time span skipped")
        n_nan = int(getattr(self.dataset, "n_nan_dropped", 0))
        if n_nan:
            warnings.append(f"{n_nan} NaN points dropped by the reader")
        if n_back:
            warnings.append(f"{n_back} scans out of time order skipped")
        if not lidar_only:
            gap = imu_gaps(self.imu.t_s)  # type: ignore[union-attr]
            if gap:
                warnings.append(gap)
            warnings.extend(guard_notes(est))
        online = None
        if getattr(est, "calib", None) is not None and est.eskf is not None:
            online = est.calib.report(est.eskf.x, est.eskf.P)
            warnings.extend(f"online extrinsic: {u}" for u in online["unobserved"])
        for w in warnings:
            log.warning("%s: %s", self.dataset.name, w)
        if span is not None and not poses and lidar_span:
            raise InputError(
                f"{self.dataset.name}: no overlap between IMU times [{span[0] * 1e-9:.3f}, {span[1] * 1e-9:.3f}] s "
                f"and LiDAR times [{lidar_span[0] * 1e-9:.3f}, {lidar_span[1] * 1e-9:.3f}] s (a time offset "
                "goes in the config's extrinsic.time_offset_s)"
            )
        if len(poses) < 2:
            raise InputError(
                f"{self.dataset.name}: {len(poses)} usable scans; at least 2 are needed"
            )
        P = np.array(poses)
        n_pre = int(getattr(est, "n_before_filter", 0))
        if n_pre:  # poses returned before the filter's world existed: move them into it
            start = getattr(est, "start_poses", None)  # the start's refined poses, if it has them
            if start is not None and len(start) == n_pre:
                P[:n_pre] = start
            P[:n_pre] = est.T_w_i0 @ P[:n_pre]
        traj = Trajectory(
            np.array(t_ns, np.int64), P[:, :3, 3], P[:, :3, :3], f"imuslam lio {self.dataset.name}"
        )
        return LioResult(traj, stats, gmap.points, self.config, warnings,
                         getattr(est, "peak_map_points", 0), time.perf_counter() - wall0,
                         getattr(est, "alignment", None), online)  # fmt: skip
