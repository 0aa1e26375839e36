"""The LiDAR(-inertial) odometry in a recording: per scan (timelines ``sensor_time``, ``scan``) the
body pose ``world/body``, its registered points deskewed to the scan end ``world/body/scan``, the
1-sigma position ellipsoid ``world/covariance``, the local map ``world/local_map`` (at the first scan
that has one, then every ``map_every`` scans) and the scan's figures ``scan/...`` (iterations,
correspondences, points, time, the residual RMS at the pose); at the end (static)
the trajectory ``world/trajectory`` (the positions of trajectory.tum), the exported map ``world/map``
and the ground truth ``world/ground_truth`` moved onto the estimate (SE(3) alignment, as the
metrics). The recording carries its layout (:func:`lio_blueprint`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from imuslam.viz.recording import set_time

if TYPE_CHECKING:
    from imuslam.interfaces import ImuLog, Trajectory
    from imuslam.lio.pipeline import LioResult, LioStep

FloatArray = NDArray[np.float64]


def quat_xyzw(R: FloatArray) -> FloatArray:
    """Unit quaternions (..., 4) x, y, z, w of rotation matrices (..., 3, 3) (rerun's order)."""
    from imuslam.geometry.quaternion import quat_from_matrix

    q = np.asarray(quat_from_matrix(R))  # w, x, y, z
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def log_pose(rr: Any, rec: Any, path: str, T: FloatArray) -> None:
    rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), rr.TransformAxes3D(0.5))


def log_covariance(rr: Any, rec: Any, path: str, centre: FloatArray, C: FloatArray) -> None:
    """The 1-sigma ellipsoid of the covariance ``C`` (3, 3), m^2, at ``centre`` (3,), world frame."""
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    if not np.all(np.isfinite(w)):
        return
    if np.linalg.det(V) < 0:
        V[:, 2] *= -1
    rec.log(path, rr.Ellipsoids3D(centers=[centre], half_sizes=[np.sqrt(np.maximum(w, 0.0))],
                                  quaternions=[rr.Quaternion(xyzw=quat_xyzw(V))]))  # fmt: skip


SCAN_FIGURES = (
    ("residual_rms_m", "residual RMS (m)"),
    ("points_registered", "points registered"),
    ("correspondences", "correspondences"),
    ("iterations", "iterations"),
    ("time_ms", "time per scan (ms)"),
)


def lio_blueprint() -> Any:
    """The viewer's layout of a ``lio`` recording: the 3D world (map, trajectory, ground truth, the
    scan) on two thirds of the window; beside it the per-scan figures (one tab each, the residual RMS
    first) above the IMU (gyro and accel tabs, raw and corrected together). Left to itself the viewer
    gives each of the seven series a plot and the 3D view an eighth of the window."""
    import rerun.blueprint as rrb

    scan = [rrb.TimeSeriesView(origin=f"scan/{k}", name=name) for k, name in SCAN_FIGURES]
    imu = [
        rrb.TimeSeriesView(origin="imu", contents=[f"imu/raw/{k}", f"imu/corrected/{k}"], name=name)
        for k, name in (("gyro", "IMU gyro (rad/s)"), ("accel", "IMU accel (m/s^2)"))
    ]
    world = rrb.Spatial3DView(origin="world", name="world")
    right = rrb.Vertical(rrb.Tabs(*scan), rrb.Tabs(*imu))
    return rrb.Blueprint(rrb.Horizontal(world, right, column_shares=[2.0, 1.0]))


class LioLogger:
    """The observer of :meth:`imuslam.lio.pipeline.LioPipeline.run` writing to ``rec``."""

    def __init__(self, rec: Any, map_every: int = 50) -> None:
        import rerun as rr

        self.rr, self.rec, self.map_every = rr, rec, map_every
        self.n = 0
        self.map_at = -map_every  # the step the local map was last logged at
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.send_blueprint(lio_blueprint())

    def __call__(self, step: LioStep) -> None:
        rr, rec, st = self.rr, self.rec, step.stats
        set_time(rec, st.t_ns, step.index)
        log_pose(rr, rec, "world/body", step.T_w_b)
        rec.log("world/body/scan", rr.Points3D(step.points_b, radii=0.03))
        if step.cov_p is not None:
            log_covariance(rr, rec, "world/covariance", step.T_w_b[:3, 3], step.cov_p)
        if step.local_map_w is not None and self.n - self.map_at >= self.map_every:
            self.map_at = self.n
            rec.log(
                "world/local_map",
                rr.Points3D(step.local_map_w(), radii=0.02, colors=[150, 150, 150]),
            )
        for name, v in (("iterations", st.iterations), ("correspondences", st.n_corr),
                        ("points_registered", st.n_used), ("time_ms", st.time_s * 1e3)):  # fmt: skip
            rec.log(f"scan/{name}", rr.Scalars(float(v)))
        if np.isfinite(step.residual_rms):
            rec.log("scan/residual_rms_m", rr.Scalars(step.residual_rms))
        self.n += 1

    def finish(self, result: LioResult, truth: Trajectory | None = None) -> None:
        """The final trajectory, the exported map and the ground truth (static)."""
        rr, rec = self.rr, self.rec
        rec.log("world/trajectory", rr.LineStrips3D([result.trajectory.p_w], colors=[255, 140, 0]),
                static=True)  # fmt: skip
        rec.log("world/map", rr.Points3D(result.map_points, radii=0.03, colors=[120, 120, 120]),
                static=True)  # fmt: skip
        if truth is not None:
            log_truth(rr, rec, truth, result.trajectory)


def log_truth(rr: Any, rec: Any, truth: Trajectory, est: Trajectory) -> None:
    """``truth`` moved onto ``est`` by the SE(3) alignment the metrics use (``world/ground_truth``,
    static); nothing when the two do not overlap in time."""
    from imuslam.errors import InputError
    from imuslam.eval.align import align
    from imuslam.eval.associate import associate

    try:
        r, e = associate(truth, est, 0.02)
        s, R, t = align(r, e, "se3")
    except InputError:
        return
    p = ((truth.p_w - t) @ R) / s  # the inverse of p_ref = s R p_est + t
    rec.log("world/ground_truth", rr.LineStrips3D([p], colors=[60, 60, 60]), static=True)


def log_imu(rec: Any, imu: ImuLog, prefix: str) -> None:
    """An IMU log as two series ``<prefix>/accel`` (m/s^2) and ``<prefix>/gyro`` (rad/s), columns."""
    import rerun as rr

    from imuslam.viz.recording import time_column

    acc = imu.accel * (9.80665 if imu.accel_unit == "g" else 1.0)
    gyr = imu.gyro * (np.pi / 180 if imu.gyro_unit == "deg/s" else 1.0)
    for name, v in (("accel", acc), ("gyro", gyr)):
        rec.log(f"{prefix}/{name}", rr.SeriesLines(names=["x", "y", "z"]), static=True)
        rec.send_columns(f"{prefix}/{name}", indexes=[time_column(rr, imu.t_ns)],
                         columns=rr.Scalars.columns(scalars=np.asarray(v, np.float64)))  # fmt: skip
