"""One entry point to read and write IMU logs in every supported format."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Literal

import numpy as np

from imuslam.errors import InputError
from imuslam.interfaces.imu import AccelUnit, GyroUnit, ImuLog
from imuslam.io.atomic import write_atomic
from imuslam.io.kinds import SourceKind, format_of
from imuslam.io.readers import TimeUnit, read_csv, read_euroc, read_imutk

ImuFormat = Literal["auto", "imutk", "euroc", "csv", "bag", "matlab"]
FORMATS = ("auto", "imutk", "euroc", "csv", "bag", "matlab")
_MAT_V73 = b"MATLAB 7.3 MAT-file"
_MAT_OLD = b"MATLAB 5.0 MAT-file"


def detect_format(path: str | Path) -> ImuFormat:
    """Format from the path: ``.bag``/``.mcap``/a ROS 2 bag folder -> bag; a EuRoC folder or a csv with
    EuRoC's header -> euroc; a MATLAB v7.3 file (by its header, whatever its name) -> matlab; anything
    else -> imu_tk text (imu_tk's own logs are text named .mat)."""
    p = Path(path)
    kind: ImuFormat | None = format_of(
        p,
        {SourceKind.BAG: "bag", SourceKind.EUROC: "euroc"},
        "a folder that is neither a ROS 2 bag nor a EuRoC dataset",
    )
    if kind is not None:
        return kind
    head_bytes = _head(p)
    if head_bytes.startswith(_MAT_V73):
        return "matlab"
    if head_bytes.startswith(_MAT_OLD):
        raise InputError(
            f"{p}: a MATLAB v5 .mat file; imuslam reads v7.3 (save it with save(..., '-v7.3')) or text"
        )
    if p.suffix == ".csv":
        try:
            with open(p, encoding="utf-8", errors="replace") as fh:
                head = fh.readline(4096)  # the reader reports what is not text, naming the line
        except OSError as exc:
            raise InputError(f"{p}: cannot read ({exc.strerror})") from None
        if head.startswith("#timestamp") or "w_RS_S_x" in head:
            return "euroc"
    return "imutk"


def _head(p: Path) -> bytes:
    try:
        with open(p, "rb") as fh:
            return fh.read(len(_MAT_V73))
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None


def _read_matlab(
    acc_path: str | Path,
    gyro_path: str | Path | None,
    accel_unit: AccelUnit | None,
    gyro_unit: GyroUnit | None,
) -> ImuLog:
    """``accelBuffer`` / ``gyroBuffer`` of MATLAB v7.3 files (:mod:`imuslam.io.matlab`): two files, or
    one holding both. Units unless given: the accelerometer's from its magnitude, the gyro's deg/s, the
    buffers' convention (a still gyro's magnitude cannot tell deg/s from rad/s); each said in a
    warning."""
    from imuslam.io.matlab import read_mat_buffers
    from imuslam.io.readers import guess_units

    log_ = read_mat_buffers(acc_path, gyro_path if gyro_path is not None else acc_path)
    warnings = list(log_.warnings)
    if accel_unit is None:
        accel_unit = guess_units(log_.accel, log_.gyro)[0]
        warnings.append(
            f"{log_.source}: accelerometer unit not given; guessed {accel_unit} from the magnitudes"
        )
    if gyro_unit is None:
        gyro_unit = "deg/s"
        warnings.append(
            f"{log_.source}: gyro unit not given; deg/s, the MATLAB buffers' convention "
            "(--gyro-unit to change it)"
        )
    for w in warnings[len(log_.warnings) :]:
        logging.getLogger(__name__).warning(w)
    return ImuLog(log_.t_ns, log_.accel, log_.gyro, accel_unit, gyro_unit, log_.source, warnings)


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
    if f == "matlab":
        return _read_matlab(acc_path, gyro_path, accel_unit, gyro_unit)
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
