"""``imuslam lio``: LiDAR-inertial odometry and mapping from a bag (or LiDAR-only from PCD / KITTI
folders): trajectory.tum, map.ply / map.pcd, config.yaml, scans.csv, trajectory.png, metrics.json."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from imuslam.cli.common import console, friendly_errors, table


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
        state: str | None = typer.Option(
            None, "--state", help="reduced (12, corrected IMU) or full (18)"
        ),
        mode: str | None = typer.Option(None, "--mode", help="features (LOAM) or direct"),
        align: str | None = typer.Option(None, "--align", help="none, kf, stkf or rwnn"),
        no_imu: bool = typer.Option(False, "--no-imu", help="LiDAR-only (constant-velocity model)"),
        max_scans: int | None = typer.Option(
            None, min=2, help="stop after this many scans (at least 2: a scan and its motion)"
        ),
    ) -> None:
        """LiDAR-inertial odometry (iterated ESKF) with a voxel map; LiDAR-only without an IMU."""
        os.environ.setdefault("OMP_NUM_THREADS", "1")  # before pykdtree loads its OpenMP pool
        import numpy as np

        from imuslam.config import load_config
        from imuslam.errors import InputError
        from imuslam.lio.config import LioConfig
        from imuslam.lio.pipeline import LioPipeline
        from imuslam.lio.report import write_results

        cfg = load_config(config, LioConfig) if config is not None else LioConfig()
        upd: dict[str, object] = {}
        for opt, val, allowed in (("--state", state, ("reduced", "full")), ("--mode", mode, ("features", "direct")),
                                  ("--align", align, ("none", "kf", "stkf", "rwnn"))):  # fmt: skip
            if val is not None and val not in allowed:
                raise InputError(f"{opt}: '{val}'; expected {' or '.join(allowed)}")
        if state is not None:
            cfg.filter.state = state  # type: ignore[assignment]
        if mode is not None:
            cfg.frontend.mode = mode  # type: ignore[assignment]
        if align is not None:
            upd["align"] = align
        if no_imu:
            upd["use_imu"] = False
        cfg = cfg.model_copy(update=upd)
        if not source.exists():
            raise InputError(f"{source}: no such bag or folder")
        truth = None
        if source.is_dir() and any(source.glob("*.pcd")):
            from imuslam.lio.datasets import PcdFolder

            data: object = PcdFolder(source)
        elif source.is_dir() and (any(source.glob("*.bin")) or (source / "velodyne").is_dir()):
            from imuslam.lio.datasets import KittiFolder

            data = KittiFolder(source)
        else:
            from imuslam.lio.datasets import BagLidarDataset

            data = BagLidarDataset(source, points_topic, imu_topic, use_imu=cfg.use_imu)
            if (
                gt is not None and gt.startswith("/") and not Path(gt).exists()
            ):  # a topic, not a file
                from imuslam.io.bag import Bag

                with Bag(source) as b:
                    truth = b.trajectory(gt)
        if gt is not None and truth is None:
            from imuslam.io.trajectory import read_trajectory

            truth = read_trajectory(Path(gt), "tum")
        imu = data.imu()  # type: ignore[attr-defined]
        if imu is not None and calib is not None:
            from imuslam.imu.model import ImuCalibration

            imu = ImuCalibration.load_yaml(calib).correct(imu)
        if imu is not None:
            from imuslam.io.plausible import check_units

            check_units(
                imu, hint="a sensor_msgs/Imu carries m/s^2 and rad/s (convert the bag's IMU)"
            )
            span = (imu.t_ns[0], imu.t_ns[-1])
            console.print(f"IMU {imu.source}: {len(imu)} samples, {imu.rate_hz:.0f} Hz, "
                          f"{(span[1] - span[0]) * 1e-9:.1f} s")  # fmt: skip
        res = LioPipeline(data, cfg, imu=imu, max_scans=max_scans).run()  # type: ignore[arg-type]
        metrics = write_results(res, out, truth)
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
                rows.append(
                    ["KITTI drift (100-800 m)", f"{metrics['kitti_mean_trans_pct']:.4g}", "%"]
                )
        console.print(table(f"imuslam lio {source}", ["quantity", "value", "unit"], rows))
        for w in res.warnings:
            console.print(f"warning: {w}", markup=False, highlight=False, soft_wrap=True)
        console.print(f"wrote {out}/trajectory.tum, map.ply, map.pcd, config.yaml, scans.csv, trajectory.png"
                      + (", metrics.json" if metrics else ""))  # fmt: skip
