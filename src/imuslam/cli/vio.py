"""``imuslam vio``: stereo visual odometry fused with the IMU in an EKF (non-holonomic constraints,
chi-square gating); fused, VO-only and IMU-only trajectories, gating statistics and plots."""

from __future__ import annotations

from pathlib import Path

import typer

from imuslam.cli import validate
from imuslam.cli.common import console, friendly_errors, table, write_json


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
            help="tum, euroc or auto (by extension)",
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
    ) -> None:
        """Stereo VO + IMU EKF: trajectory.tum (fused), vo.tum, imu.tum, gating.json, plots."""
        import numpy as np
        import yaml
        from pydantic import ValidationError
        from tqdm import tqdm

        from imuslam.config import describe_validation_error
        from imuslam.errors import InputError
        from imuslam.eval.vio_compare import compare_tracks, plot_vio
        from imuslam.io.results import results_folder
        from imuslam.io.trajectory import read_trajectory, write_tum
        from imuslam.vio.config import VioConfig
        from imuslam.vio.pipeline import run_vio

        if align not in ("se3", "sim3", "yaw", "first"):
            raise InputError(f"--align: '{align}'; expected se3, sim3, yaw or first")
        if dataset == "sim" and sim_duration * sim_rate < 3:
            raise InputError(
                f"--sim-duration {sim_duration:g} s at --sim-rate {sim_rate:g} Hz renders "
                f"{int(sim_duration * sim_rate)} frame(s); the VO needs at least 3"
            )
        cfg_d: dict = {}
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
            cfg = VioConfig.model_validate(cfg_d)
        except ValidationError as exc:
            raise InputError(f"{config or 'options'}: {describe_validation_error(exc)}") from None

        truth = None
        if dataset == "sim":
            from imuslam.sim.stereo_run import SimStereoRun, StereoRunConfig

            data = SimStereoRun(
                StereoRunConfig(duration_s=sim_duration, image_hz=sim_rate, seed=seed)
            )
            truth = data.truth()
            times = data.t_frames_ns
        else:
            from imuslam.vio.calib import read_kalibr_camchain
            from imuslam.vio.dataset import BagStereo, EurocStereo

            cal = read_kalibr_camchain(camchain) if camchain is not None else None
            p = Path(dataset)
            if p.suffix in (".bag", ".mcap", ".db3") or (p / "metadata.yaml").is_file():
                if cal is None or left_topic is None or right_topic is None:
                    raise InputError(
                        f"{p}: a bag needs --camchain, --left-topic and --right-topic (image topics)"
                    )
                data = BagStereo(p, cal, left_topic, right_topic, imu_topic)  # type: ignore[assignment]
                times = None
            else:
                data = EurocStereo(p, cal)  # type: ignore[assignment]
                times = data.t_ns  # type: ignore[attr-defined]
        if calib is not None:
            from imuslam.imu.model import ImuCalibration

            data.imu = ImuCalibration.load_yaml(calib).correct(data.imu.to_si())
        if dataset != "sim":
            from imuslam.io.plausible import check_units

            check_units(data.imu, hint="EuRoC's imu0 and a sensor_msgs/Imu carry m/s^2 and rad/s")
        if gt is not None:
            fmt = gt_format if gt_format != "auto" else ("euroc" if gt.suffix == ".csv" else "tum")
            truth = read_trajectory(gt, fmt)

        with tqdm(total=len(data), unit="frame", desc="vio") as bar:

            def tick(n: int) -> None:
                bar.update(n)

            res = run_vio(data, cfg, tick)
        summary = res.summary()
        tracks = {"fused": res.fused, "vo": res.vo, "imu": res.imu}
        metrics = None
        if truth is not None:
            tt = np.asarray(times) if times is not None else res.vo.t_ns
            ev = compare_tracks(truth, tracks, tt, align=align)
            metrics = {k: v.to_dict() for k, v in ev.items()}
            rows = [
                [k, f"{v.ape_trans.rmse:.4g}", f"{v.rpe_trans.rmse:.4g}", f"{v.ape_rot_deg.rmse:.3g}", str(v.n_pairs)]
                for k, v in ev.items()
            ]  # fmt: skip
            console.print(table(f"against {truth.source} ({align} aligned, at the frame times)",
                                ["quantity", "ATE [m]", "RPE/frame [m]", "ATE rot [deg]", "poses"], rows))  # fmt: skip
        rows = []
        for kind, st in summary["gating"].items():
            rows.append([kind, str(st["accepted"]), str(st["rejected"]),
                         f"{st.get('nis_mean_accepted', float('nan')):.3g}", str(st["dof"])])  # fmt: skip
        console.print(
            table("gating", ["quantity", "accepted", "rejected", "mean NIS", "dof"], rows)
        )
        fr = summary["frames"]
        console.print(
            f"frames: {fr['used']} used, {fr['missing']} missing, {fr['unreadable']} unreadable; VO: "
            f"{summary['vo']['measurements']} measurements, {summary['vo']['skipped_few_features']} "
            f"skipped (too few features), {summary['vo']['skipped_few_inliers']} (too few inliers)"
        )
        with results_folder(out) as tmp:
            write_tum(res.fused, tmp / "trajectory.tum")
            write_tum(res.vo, tmp / "vo.tum")
            write_tum(res.imu, tmp / "imu.tum")
            write_json(tmp / "gating.json", summary)
            if metrics is not None:
                write_json(tmp / "metrics.json", metrics)
            (tmp / "config.yaml").write_text(
                yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
            )
            nis = {
                k: (np.asarray(v.nis), np.asarray(v.accepted_mask, bool), v.dof)
                for k, v in res.gating.items()
            }
            plot_vio(truth, tracks, nis, (res.bias_t_s, res.bias, res.bias_std), str(tmp))
        console.print(
            f"wrote {out}/trajectory.tum, vo.tum, imu.tum, gating.json, config.yaml, plots"
        )
