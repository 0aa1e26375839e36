"""``imuslam calibrate-lidar``: the LiDAR pose on the IMU and the LiDAR clock offset from a bag, without
a target (``imuslam.lio.extrinsic``): lio_config.yaml for ``imuslam lio --config``, metrics.json with
values, 1-sigma and the observability verdict, config.yaml (the settings of this run)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import typer

from imuslam.cli import validate
from imuslam.cli.common import console, friendly_errors, table


def register(app: typer.Typer) -> None:
    @app.command("calibrate-lidar")
    @friendly_errors
    def calibrate_lidar_cmd(
        bag: Path = typer.Argument(..., help="ROS 1 / ROS 2 / MCAP bag with PointCloud2 and Imu"),
        imu_topic: str | None = typer.Option(None, "--imu-topic", help="sensor_msgs/Imu topic"),
        points_topic: str | None = typer.Option(
            None, "--points-topic", help="sensor_msgs/PointCloud2 topic"
        ),
        out: Path = typer.Option(
            Path("lidar_calib_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
        config: Path | None = typer.Option(
            None, "--config", help="LioConfig YAML: the starting extrinsic and offset"
        ),
        calib: Path | None = typer.Option(
            None, "--calib", help="IMU calibration.yaml, applied first"
        ),
        duration: float | None = typer.Option(
            None,
            "--duration",
            help="use the first N seconds of the scans, s",
            callback=validate.positive("s"),
        ),
        search: float = typer.Option(
            0.2,
            "--search",
            help="clock offsets searched around the start's, +- s",
            callback=validate.positive("s", hi=5.0),
        ),
    ) -> None:
        """Calibrate the LiDAR pose on the IMU and the clock offset without a target (LI-Init's method)."""
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        from imuslam.config import load_config
        from imuslam.io.results import write_results
        from imuslam.lio.config import LioConfig
        from imuslam.lio.extrinsic import calibrate_lidar_imu
        from imuslam.threads import blas_threads

        cfg = load_config(config, LioConfig) if config is not None else LioConfig()
        data, scans, imu = _recording(bag, points_topic, imu_topic, calib, duration, search, cfg)
        console.print(
            f"{len(scans)} scans of {data.points_topic}, {len(imu)} IMU samples of {data.imu_topic}"
        )
        with blas_threads(1):
            res = calibrate_lidar_imu(scans, imu, cfg, search_s=search)
        lio_cfg = cfg.model_copy(update={"extrinsic": res.extrinsic()})
        settings = {"bag": str(bag), "imu_topic": data.imu_topic, "points_topic": data.points_topic,
                    "config": None if config is None else str(config), "calib": None if calib is None else str(calib),
                    "duration_s": duration, "search_s": search, "start": cfg.model_dump(mode="json")}  # fmt: skip

        def extra(folder: Path) -> None:
            import yaml

            from imuslam.io.atomic import write_atomic

            text = res.yaml_header() + yaml.safe_dump(
                lio_cfg.model_dump(mode="json"), sort_keys=False
            )
            write_atomic(folder / "lio_config.yaml", text)

        write_results(out, config=settings, metrics=res.to_dict(), extra=extra)
        _print_result(res, bag)
        console.print(
            f"wrote {out}/lio_config.yaml (for imuslam lio --config), metrics.json, config.yaml"
        )


def _recording(
    bag: Path, points_topic: str | None, imu_topic: str | None, calib: Path | None,
    duration: float | None, search: float, cfg: Any,
) -> tuple[Any, list[Any], Any]:  # fmt: skip
    """The bag's scans (the first ``duration`` s) and the IMU around them, corrected by ``calib``."""
    import numpy as np

    from imuslam.errors import InputError
    from imuslam.io.datasets import open_dataset
    from imuslam.io.lidarsets import BagLidarDataset

    data = open_dataset(bag, "lidar", points_topic=points_topic, imu_topic=imu_topic)
    if not isinstance(data, BagLidarDataset):
        raise InputError(f"{bag}: a folder of scans has no IMU; expected a bag with an Imu topic")
    imu = data.imu()
    if imu is None:
        raise InputError(f"{bag}: no sensor_msgs/Imu topic; name one with --imu-topic")
    if calib is not None:
        from imuslam.imu.model import ImuCalibration

        imu = ImuCalibration.load_yaml(calib).correct(imu)
    scans = []
    t_first: int | None = None
    for s in data.lidar_scans():
        t_first = s.t_ns if t_first is None else t_first
        if duration is not None and (s.t_ns - t_first) * 1e-9 > duration:
            break
        scans.append(s)
    if len(scans) < 20:
        raise InputError(
            f"{bag}:{data.points_topic}: {len(scans)} scans; the calibration needs at least 20"
        )
    if duration is not None:
        lo = scans[0].t_ns - int((search + abs(cfg.extrinsic.time_offset_s) + 1.0) * 1e9)
        hi = scans[-1].t_ns + int((search + abs(cfg.extrinsic.time_offset_s) + 1.0) * 1e9)
        i0, i1 = np.searchsorted(imu.t_ns, [lo, hi])
        imu = imu.slice(int(i0), int(i1))
    return data, scans, imu


def _print_result(res: Any, bag: Path) -> None:
    """The estimate with its 1-sigma and whether the motion excited each direction (yes; weak: 1-sigma
    above the accuracy target; NO: unobservable, held at the start); a warning per weak or unexcited
    direction."""
    from imuslam.lio.extrinsic import AXES

    rows = [[f"lever arm p_i_l {a}", f"{res.p_i_l[k]:.4f}", f"{res.sigma_p_m[k]:.4f}", "m",
             res.verdict("p", k)] for k, a in enumerate(AXES)]  # fmt: skip
    rpy = res.rpy_deg_i_l
    rows += [[f"R_i_l {n} (Z-Y-X Euler)", f"{rpy[k]:.3f}", "", "deg", ""]
             for k, n in enumerate(("roll", "pitch", "yaw"))]  # fmt: skip
    rows += [[f"R_i_l rotation about IMU {a}", "", f"{res.sigma_rot_deg[k]:.3f}", "deg",
              res.verdict("rot", k)] for k, a in enumerate(AXES)]  # fmt: skip
    rows += [
        ["clock offset t_imu - t_lidar", f"{res.time_offset_s * 1e3:.2f}",
         f"{res.sigma_time_offset_s * 1e3:.2f}", "ms", res.verdict("time")],
        ["gyro residual RMS", f"{res.rms_gyro:.4f}", "", "rad/s", ""],
        ["accelerometer residual RMS", f"{res.rms_accel:.4f}", "", "m/s^2", ""],
        ["scans used", f"{res.n_scans}", "", "", ""],
        ["time span", f"{res.duration_s:.1f}", "", "s", ""],
    ]  # fmt: skip
    cols = ["parameter", "value", "1-sigma", "unit", "observed"]
    console.print(table(f"imuslam calibrate-lidar {bag}", cols, rows))
    for u in res.unobservable:
        console.print(
            f"warning: not excited by the motion: {u}",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    for w in res.weakly_observed:
        console.print(f"warning: weakly observed (the value is the data's, its accuracy is not "
                      f"promised): {w}", markup=False, highlight=False, soft_wrap=True)  # fmt: skip
    if not res.observable:
        console.print("warning: the parameters marked NO keep (about) their starting values; record a "
                      "motion that turns about all three axes", markup=False, highlight=False, soft_wrap=True)  # fmt: skip
