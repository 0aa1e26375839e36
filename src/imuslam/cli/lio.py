"""``imuslam lio``: LiDAR-inertial odometry and mapping from a bag (or LiDAR-only from PCD / KITTI
folders): trajectory.tum, map.ply / map.pcd, config.yaml, scans.csv, trajectory.png, metrics.json."""

from __future__ import annotations

import os
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from imuslam.cli.common import (
    RRD_HELP,
    VIEWER_HELP,
    console,
    friendly_errors,
    print_warnings,
    progress_option,
    show_progress,
    table,
)

if TYPE_CHECKING:
    from imuslam.interfaces import ImuLog, Trajectory
    from imuslam.lio.config import LioConfig
    from imuslam.lio.pipeline import LioResult


def register(app: typer.Typer) -> None:
    @app.command("lio")
    @friendly_errors
    def lio_cmd(
        source: Path = typer.Argument(
            ..., help="ROS 1 / ROS 2 / MCAP bag, or a folder of .pcd or KITTI .bin scans"
        ),
        out: Path = typer.Option(Path("lio_out"), "--out", help="results folder"),
        imu_topic: str | None = typer.Option(None, "--imu-topic", help="sensor_msgs/Imu topic"),
        points_topic: str | None = typer.Option(
            None, "--points-topic", help="sensor_msgs/PointCloud2 topic"
        ),
        calib: Path | None = typer.Option(
            None, "--calib", help="IMU calibration.yaml, applied first"
        ),
        config: Path | None = typer.Option(
            None, "--config", help="LioConfig YAML (T_i_l, time offset, ...)"
        ),
        gt: str | None = typer.Option(
            None, "--gt", help="ground truth: a TUM file or a pose topic of the bag"
        ),
        state: StateChoice | None = typer.Option(
            None,
            "--state",
            help="reduced (12, corrected IMU) or full (18); default: the config's, full",
        ),
        mode: ModeChoice | None = typer.Option(
            None, "--mode", help="features (LOAM) or direct; default: the config's, features"
        ),
        align: AlignChoice | None = typer.Option(
            None, "--align", help="the start's alignment; default: the config's, none"
        ),
        no_imu: bool = typer.Option(False, "--no-imu", help="LiDAR-only (constant-velocity model)"),
        max_scans: int | None = typer.Option(
            None, min=2, help="stop after this many scans (at least 2: a scan and its motion)"
        ),
        rrd: Path | None = typer.Option(None, "--rrd", help=RRD_HELP),
        viewer: bool = typer.Option(False, "--viewer", help=VIEWER_HELP),
        progress: bool = progress_option(),
    ) -> None:
        """LiDAR-inertial odometry (iterated ESKF) with a voxel map; LiDAR-only without an IMU."""
        os.environ.setdefault("OMP_NUM_THREADS", "1")  # before pykdtree loads its OpenMP pool
        from imuslam.io.datasets import open_dataset
        from imuslam.io.lidarsets import BagLidarDataset
        from imuslam.lio.pipeline import LioPipeline
        from imuslam.lio.report import write_results

        cfg = _config(config, state, mode, align, no_imu)
        data = open_dataset(source, "lidar", points_topic=points_topic, imu_topic=imu_topic,
                            use_imu=cfg.use_imu)  # fmt: skip
        bag = isinstance(data, BagLidarDataset)
        truth = _reference(gt, source, bag) if gt is not None else None
        raw = data.imu()
        imu = _checked_imu(raw, calib) if raw is not None else None
        from imuslam.viz.recording import open_recording

        with open_recording(f"imuslam lio {source.name}", rrd, viewer) as rec:
            obs = _observer(rec, raw, imu if calib is not None else None)
            res = LioPipeline(
                data, cfg, imu=imu, max_scans=max_scans, progress=show_progress(progress)
            ).run(obs)  # type: ignore[arg-type]
            if obs is not None:
                obs.finish(res, truth)
            metrics = write_results(res, out, truth)
        console.print(
            table(f"imuslam lio {source}", ["quantity", "value", "unit"], _rows(res, metrics))
        )
        for line in describe_run(res.config, imu is not None, calib is not None):
            console.print(line, markup=False, highlight=False)
        print_warnings(res.warnings)
        console.print(f"wrote {out}/trajectory.tum, map.ply, map.pcd, config.yaml, scans.csv, "
                      "trajectory.png, metrics.json")  # fmt: skip


def describe_run(cfg: LioConfig, has_imu: bool, calibrated: bool) -> list[str]:
    """The configuration that ran, in one line, and a hint when the IMU was used as it came (its bias
    and scale errors enter every prediction: on a 20 s simulated street the raw IMU's rotation error
    was twice the LiDAR-only run's, a calibrated one's below it)."""
    inertial = has_imu and cfg.use_imu
    dim = {"full": 18, "reduced": 12}.get(cfg.filter.state, 0)
    if inertial:
        what = f"LiDAR-inertial, IMU {'calibrated (--calib)' if calibrated else 'raw'}"
        what += f", state {cfg.filter.state} ({dim}), start alignment {cfg.align}"
    else:
        what = "LiDAR-only (constant-velocity model" + (
            ", no IMU)" if cfg.use_imu else ", --no-imu)"
        )
    lines = [f"ran: {what}, front end {cfg.frontend.mode}"]
    if inertial and not calibrated:
        lines.append(
            "hint: the IMU was used raw; its biases and scale errors enter every prediction. "
            "Calibrate it (imuslam calibrate) and pass --calib calibration.yaml, or compare with --no-imu"
        )
    return lines


def _observer(rec: Any, raw: ImuLog | None, corrected: ImuLog | None) -> Any:
    """The recording's per-scan logger with the IMU raw (and corrected) logged; None without one."""
    if rec is None:
        return None
    from imuslam.viz.lio import LioLogger, log_imu

    if raw is not None:
        log_imu(rec, raw, "imu/raw")
    if corrected is not None:
        log_imu(rec, corrected, "imu/corrected")
    return LioLogger(rec)


class StateChoice(StrEnum):
    reduced = "reduced"
    full = "full"


class ModeChoice(StrEnum):
    features = "features"
    direct = "direct"


class AlignChoice(StrEnum):
    none = "none"
    kf = "kf"
    stkf = "stkf"
    rwnn = "rwnn"


def _config(
    config: Path | None,
    state: StateChoice | None,
    mode: ModeChoice | None,
    align: AlignChoice | None,
    no_imu: bool,
) -> LioConfig:
    """The effective configuration: the --config file (unknown keys refused), then the options, as
    one validated copy (nothing is changed after validation)."""
    from imuslam.config import load_config
    from imuslam.lio.config import LioConfig

    cfg = load_config(config, LioConfig) if config is not None else LioConfig()
    upd: dict[str, Any] = {}
    if state is not None:
        upd["filter"] = cfg.filter.model_copy(update={"state": state.value})
    if mode is not None:
        upd["frontend"] = cfg.frontend.model_copy(update={"mode": mode.value})
    if align is not None:
        upd["align"] = align.value
    if no_imu:
        upd["use_imu"] = False
    return cfg.model_copy(update=upd)


def _reference(gt: str, source: Path, bag: bool) -> Trajectory:
    """--gt: a pose topic of the bag (a name starting with / that is no file), else a TUM file."""
    if bag and gt.startswith("/") and not Path(gt).exists():
        from imuslam.io.bag import Bag

        with Bag(source) as b:
            return b.trajectory(gt)
    from imuslam.io.trajectory import read_trajectory

    return read_trajectory(Path(gt), "tum")


def _checked_imu(imu: ImuLog, calib: Path | None) -> ImuLog:
    """The IMU corrected by ``calib``, its units checked against what a vehicle can do."""
    from imuslam.io.plausible import check_units

    if calib is not None:
        from imuslam.imu.model import ImuCalibration

        imu = ImuCalibration.load_yaml(calib).correct(imu)
    check_units(imu, hint="a sensor_msgs/Imu carries m/s^2 and rad/s (convert the bag's IMU)")
    span = (imu.t_ns[0], imu.t_ns[-1])
    console.print(f"IMU {imu.source}: {len(imu)} samples, {imu.rate_hz:.0f} Hz, "
                  f"{(span[1] - span[0]) * 1e-9:.1f} s")  # fmt: skip
    return imu


def _rows(res: LioResult, metrics: dict[str, Any]) -> list[list[str]]:
    import numpy as np

    st = res.stats
    tms = np.array([s.time_s for s in st]) * 1e3
    rows = [
        ["scans", f"{len(st)}", ""],
        ["speed", f"{res.scans_per_s:.1f}", "scans/s"],
        ["time per scan (median / max)", f"{np.median(tms):.1f} / {np.max(tms):.1f}", "ms"],
        ["iterations (mean)", f"{np.mean([s.iterations for s in st]):.2f}", ""],
        ["points registered (mean)", f"{np.mean([s.n_used for s in st]):.0f}", "points"],
        ["path length", f"{res.trajectory.path_length:.1f}", "m"],
        ["map points (exported)", f"{len(res.map_points)}", "points"],
    ]
    if metrics:
        rows += [["ATE (SE(3) aligned)", f"{metrics['ape_trans']['rmse']:.4g}", "m"],
                 ["rotation RMSE", f"{metrics['ape_rot_deg']['rmse']:.4g}", "deg"],
                 ["RPE per metre", f"{metrics['rpe_trans']['rmse']:.4g}", "m"]]  # fmt: skip
        if "kitti_mean_trans_pct" in metrics:
            rows.append(["KITTI drift (100-800 m)", f"{metrics['kitti_mean_trans_pct']:.4g}", "%"])
    return rows
