"""``imuslam vio``: stereo visual odometry fused with the IMU in an EKF (non-holonomic constraints,
chi-square gating); fused, VO-only and IMU-only trajectories, metrics (gating, frames, errors against a reference) and plots."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from imuslam.cli import validate
from imuslam.cli.common import (
    RRD_HELP,
    VIEWER_HELP,
    console,
    friendly_errors,
    progress_option,
    show_progress,
    table,
)

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from imuslam.interfaces import StereoSource, Trajectory
    from imuslam.vio.config import VioConfig


def register(app: typer.Typer) -> None:
    @app.command("vio")
    @friendly_errors
    def vio_cmd(
        dataset: str = typer.Argument(
            ...,
            help="EuRoC folder (mav0/cam0, cam1, imu0), a bag (.bag, .mcap, ROS 2 folder) with "
            "--camchain and the topics, or 'sim' for the rendered simulated robot",
        ),
        left_topic: str | None = typer.Option(None, help="bag: left Image / CompressedImage topic"),
        right_topic: str | None = typer.Option(None, help="bag: right image topic"),
        imu_topic: str | None = typer.Option(None, help="bag: Imu topic (default: the only one)"),
        out: Path = typer.Option(Path("vio_out"), "--out", help="results folder"),
        camchain: Path | None = typer.Option(
            None, help="Kalibr camchain YAML (instead of sensor.yaml)"
        ),
        calib: Path | None = typer.Option(
            None, "--calib", help="IMU calibration.yaml, applied first"
        ),
        gt: Path | None = typer.Option(
            None, "--gt", help="ground truth (TUM, EuRoC csv) for ATE/RPE"
        ),
        gt_format: str = typer.Option(
            "auto",
            help="tum, euroc or auto (by content)",
            callback=validate.choice(("auto", "tum", "euroc")),
        ),
        align: str = typer.Option(
            "se3",
            help="ATE alignment: se3, sim3, yaw, first (short or static runs)",
            callback=validate.choice(("se3", "sim3", "yaw", "first")),
        ),
        config: Path | None = typer.Option(
            None, "--config", help="VioConfig YAML (keys = field names)"
        ),
        nhc: bool | None = typer.Option(None, "--nhc/--no-nhc", help="non-holonomic constraints"),
        detector: str | None = typer.Option(None, help="sift or orb"),
        g: float | None = typer.Option(
            None, help="local gravity, m/s^2", callback=validate.gravity()
        ),
        sim_duration: float = typer.Option(
            20.0,
            help="sim: seconds of rendered driving (1 to 3600)",
            callback=validate.number(1.0, 3600.0, unit="s", what="a duration"),
        ),
        sim_rate: float = typer.Option(
            20.0,
            help="sim: stereo frames per second (1 to 100)",
            callback=validate.number(1.0, 100.0, unit="Hz", what="a camera frame rate"),
        ),
        seed: int = typer.Option(
            0, help="sim: random seed", callback=validate.integer(0, validate.SEED_MAX)
        ),
        outliers: float = typer.Option(
            0.0,
            help="corrupt this share of the VO measurements (study)",
            callback=validate.number(0.0, 1.0, hi_open=True, what="a share"),
        ),
        progress: bool = progress_option(),
        rrd: Path | None = typer.Option(None, "--rrd", help=RRD_HELP),
        viewer: bool = typer.Option(False, "--viewer", help=VIEWER_HELP),
    ) -> None:
        """Stereo VO + IMU EKF: trajectory.tum (fused), vo.tum, imu.tum, metrics.json, plots."""
        from tqdm import tqdm

        from imuslam.vio.pipeline import VioPipeline

        cfg = _config(config, nhc, g, outliers, detector)
        data, truth, times = _open(dataset, camchain, left_topic, right_topic, imu_topic,
                                   (sim_duration, sim_rate, seed))  # fmt: skip
        imu = data.imu()
        if calib is not None:
            from imuslam.imu.model import ImuCalibration

            imu = ImuCalibration.load_yaml(calib).correct(imu.to_si())
        if dataset != "sim":
            from imuslam.io.plausible import check_units

            check_units(imu, hint="EuRoC's imu0 and a sensor_msgs/Imu carry m/s^2 and rad/s")
        if gt is not None:
            from imuslam.io.trajectory import read_trajectory

            truth = read_trajectory(gt, gt_format)  # auto: TUM or EuRoC csv by content
        pipeline = VioPipeline(data, cfg, imu=imu)
        from imuslam.viz.recording import open_recording

        with (
            open_recording(f"imuslam vio {dataset}", rrd, viewer) as rec,
            tqdm(
                total=len(data), unit="frame", desc="vio", disable=not show_progress(progress)
            ) as bar,
        ):
            obs = _observer(rec, imu, calib is not None)
            res = pipeline.run(bar.update, obs)  # type: ignore[arg-type]  # tqdm's update returns a flag
            if obs is not None:
                obs.finish(res, truth)
        ev = None
        if truth is not None:
            ev = pipeline.evaluate(res, truth, times, align)
            _print_errors(ev, f"against {truth.source} ({align} aligned, at the frame times)")
        _print_summary(res.summary())
        pipeline.save(res, out, truth, ev)
        console.print(
            f"wrote {out}/trajectory.tum, vo.tum, imu.tum, metrics.json, config.yaml, plots"
        )


def _open(
    dataset: str, camchain: Path | None, left_topic: str | None, right_topic: str | None,
    imu_topic: str | None, sim: tuple[float, float, int],
) -> tuple[StereoSource, Trajectory | None, NDArray[np.int64] | None]:  # fmt: skip
    """The dataset (``sim``: the rendered robot, for ``sim`` = (duration s, frame rate Hz, seed); else
    the reader ``io.datasets.open_dataset`` picks), its ground truth when it has one, and the frame
    times to score the tracks at (None: the VO's own times)."""
    if dataset == "sim":
        from imuslam.errors import InputError
        from imuslam.sim.stereo_run import SimStereoRun, StereoRunConfig

        duration, rate, seed = sim
        if duration * rate < 3:
            raise InputError(
                f"--sim-duration {duration:g} s at --sim-rate {rate:g} Hz renders "
                f"{int(duration * rate)} frame(s); the VO needs at least 3"
            )
        run = SimStereoRun(StereoRunConfig(duration_s=duration, image_hz=rate, seed=seed))
        return run, run.truth(), run.t_frames_ns
    from imuslam.io.datasets import open_dataset
    from imuslam.io.stereosets import EurocStereo

    data = open_dataset(dataset, "stereo", imu_topic=imu_topic, camchain=camchain,
                        left_topic=left_topic, right_topic=right_topic)  # fmt: skip
    return data, None, data.t_ns if isinstance(data, EurocStereo) else None


def _observer(rec: Any, imu: Any, calibrated: bool) -> Any:
    """The recording's per-pair logger, the IMU logged first; None without a recording."""
    if rec is None:
        return None
    from imuslam.viz.lio import log_imu
    from imuslam.viz.vio import VioLogger

    log_imu(rec, imu, "imu/corrected" if calibrated else "imu/raw")
    return VioLogger(rec)


def _config(
    config: Path | None, nhc: bool | None, g: float | None, outliers: float, detector: str | None
) -> VioConfig:
    """The effective configuration: the --config file's fields, then the options given."""
    from pydantic import ValidationError

    from imuslam.config import describe_validation_error
    from imuslam.errors import InputError
    from imuslam.vio.config import VioConfig

    cfg_d: dict[str, Any] = {}
    if config is not None:
        from imuslam.io.yamlfile import read_yaml

        cfg_d = read_yaml(config, "a mapping of VioConfig fields (--config)", empty={})
    if nhc is not None:
        cfg_d["nhc"] = nhc
    if g is not None:
        cfg_d["g"] = g
    if outliers:
        cfg_d["outlier_fraction"] = outliers
    if detector is not None:
        if detector not in ("sift", "orb"):
            raise InputError(f"--detector: '{detector}'; expected sift or orb")
        cfg_d.setdefault("vo", {})["detector"] = detector
    try:
        return VioConfig.model_validate(cfg_d)
    except ValidationError as exc:
        raise InputError(f"{config or 'options'}: {describe_validation_error(exc)}") from None


def _print_errors(ev: dict[str, Any], title: str) -> None:
    rows = [
        [k, f"{v.ape_trans.rmse:.4g}", f"{v.rpe_trans.rmse:.4g}", f"{v.ape_rot_deg.rmse:.3g}", str(v.n_pairs)]
        for k, v in ev.items()
    ]  # fmt: skip
    console.print(
        table(title, ["quantity", "ATE [m]", "RPE/frame [m]", "ATE rot [deg]", "poses"], rows)
    )


def _print_summary(summary: dict[str, Any]) -> None:
    rows = []
    for kind, st in summary["gating"].items():
        rows.append([kind, str(st["accepted"]), str(st["rejected"]),
                     f"{st.get('nis_mean_accepted', float('nan')):.3g}", str(st["dof"])])  # fmt: skip
    console.print(
        table(
            "gating",
            ["quantity", "accepted [updates]", "rejected [updates]", "mean NIS", "dof"],
            rows,
        )
    )
    from imuslam.eval.vio_compare import nis_consistency

    for kind, st in summary["gating"].items():
        console.print(nis_consistency(kind, st), markup=False, highlight=False)
    fr = summary["frames"]
    console.print(
        f"frames: {fr['used']} used, {fr['missing']} missing, {fr['unreadable']} unreadable; VO: "
        f"{summary['vo']['measurements']} measurements, {summary['vo']['skipped_few_features']} "
        f"skipped (too few features), {summary['vo']['skipped_few_inliers']} (too few inliers)"
    )
