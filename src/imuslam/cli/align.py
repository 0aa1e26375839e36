"""``imuslam align``: INS alignment of an IMU log (coarse, Kalman, strong tracking or RWNN), a thin
body over :class:`imuslam.ins.pipeline.AlignPipeline`."""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import Any

import typer

from imuslam.cli import validate
from imuslam.cli.common import (
    FORMAT_HELP,
    RRD_HELP,
    VIEWER_HELP,
    ImuFormatChoice,
    console,
    friendly_errors,
    load_log,
    table,
)
from imuslam.errors import InputError


class Method(StrEnum):
    coarse = "coarse"
    kf = "kf"
    stkf = "stkf"
    rwnn = "rwnn"


class TrajFormat(StrEnum):
    auto = "auto"
    tum = "tum"
    kitti = "kitti"
    euroc = "euroc"
    bag = "bag"


class Init(StrEnum):
    auto = "auto"
    coarse = "coarse"
    aiding = "aiding"


class AccelUnit(StrEnum):
    m_s2 = "m/s^2"
    g = "g"


class GyroUnit(StrEnum):
    rad_s = "rad/s"
    deg_s = "deg/s"


def _record(res: Any, name: str, rrd: Path | None, viewer: bool) -> None:
    """With --rrd / --viewer: the alignment's estimates in a recording (:mod:`imuslam.viz.align`)."""
    if rrd is None and not viewer:
        return
    from imuslam.viz.align import log_alignment
    from imuslam.viz.recording import open_recording

    with open_recording(name, rrd, viewer) as rec:
        log_alignment(rec, res)


def _trajectory_format(path: Path, fmt: str) -> str:
    if fmt != "auto":
        return fmt
    if path.is_dir() or path.suffix in (".bag", ".mcap", ".db3"):
        return "bag"
    return "euroc" if path.suffix == ".csv" else "tum"


def register(app: typer.Typer) -> None:
    @app.command("align")
    @friendly_errors
    def align_cmd(
        log_path: Path = typer.Argument(
            ..., metavar="LOG", help="IMU log (SI, g or deg/s; calibrated)"
        ),
        method: Method = typer.Option(Method.kf, help="coarse, kf, stkf or rwnn"),
        aiding: str = typer.Option(
            "zupt",
            help="'zupt' (the IMU stands still) or a trajectory of the IMU frame (TUM, EuRoC csv, bag) "
            "whose positions aid the filter",
        ),
        aiding_format: TrajFormat = typer.Option(
            TrajFormat.auto, help="auto, tum, euroc, kitti or bag"
        ),
        aiding_topic: str | None = typer.Option(None, help="pose topic of an aiding bag"),
        aiding_std: float = typer.Option(
            0.01, help="aiding 1-sigma: m/s for zupt, m for positions", callback=validate.positive()
        ),
        init: Init = typer.Option(
            Init.auto,
            help="initial state: 'coarse' (levelling on a still start), 'aiding' (the trajectory's first "
            "pose) or 'auto' (coarse for zupt, aiding for a trajectory)",
        ),
        noise: str = typer.Option(
            "auto",
            help="IMU white noise: 'auto' (as the log shows it, vibration included), 'datasheet' "
            "(defaults) or a Kalibr imu.yaml (as `imuslam allan` writes)",
        ),
        g: float = typer.Option(
            9.80665, "--g", help="gravity magnitude, m/s^2", callback=validate.gravity()
        ),
        t_still: float = typer.Option(
            5.0, help="seconds of still start used for levelling", callback=validate.positive("s")
        ),
        lat_deg: float | None = typer.Option(
            None,
            help="latitude, for gyrocompassing (coarse)",
            callback=validate.number(-90, 90, unit="deg", what="a latitude"),
        ),
        heading_deg: float | None = typer.Option(
            None,
            help="initial yaw from another source (compass, a known pose): deg, counter-clockwise from east (ENU)",
            callback=validate.number(-360, 360, unit="deg", what="a heading"),
        ),
        truth: Path | None = typer.Option(
            None,
            help="ground-truth state (EuRoC state csv with biases): plotted and compared",
        ),
        fmt: ImuFormatChoice = typer.Option(ImuFormatChoice.auto, "--format", help=FORMAT_HELP),
        topic: str | None = typer.Option(None, help="IMU topic of a bag"),
        accel_unit: AccelUnit | None = typer.Option(None, help="m/s^2 or g (guessed if absent)"),
        gyro_unit: GyroUnit | None = typer.Option(None, help="rad/s or deg/s (guessed if absent)"),
        columns: str | None = typer.Option(
            None, help="CSV column mapping: t=..,ax=..,ay=..,az=..,gx=..,gy=..,gz=.."
        ),
        out: Path = typer.Option(
            Path("align_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
        plots: bool = typer.Option(
            True, "--plots/--no-plots", help="write biases.png (and the error)"
        ),
        rrd: Path | None = typer.Option(None, "--rrd", help=RRD_HELP),
        viewer: bool = typer.Option(False, "--viewer", help=VIEWER_HELP),
    ) -> None:
        """Estimate attitude and the IMU's remaining biases; write them, plots and the corrected IMU."""
        from imuslam.ins.kf import KfNoise
        from imuslam.ins.pipeline import AlignConfig, AlignDataset, AlignPipeline
        from imuslam.io.plausible import check_at_rest, check_units
        from imuslam.io.trajectory import read_euroc_state, read_trajectory

        _check_sources(init, aiding, noise)
        cfg = AlignConfig(method=method.value, aiding_std=aiding_std, init=init.value, noise=noise, g=g,
                          t_still_s=t_still, lat_deg=lat_deg, heading_deg=heading_deg)  # fmt: skip
        au = None if accel_unit is None else accel_unit.value
        gu = None if gyro_unit is None else gyro_unit.value
        full = load_log(log_path, None, fmt.value, topic, au, gu, columns)
        check_units(full, hint="give --accel-unit / --gyro-unit")
        if aiding == "zupt" or init == Init.coarse:  # levelled on a still start
            check_at_rest(full, t_still, hint="give --gyro-unit, or --t-still")
        full = full.to_si()
        tr = None
        if aiding != "zupt":
            ap = Path(aiding)
            tr = read_trajectory(ap, _trajectory_format(ap, aiding_format.value), aiding_topic)
        kalibr = None if noise in ("auto", "datasheet") else KfNoise.from_kalibr_yaml(noise)
        truth_state = None if truth is None else read_euroc_state(truth)
        pipeline = AlignPipeline(AlignDataset(full, tr, truth_state, kalibr), cfg)
        res = pipeline.run()
        _record(res, f"imuslam align {log_path.name}", rrd, viewer)
        inputs = {
            "log": str(log_path),
            "aiding": aiding,
            "truth": None if truth is None else str(truth),
        }
        if res.coarse is not None:
            _print_coarse(res.coarse)
            files = pipeline.save(res, out, plots, None, **inputs)
            console.print(f"wrote {out}/{', '.join(files)}")
            return
        _print_alignment(res, method.value)
        corrected_imu = _corrected_writer(log_path, fmt.value, topic, full, res.alignment)
        files = pipeline.save(res, out, plots, corrected_imu, **inputs)
        console.print(f"wrote {out}/{', '.join(files)}")


def _check_sources(init: Init, aiding: str, noise: str) -> None:
    """--aiding and --noise name what exists, and --init aiding has a trajectory to start from."""
    if init == Init.aiding and aiding == "zupt":
        raise InputError("--init aiding needs a trajectory as --aiding")
    if aiding != "zupt" and not Path(aiding).exists():
        raise InputError(f"--aiding {aiding}: no such file; expected 'zupt' or a trajectory")
    if noise not in ("auto", "datasheet") and not Path(noise).is_file():
        raise InputError(
            f"--noise {noise}: no such file; expected auto, datasheet or a Kalibr imu.yaml"
        )


def _print_coarse(ca: Any) -> None:
    import numpy as np

    rows = [["roll", f"{np.rad2deg(ca.roll):.3f}", f"{np.rad2deg(ca.roll_pitch_std):.2g}", "deg"],
            ["pitch", f"{np.rad2deg(ca.pitch):.3f}", f"{np.rad2deg(ca.roll_pitch_std):.2g}", "deg"],
            ["yaw", "unobservable" if ca.yaw is None else f"{np.rad2deg(ca.yaw):.2f}",
             "-" if ca.yaw_std is None else f"{np.rad2deg(ca.yaw_std):.2g}", "deg"]]  # fmt: skip
    console.print(table("Coarse alignment", ["quantity", "value", "1-sigma", "unit"], rows))
    console.print(ca.reason)


def _print_alignment(res: Any, method: str) -> None:
    """The noise used, then the biases at the end with their 1-sigma (and the truth, when given), and
    the final attitude error against the truth (heading and tilt)."""
    import numpy as np

    a, kn = res.alignment, res.noise
    assert a is not None and kn is not None
    console.print(
        f"IMU white noise {kn.accel:.3g} m/s^2/sqrt(Hz), {kn.gyro:.3g} rad/s/sqrt(Hz) "
        f"({res.noise_source}); bias random walks {kn.accel_bias_rw:.3g} m/s^3/sqrt(Hz), "
        f"{kn.gyro_bias_rw:.3g} rad/s^2/sqrt(Hz)"
    )
    tb, tbg = res.truth_accel_bias, res.truth_gyro_bias
    cols = (
        ["quantity", "estimate", "1-sigma"]
        + (["truth", "|err|/sigma"] if tb is not None else [])
        + ["unit"]
    )
    rows = []
    for name, est, sd, tru, unit, f in (
        ("accel bias", a.accel_bias, a.accel_bias_std, tb, "m/s^2", "{:+.5f}"),
        ("gyro bias", a.gyro_bias, a.gyro_bias_std, tbg, "rad/s", "{:+.6f}"),
    ):
        for j in range(3):
            row = [f"{name} {'xyz'[j]}", f.format(est[-1, j]), f"{sd[-1, j]:.2g}"]
            if tru is not None:
                row += [f.format(tru[-1, j]), f"{abs(est[-1, j] - tru[-1, j]) / sd[-1, j]:.1f}"]
            rows.append(row + [unit])
    console.print(table(f"Alignment ({method}, {res.aiding_kind} aiding)", cols, rows))
    att = getattr(res, "attitude_error_deg", None)
    if att is not None and len(att):
        x, y, z = (float(v) for v in att[-1])
        console.print(
            f"final attitude error against the truth: heading {z:+.3f} deg, tilt "
            f"{float(np.hypot(x, y)):.3f} deg (roll {x:+.3f}, pitch {y:+.3f})"
        )


def _corrected_writer(
    log_path: Path, fmt: str, topic: str | None, full: Any, a: Any
) -> Callable[[Path], list[str]]:
    """Writes the corrected IMU into the results folder: a bag stays a bag (a copy with the IMU topic
    replaced, every other message untouched), anything else becomes EuRoC csv."""
    from imuslam.io.load import detect_format, write_imu

    def corrected_imu(folder: Path) -> list[str]:
        if detect_format(log_path) == "bag" and fmt in ("auto", "bag"):
            dst = folder / ("corrected_imu" + (log_path.suffix if log_path.is_file() else ""))
            t_topic = topic or full.source.rsplit(":", 1)[-1]
            write_imu(a.corrected(full), dst, "bag", template=log_path, topic=t_topic)
            return [f"{dst.name} (the input bag, {t_topic} corrected)"]
        write_imu(a.corrected(full), folder / "corrected_imu.csv", "euroc")
        return ["corrected_imu.csv (EuRoC format)"]

    return corrected_imu
