"""``imuslam map2d``: 2D SLAM (scan-to-submap matching, loop closure, pose graph) of a laser log."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from imuslam.cli import validate
from imuslam.cli.common import console, friendly_errors, progress_option, show_progress, table
from imuslam.cli.lio import RRD_HELP, VIEWER_HELP

if TYPE_CHECKING:
    from imuslam.interfaces.imu import ImuLog
    from imuslam.io.laserlog import LaserLog
    from imuslam.slam2d.config import Slam2dConfig


def _check_reference(gt: Path, log_: LaserLog) -> None:
    """The --gt reference read and matched to the log before the run: a corrected CARMEN log must
    hold scans with this log's readings, a trajectory must be readable; else one line naming --gt."""
    from imuslam.errors import InputError
    from imuslam.eval.slam2d_gt import is_carmen

    try:
        if is_carmen(gt):
            from imuslam.eval.relations import associate_by_ranges
            from imuslam.io.carmen import read_carmen

            ri, _ = associate_by_ranges(read_carmen(gt).laser.ranges, log_.ranges)
            if len(ri) < 2:
                raise InputError("fewer than 2 of its scans have the readings of a scan of the log")
        else:
            from imuslam.io.trajectory import read_trajectory

            read_trajectory(gt, "tum")
    except InputError as exc:
        if str(gt) in str(exc):  # the reader named the file and what it expected
            raise InputError(f"--gt: {exc}") from None
        raise InputError(
            f"--gt {gt}: {exc}; expected the corrected log or trajectory of {log_.source}"
        ) from None


def register(app: typer.Typer) -> None:
    @app.command("map2d")
    @friendly_errors
    def map2d_cmd(
        log_path: Path = typer.Argument(
            ...,
            help="CARMEN log (.clf/.log[.gz|.bz2]), BreezySLAM .dat, a bag, or an imuslam simulate folder",
        ),
        out: Path = typer.Option(Path("map2d_out"), "--out", help="results folder"),
        calib: Path | None = typer.Option(
            None, "--calib", help="IMU calibration.yaml applied before use"
        ),
        gt: Path | None = typer.Option(
            None, "--gt", help="reference: a corrected CARMEN log or a TUM trajectory"
        ),
        config: Path | None = typer.Option(None, "--config", help="YAML with Slam2dConfig fields"),
        fmt: str = typer.Option(
            "auto",
            "--format",
            help="auto, carmen, breezyslam, bag or sim",
            callback=validate.choice(("auto", "carmen", "breezyslam", "bag", "sim")),
        ),
        scan_topic: str | None = typer.Option(
            None, "--scan-topic", help="bag: LaserScan / MultiEchoLaserScan topic"
        ),
        imu_topic: str | None = typer.Option(
            None, "--imu-topic", help="bag: Imu topic (default: the only one)"
        ),
        odom_topic: str | None = typer.Option(
            None, "--odom-topic", help="bag: Odometry topic (default: the only one)"
        ),
        no_odometry: bool = typer.Option(
            False, "--no-odometry", help="do not use the wheel odometry"
        ),
        no_imu: bool = typer.Option(False, "--no-imu", help="do not use the IMU"),
        no_loop: bool = typer.Option(False, "--no-loop", help="local SLAM only (no loop closure)"),
        progress: bool = progress_option(),
        rrd: Path | None = typer.Option(None, "--rrd", help=RRD_HELP),
        viewer: bool = typer.Option(False, "--viewer", help=VIEWER_HELP),
    ) -> None:
        """Map a 2D laser log: trajectory.tum, map.pgm/map.yaml (map_server), map.png, config.yaml."""
        from tqdm import tqdm

        from imuslam.slam2d.pipeline import Slam2dPipeline

        cfg = _config(config, no_odometry, no_imu, no_loop)
        log_, imu = _load(log_path, fmt, scan_topic, imu_topic, odom_topic, calib, cfg)
        if gt is not None:
            _check_reference(gt, log_)
        pipeline = Slam2dPipeline(log_, cfg, imu=imu)
        from imuslam.viz.recording import open_recording

        with (
            open_recording(f"imuslam map2d {log_path.name}", rrd, viewer) as rec,
            tqdm(
                total=len(log_), unit="scan", desc="map2d", disable=not show_progress(progress)
            ) as bar,
        ):

            def tick(k: int) -> None:
                if k % 50 == 49:
                    bar.update(50)

            obs = _observer(rec, pipeline.imu, calib is not None)
            run = pipeline.run_and_render(tick, obs)
            bar.update(len(log_) - bar.n)
            if obs is not None:
                obs.finish(run)
        metrics = ref_xy = None
        if gt is not None:
            from imuslam.eval.slam2d_gt import reference_in_map, score_run

            metrics = score_run(gt, log_, run.result.t_ns, run.result.pose_xy_yaw)
            ref_xy = reference_in_map(gt, log_, run.result.t_ns, run.result.pose_xy_yaw)
        s = pipeline.save(run, out, metrics, ref_xy)
        rows = _summary_rows(s, run.result.warnings, run.wall_s, metrics)
        console.print(table(f"imuslam map2d: {log_path.name}", ["quantity", "value", "unit"], rows))
        console.print(
            f"wrote {out}/: trajectory.tum, map.pgm, map.yaml, map.png, config.yaml, metrics.json"
        )


def _observer(rec: Any, imu: ImuLog | None, calibrated: bool) -> Any:
    """The recording's per-scan logger, the run's IMU logged first; None without a recording."""
    if rec is None:
        return None
    from imuslam.viz.lio import log_imu
    from imuslam.viz.slam2d import Slam2dLogger

    if imu is not None:
        log_imu(rec, imu, "imu/corrected" if calibrated else "imu/raw")
    return Slam2dLogger(rec)


def _config(config: Path | None, no_odometry: bool, no_imu: bool, no_loop: bool) -> Slam2dConfig:
    """The effective configuration: the --config file's fields, then the --no-* options."""
    from pydantic import ValidationError

    from imuslam.config import describe_validation_error
    from imuslam.errors import InputError
    from imuslam.io.yamlfile import read_yaml
    from imuslam.slam2d.config import Slam2dConfig

    data = (
        read_yaml(config, "a mapping of Slam2dConfig fields (--config)", empty={}) if config else {}
    )
    try:
        cfg = Slam2dConfig.model_validate(data)
    except ValidationError as exc:
        raise InputError(f"--config {config}: {describe_validation_error(exc)}") from None
    loop = cfg.loop.model_copy(update={"enabled": cfg.loop.enabled and not no_loop})
    return cfg.model_copy(update={"use_odometry": cfg.use_odometry and not no_odometry,
                                  "use_imu": cfg.use_imu and not no_imu, "loop": loop})  # fmt: skip


def _load(
    log_path: Path, fmt: str, scan_topic: str | None, imu_topic: str | None,
    odom_topic: str | None, calib: Path | None, cfg: Slam2dConfig,
) -> tuple[LaserLog, ImuLog | None]:  # fmt: skip
    """The log (its stamps checked) and the run's IMU: the log's, corrected by ``calib``, its units
    checked."""
    from imuslam.errors import InputError
    from imuslam.io.datasets import open_dataset
    from imuslam.io.plausible import check_stamps, check_units

    if calib is not None and not cfg.use_imu:
        raise InputError(
            "--calib: it corrects the IMU, which --no-imu leaves out; give one of them"
        )
    log_ = open_dataset(log_path, "laser", fmt=fmt, scan_topic=scan_topic, imu_topic=imu_topic,
                        odom_topic=odom_topic, use_imu=cfg.use_imu)  # fmt: skip
    check_stamps(log_.t_ns, "scans", str(log_path))
    imu = log_.imu()
    if calib is not None:
        if imu is None:
            raise InputError(f"--calib: {log_path} has no IMU to correct")
        from imuslam.imu.model import ImuCalibration

        imu = ImuCalibration.load_yaml(calib).correct(imu)
    if imu is not None and cfg.use_imu:
        check_units(imu, hint="check the log's IMU units, or map without it (--no-imu)")
    return log_, imu


def _summary_rows(
    s: dict[str, Any], warnings: dict[str, int], wall: float, metrics: dict[str, Any] | None
) -> list[list[str]]:
    """The terminal table: the run's summary, its warnings and the errors against a reference."""
    rows = [
        ["scans", f"{s['scans']}", ""], ["log duration", f"{s['log_duration_s']:.1f}", "s"],
        ["path length", f"{s['path_length_m']:.1f}", "m"], ["nodes / submaps", f"{s['nodes']} / {s['submaps']}", ""],
        ["loop constraints", f"{s['loop_constraints']} of {s['loop_searches']} searches", ""],
        ["mean match score", f"{s['mean_match_score']:.3f}", "probability"],
        ["time", f"{wall:.1f}", "s"], ["faster than real time", f"{s['faster_than_real_time']:.1f}", "x"],
    ]  # fmt: skip
    for k, v in warnings.items():
        rows.append([k, f"{v}", "count"])
    for name in ("slam", "odometry"):
        m = metrics.get(name) if metrics is not None else None
        if m is None or metrics is None:
            continue
        if metrics["kind"] == "kuemmerle2009_relations":
            rows.append([f"{name}: relation error (Kümmerle 2009)",
                         f"{m['trans_mean']:.3f} ± {m['trans_std']:.3f} m, {m['rot_mean_deg']:.2f} ± {m['rot_std_deg']:.2f}", "m, deg"])  # fmt: skip
            rows.append([f"{name}: ATE after SE(2) alignment (RMSE, largest)",
                         f"{m['ate_rmse_m']:.3f}, {m['ate_max_m']:.3f}", "m"])  # fmt: skip
            for key, r in metrics.get("sets", {}).items():
                if name in r:
                    q = r[name]
                    rows.append([f"{name}: relation error, {key} relations ({q['n']})",
                                 f"{q['trans_mean']:.3f} ± {q['trans_std']:.3f} m, {q['rot_mean_deg']:.2f} ± {q['rot_std_deg']:.2f}", "m, deg"])  # fmt: skip
        else:
            rows.append([f"{name}: ATE RMSE", f"{m['ate_rmse_m']:.3f}", "m"])
            rows.append([f"{name}: RPE per metre", f"{m['rpe_trans_rmse_m_per_m']:.3f}", "m"])
    return rows
