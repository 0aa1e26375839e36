"""A study of a user's own recorded log: the estimator over the log once per IMU (as recorded, with
each calibration, ...), every run scored without ground truth by the sharpness of its map, against the
reference run's trajectory, and against a ground truth when one is given.

Everything is read and checked before the first run (the log and the estimator's topics, every
calibration against the log's units, the estimator's configuration): a bad input is one line and
nothing is run or written. Map sharpness (``eval.mapquality.point_map_quality``): every scan's hits
placed at the run's poses (as the output map inserts them), then the mean map entropy and the spread
of the hits about their local wall within ``radius_m``; and the occupied cells of the output map. A
blurred or doubled wall raises all three. VIO keeps no map: its runs are scored by trajectory only.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import EstimatorError, InputError
from imuslam.imu.model import ImuCalibration
from imuslam.interfaces import ImuLog, Trajectory
from imuslam.study.logconfig import LogSpec, LogStudyConfig, RunSpec
from imuslam.study.logreport import LogStudyRun, RunResult

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


def inject_seed000(imu: ImuLog) -> ImuLog:
    """The log as a sensor with seed 000's table-2 errors would have reported it (``x_S`` from
    ``x_O = T K (x_S + b)``, ``sim.imu_errors``), taking the recorded values as the truth; a new log
    in the units of the correction model (m/s^2, rad/s)."""
    from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO, raw_from_errors

    si = imu.to_si()
    return ImuLog(si.t_ns.copy(), raw_from_errors(si.accel, SEED000_ACCEL),
                  raw_from_errors(si.gyro, SEED000_GYRO), "m/s^2", "rad/s",
                  f"{imu.source} (seed 000's errors injected)", list(si.warnings))  # fmt: skip


@functools.lru_cache(maxsize=4)
def gimbal_calibration_seed000(seed: int, method: str = "online") -> ImuCalibration:
    """The calibration imuslam estimates from a simulated 40-pose gimbal session of a sensor with seed
    000's table-2 errors. online: the online calibrator's start-up session on the simulated robot
    (``imu.online_sim.run_simulated_robot``, the poses in the order ``imuslam online`` flies them);
    multipose: the multi-position fit of a 40-pose log (``study.conditions.gimbal_calibration``)."""
    if method == "multipose":
        from imuslam.study.conditions import gimbal_calibration
        from imuslam.study.config import DriftSpec

        return gimbal_calibration(DriftSpec(), 0.0, seed)
    from imuslam.imu.online import OnlineConfig
    from imuslam.imu.online_sim import Drift, run_simulated_robot
    from imuslam.imu.poseplan import PlanModel, optimise_order
    from imuslam.sim.multipose import sphere_plan_deg

    rng = np.random.default_rng(seed)
    plan = optimise_order(PlanModel.seed000(), sphere_plan_deg(40, rng), iterations=1000)
    cal = run_simulated_robot(plan, 0.0, Drift(), rng, OnlineConfig()).calibrator.current
    if cal is None:  # the session always ends with one on the simulator: the calibrator failed
        raise EstimatorError(
            f"gimbal_seed {seed}: the simulated online session gave no calibration"
        )
    return cal


def describe_run(r: RunSpec) -> str:
    """What IMU a run gets, in words."""
    if not r.use_imu:
        return "not used"
    parts = ["seed 000's errors injected"] if r.inject else []
    if r.calibration is not None:
        parts.append(f"corrected by {Path(r.calibration).name}")
    elif r.gimbal_calibration is not None:
        how = "online" if r.gimbal_method == "online" else "multi-position"
        parts.append(f"corrected by a simulated {how} gimbal calibration (seed {r.gimbal_seed})")
    return ", ".join(parts) or "as recorded"


@dataclass
class PreparedLog:
    """A log read and checked, with the IMU of every run and the estimator's configuration."""

    spec: LogSpec
    where: str
    data: Any  # the opened dataset: a LaserLog (map2d), a LiDAR (lio) or stereo (vio) dataset
    cfg: Any
    imus: dict[str, ImuLog | None]
    truth: Trajectory | None = None
    times_ns: NDArray[np.int64] | None = None


def _run_imu(base: ImuLog | None, r: RunSpec, where: str, platform_hint: str) -> ImuLog | None:
    """The IMU of run ``r`` from the log's ``base`` IMU; InputError naming the run's field."""
    from imuslam.io.plausible import check_units

    needs = r.inject or r.calibration or r.gimbal_calibration
    if base is None:
        if needs:
            raise InputError(f"{where}: the log has no IMU to correct or corrupt")
        return None
    imu = base
    if r.inject:
        try:
            imu = inject_seed000(imu)
        except InputError as exc:
            raise InputError(f"{where}.inject: {exc}") from None
    if r.calibration is not None:
        try:
            cal = ImuCalibration.load_yaml(r.calibration)
            imu = cal.correct(imu)
            cal.check_magnitudes(imu)
        except InputError as exc:
            raise InputError(f"{where}.calibration: {exc}") from None
    elif r.gimbal_calibration is not None:
        imu = gimbal_calibration_seed000(r.gimbal_seed, r.gimbal_method).correct(imu.to_si())
    if "counts" in (imu.accel_unit, imu.gyro_unit) and r.use_imu:
        raise InputError(
            f"{where}: the log's IMU is in raw counts; expected a calibration that turns it into "
            "m/s^2 and rad/s (calibration: the file imuslam calibrate wrote), or use_imu: false"
        )
    try:
        check_units(imu, hint=platform_hint)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    return imu


def _config(model: Any, spec: LogSpec, where: str) -> Any:
    from pydantic import ValidationError

    from imuslam.config import describe_validation_error

    try:
        return model.model_validate(spec.config)
    except ValidationError as exc:
        raise InputError(f"{where}.config: {describe_validation_error(exc)}") from None


def _read_truth(spec: LogSpec, where: str) -> Trajectory | None:
    if spec.gt is None:
        return None
    from imuslam.io.trajectory import read_trajectory

    fmt = spec.gt_format
    if fmt == "auto":
        fmt = "euroc" if spec.gt.endswith(".csv") else "tum"
    try:
        return read_trajectory(spec.gt, fmt)
    except InputError as exc:
        raise InputError(f"{where}.gt: {exc}") from None


def prepare_log(spec: LogSpec, where: str) -> PreparedLog:
    """Read ``spec``'s log, check it carries the estimator's topics, build every run's IMU."""
    if not Path(spec.path).exists():
        raise InputError(f"{where}.path: {spec.path}: no such file or folder")
    hint = "check the log's IMU units, or the calibration's units.accel_in / gyro_in"
    data: Any
    base: ImuLog | None
    if spec.estimator == "map2d":
        from imuslam.io.datasets import open_dataset
        from imuslam.io.plausible import check_stamps
        from imuslam.slam2d.config import Slam2dConfig

        cfg = _config(Slam2dConfig, spec, where)
        try:
            data = open_dataset(spec.path, "laser", fmt=spec.format, scan_topic=spec.scan_topic,
                                imu_topic=spec.imu_topic, odom_topic=spec.odom_topic)  # fmt: skip
            check_stamps(data.t_ns, "scans", spec.path)
        except InputError as exc:
            raise InputError(f"{where} (map2d needs a 2D laser scan topic): {exc}") from None
        base, times = data.imu(), data.t_ns
    elif spec.estimator == "lio":
        from imuslam.io.datasets import open_dataset
        from imuslam.lio.config import LioConfig

        cfg = _config(LioConfig, spec, where)
        try:
            data = open_dataset(spec.path, "lidar", points_topic=spec.points_topic,
                                imu_topic=spec.imu_topic)  # fmt: skip
            base = data.imu()
        except InputError as exc:
            raise InputError(f"{where} (lio needs a 3D point cloud topic): {exc}") from None
        times = None
    else:
        from imuslam.io.datasets import open_dataset
        from imuslam.io.stereosets import EurocStereo
        from imuslam.vio.config import VioConfig

        cfg = _config(VioConfig, spec, where)
        try:
            data = open_dataset(spec.path, "stereo", imu_topic=spec.imu_topic,
                                camchain=None if spec.camchain is None else Path(spec.camchain),
                                left_topic=spec.left_topic, right_topic=spec.right_topic)  # fmt: skip
        except InputError as exc:
            raise InputError(f"{where} (vio needs stereo images and an IMU): {exc}") from None
        base = data.imu()
        times = data.t_ns if isinstance(data, EurocStereo) else None  # a bag: the VO's own times
    if base is None and spec.estimator != "map2d":
        raise InputError(f"{where}: the log has no IMU ({spec.estimator} fuses one)")
    imus = {
        r.name: _run_imu(base, r, f"{where}.runs[{i}] ({r.name})", hint)
        for i, r in enumerate(spec.runs)
    }
    return PreparedLog(spec, where, data, cfg, imus, _read_truth(spec, where), times)


def map2d_points(log_: Any, poses_xy_yaw: FloatArray, cfg: Any) -> FloatArray:
    """Every scan's hits (M, 2) in the world at the given poses, unwarped as the output map inserts
    them (``slam2d.pipeline.render_map``)."""
    from imuslam.slam2d import pose2
    from imuslam.slam2d.pipeline import scan_points

    P = np.asarray(poses_xy_yaw)
    out = []
    for k, q in enumerate(scan_points(log_, cfg, with_time=True)):
        if log_.time_increment > 0 and k > 0:
            dt = max(float(log_.t_ns[k] - log_.t_ns[k - 1]) * 1e-9, 1e-3)
            q2 = pose2.act_each(
                pose2.between(P[k - 1], P[k])[None] * (q[:, 2] / dt)[:, None], q[:, :2]
            )
        else:
            q2 = q[:, :2]
        out.append(pose2.act(P[k], q2))
    return np.concatenate(out) if out else np.zeros((0, 2))


def _run_map2d(
    pl: PreparedLog, imu: ImuLog | None, use_imu: bool
) -> tuple[Trajectory, dict[str, float], Any]:
    from imuslam.eval.mapquality import point_map_quality
    from imuslam.slam2d.output import planar_trajectory
    from imuslam.slam2d.pipeline import Slam2dPipeline

    cfg = pl.cfg if use_imu else pl.cfg.model_copy(update={"use_imu": False})
    run = Slam2dPipeline(pl.data, cfg, imu=imu).run_and_render()
    q = point_map_quality(
        map2d_points(pl.data, run.result.pose_xy_yaw, cfg), pl.spec.radius_m or 0.2
    )
    g = run.grid
    occupied = int(np.count_nonzero(g.known() & (g.prob >= 0.65)))
    m = {"map_entropy": q.map_entropy, "wall_spread_cm": q.wall_spread_cm,
         "occupied_cells": float(occupied), "map_queries": float(q.queries)}  # fmt: skip
    return planar_trajectory(run.result), m, g


def _run_lio(
    pl: PreparedLog, imu: ImuLog | None, use_imu: bool
) -> tuple[Trajectory, dict[str, float]]:
    """LiDAR-inertial odometry with the run's IMU; the map (5 cm voxels) scored in 3D: mean map entropy
    and mean plane variance (``eval.mapquality.point_map_quality``)."""
    from imuslam.eval.mapquality import point_map_quality
    from imuslam.lio.pipeline import LioPipeline

    cfg = pl.cfg if use_imu else pl.cfg.model_copy(update={"use_imu": False})
    res = LioPipeline(pl.data, cfg, imu=imu, progress=False, map_voxel=0.05).run()
    q = point_map_quality(res.map_points, pl.spec.radius_m or 0.3)
    m = {"map_entropy": q.map_entropy, "wall_spread_cm": q.wall_spread_cm,
         "plane_variance_m2": q.plane_variance_m2, "map_queries": float(q.queries)}  # fmt: skip
    return res.trajectory, m


def _run_vio(
    pl: PreparedLog, imu: ImuLog | None, vo: Any
) -> tuple[Trajectory, dict[str, float], Any]:
    from imuslam.vio.pipeline import run_vio

    if imu is None:
        raise ValueError(f"{pl.where}: vio needs the log's IMU")
    res = run_vio(pl.data, pl.cfg, vo_run=vo, imu=imu)
    return res.fused, {}, res.imu


def _compare(ref: Trajectory, traj: Trajectory, times: Any, align: str) -> dict[str, float]:
    """ATE / RPE (per frame) of ``traj`` against ``ref`` at the common ``times``."""
    from imuslam.eval.vio_compare import compare_tracks

    t = np.asarray(times if times is not None else traj.t_ns)
    ev = compare_tracks(ref, {"x": traj}, t, align=align)["x"]
    return {"ate_m": ev.ape_trans.rmse, "ate_rot_deg": ev.ape_rot_deg.rmse,
            "rpe_m": ev.rpe_trans.rmse, "rpe_rot_deg": ev.rpe_rot_deg.rmse}  # fmt: skip


def run_log(pl: PreparedLog, tick: Any = None) -> list[RunResult]:
    """Every run of a prepared log, then each scored against the reference run and the truth."""
    vo = None
    if pl.spec.estimator == "vio":  # the VO front end does not see the IMU: once for every run
        from imuslam.vio.pipeline import compute_vo

        vo = compute_vo(pl.data, pl.cfg.vo)
    out = []
    for r in pl.spec.runs:
        t0 = time.perf_counter()
        imu = pl.imus[r.name]
        imu_track = None
        if pl.spec.estimator == "map2d":
            traj, m, grid = _run_map2d(pl, imu, r.use_imu)
        elif pl.spec.estimator == "lio":
            traj, m = _run_lio(pl, imu, r.use_imu)
            grid = None
        else:
            traj, m, imu_track = _run_vio(pl, imu, vo)
            grid = None
        m["path_length_m"] = float(np.sum(np.linalg.norm(np.diff(traj.p_w, axis=0), axis=1)))
        out.append(RunResult(pl.spec.name, r.name, describe_run(r), traj, m, grid,
                             time.perf_counter() - t0, imu_track))  # fmt: skip
        log.debug("%s / %s: %.1f s", pl.spec.name, r.name, out[-1].wall_s)
        if tick is not None:
            tick()
    ref = next(x for x in out if x.run == pl.spec.reference_run)
    for x in out:
        for k, v in _compare(ref.trajectory, x.trajectory, pl.times_ns, pl.spec.align).items():
            x.metrics[f"ref_{k}"] = v
        if pl.truth is not None:
            for k, v in _compare(pl.truth, x.trajectory, pl.times_ns, pl.spec.align).items():
                x.metrics[f"gt_{k}"] = v
            if (
                x.imu_track is not None
            ):  # what the IMU alone is worth (vio: integrated from the start)
                ev = _compare(pl.truth, x.imu_track, pl.times_ns, pl.spec.align)
                x.metrics["gt_imu_ate_m"] = ev["ate_m"]
                x.metrics["gt_imu_ate_rot_deg"] = ev["ate_rot_deg"]
    return out


def run_log_study(
    study: LogStudyConfig, out: str | Path | None, source: str, progress: bool = False
) -> LogStudyRun:
    """Check every log and run (nothing runs before all are good), run them, and with ``out`` write
    the report (``study.logreport.write_log_outputs``)."""
    if out is not None:
        from imuslam.io.results import check_not_input, check_out_dir

        check_out_dir(out, "folder")
        inputs: list[tuple[str, str | None]] = []
        for lg in study.logs:
            inputs += [(f"the log of {lg.name}", lg.path), ("a ground truth", lg.gt),
                       ("a camchain", lg.camchain)]  # fmt: skip
            inputs += [(f"the calibration of run {r.name}", r.calibration) for r in lg.runs]
        check_not_input(out, inputs)
    prepared = [
        prepare_log(lg, f"{source}: logs[{i}] ({lg.name})") for i, lg in enumerate(study.logs)
    ]
    res = LogStudyRun()
    from tqdm import tqdm

    n = sum(len(pl.spec.runs) for pl in prepared)
    with tqdm(total=n, unit="run", desc="study", disable=not progress) as bar:
        for pl in prepared:
            res.runs += run_log(pl, bar.update)
    if out is not None:
        from imuslam.io.results import results_folder
        from imuslam.study.logreport import write_log_outputs

        with results_folder(out) as tmp:
            write_log_outputs(study, res, tmp)
    return res
