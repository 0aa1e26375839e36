"""One entry point to read and write IMU logs in every supported format."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from imuslam.errors import InputError
from imuslam.interfaces.imu import AccelUnit, GyroUnit, ImuLog
from imuslam.io.atomic import write_atomic
from imuslam.io.kinds import SourceKind, source_kind
from imuslam.io.readers import TimeUnit, read_csv, read_euroc, read_imutk

ImuFormat = Literal["auto", "imutk", "euroc", "csv", "bag"]
FORMATS = ("auto", "imutk", "euroc", "csv", "bag")


def detect_format(path: str | Path) -> ImuFormat:
    """Format from the path: ``.bag``/``.mcap``/a ROS 2 bag folder -> bag; a EuRoC folder or a csv with
    EuRoC's header -> euroc; anything else -> imu_tk text."""
    p = Path(path)
    kind = source_kind(p)
    if kind is SourceKind.BAG:
        return "bag"
    if kind is SourceKind.EUROC:
        return "euroc"
    if p.is_dir():
        raise InputError(f"{p}: a folder that is neither a ROS 2 bag nor a EuRoC dataset")
    if p.suffix == ".csv":
        try:
            with open(p, encoding="utf-8", errors="replace") as fh:
                head = fh.readline(4096)  # the reader reports what is not text, naming the line
        except OSError as exc:
            raise InputError(f"{p}: cannot read ({exc.strerror})") from None
        if head.startswith("#timestamp") or "w_RS_S_x" in head:
            return "euroc"
    return "imutk"


def load_imu(
    acc_path: str | Path,
    gyro_path: str | Path | None = None,
    fmt: ImuFormat = "auto",
    topic: str | None = None,
    accel_unit: AccelUnit | None = None,
    gyro_unit: GyroUnit | None = None,
    columns: dict[str, str | int] | None = None,
    time_unit: TimeUnit | None = None,
) -> ImuLog:
    """Read an IMU log. ``gyro_path`` only for imu_tk text in two files; ``columns`` for generic CSV."""
    if fmt not in FORMATS:
        raise InputError(
            f"{acc_path}: unknown format '{fmt}'; expected one of {', '.join(FORMATS)}"
        )
    if not Path(acc_path).exists():
        raise InputError(f"{acc_path}: no such file")
    f = detect_format(acc_path) if fmt == "auto" else fmt
    if f == "bag":
        from imuslam.io.rosbag import read_imu_bag  # rosbags loads only for a bag

        return read_imu_bag(acc_path, topic)
    if f == "euroc":
        return read_euroc(acc_path)
    if f == "csv":
        if not columns:
            raise InputError(
                f"{acc_path}: a generic CSV needs a column mapping (t, ax, ay, az, gx, gy, gz)"
            )
        return read_csv(
            acc_path,
            columns,
            time_unit=time_unit or "auto",
            accel_unit=accel_unit,
            gyro_unit=gyro_unit,
        )
    return read_imutk(
        acc_path, gyro_path, time_unit=time_unit or "s", accel_unit=accel_unit, gyro_unit=gyro_unit
    )


def _rows(t_s: np.ndarray, x: np.ndarray) -> str:
    data = np.column_stack([t_s, x])
    return (
        "\n".join(
            " ".join(f"{v:.9f}" if j == 0 else f"{v:.9g}" for j, v in enumerate(r)) for r in data
        )
        + "\n"
    )


def write_imu(
    log: ImuLog,
    out: str | Path,
    fmt: ImuFormat,
    template: str | Path | None = None,
    topic: str | None = None,
    two_files: bool = False,
) -> list[Path]:
    """Write ``log`` in ``fmt``, atomically; returns the files written.

    imutk: one 7-column file ``t ax ay az gx gy gz`` at ``out``, or with ``two_files`` the folder ``out``
    holding ``acc.txt`` and ``gyro.txt`` (``t x y z``). euroc: EuRoC csv at ``out``. bag: with a
    ``template`` bag, a copy of it with ``topic`` replaced; without, a new bag holding only the IMU.
    """
    o = Path(out)
    t_s = log.t_ns.astype(np.float64) * 1e-9
    if fmt == "imutk" or fmt == "csv":
        if two_files:
            write_atomic(o / "acc.txt", _rows(t_s, log.accel))
            write_atomic(o / "gyro.txt", _rows(t_s, log.gyro))
            return [o / "acc.txt", o / "gyro.txt"]
        write_atomic(o, _rows(t_s, np.hstack([log.accel, log.gyro])))
        return [o]
    if fmt == "euroc":
        if log.accel_unit != "m/s^2" or log.gyro_unit != "rad/s":
            raise InputError(
                f"{log.source}: EuRoC csv holds m/s^2 and rad/s; the log is not in SI units"
            )
        head = (
            "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
            "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
        )
        body = "\n".join(
            f"{int(t)}," + ",".join(f"{v:.17g}" for v in np.concatenate([g, a]))
            for t, g, a in zip(log.t_ns, log.gyro, log.accel, strict=True)
        )
        write_atomic(o, head + body + "\n")
        return [o]
    if fmt == "bag":
        from imuslam.io.rosbag import replace_imu_topic, write_imu_bag

        if template is not None:
            if topic is None:
                raise InputError(f"{template}: name the IMU topic to replace (--topic)")
            replace_imu_topic(template, o, topic, log)
        else:
            write_imu_bag(log, o, topic=topic or "/imu/data")
        return [o]
    raise InputError(f"{o}: cannot write format '{fmt}'")
