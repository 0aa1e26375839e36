"""Trajectories: TUM, KITTI and EuRoC ground-truth files, and PoseStamped topics of bags.

A :class:`~imuslam.interfaces.Trajectory` (re-exported here) holds integer ``t_ns``, positions ``p_w`` (N, 3) and rotations ``R_w_b``
(N, 3, 3) mapping body vectors into the world. Quaternion orders are converted here and only here:
TUM is ``qx qy qz qw``, EuRoC ``qw qx qy qz``.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.trajectory import Trajectory
from imuslam.io.atomic import write_atomic
from imuslam.io.posecheck import MAX_ABS_POSITION_M, check_poses, check_times
from imuslam.io.text import read_table, read_table_ns

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
TrajFormat = Literal["tum", "kitti", "euroc", "bag"]
TRAJ_FORMATS = ("tum", "kitti", "euroc", "bag")

__all__ = [
    "TRAJ_FORMATS",
    "detect_trajectory_format",
    "StateTruth",
    "Trajectory",
    "read_trajectory",
    "write_kitti",
    "write_tum",
]


def _t_ns_from_seconds(
    t: FloatArray, source: str = "", lines: NDArray[np.int64] | None = None
) -> NDArray[np.int64]:
    big = np.abs(t) >= 9.2e9  # int64 nanoseconds end in 2262
    if big.any():
        i = int(np.argmax(big))
        raise InputError(
            f"{source}, line {int(lines[i]) if lines is not None else i}: time {t[i]:g} s is beyond the "
            "int64 nanosecond range (the year 2262); expected seconds"
        )
    t0 = np.floor(t[0]) if len(t) else 0.0
    return (np.int64(t0) * 1_000_000_000 + np.round((t - t0) * 1e9).astype(np.int64)).astype(
        np.int64
    )


_DECIMAL_SECONDS = re.compile(r"([+-]?)(\d+)(?:\.(\d*))?")


def _exact_stamps_ns(path: str | Path, t_ns: NDArray[np.int64], lines: NDArray[np.int64]) -> None:
    """Replace in place the stamps of ``t_ns`` (read at ``lines``, 1-based) by the exact nanoseconds
    of their decimal text: float64 resolves a 1.4e9 s stamp to 238 ns only, so two poses written 128 ns
    apart (an IMU sample beside a camera frame's mid-time) would read as one time. A token in another
    form (an exponent) keeps its float value."""
    from imuslam.io.text import read_text

    text = read_text(path).splitlines()
    for j, ln in enumerate(lines):
        tok = text[int(ln) - 1].replace(",", " ").split(maxsplit=1)[0]
        m = _DECIMAL_SECONDS.fullmatch(tok)
        if m is None:
            continue
        frac = (m.group(3) or "") + "0" * 10
        ns = int(m.group(2)) * 1_000_000_000 + int(frac[:9]) + (frac[9] >= "5")
        t_ns[j] = -ns if m.group(1) == "-" else ns


def read_tum(path: str | Path) -> Trajectory:
    """TUM: ``t x y z qx qy qz qw`` per line (s, m), spaces or commas, '#' comments; stamps exact to
    the nanosecond as written."""
    d, ln = read_table(path, 8)
    q = d[:, [7, 4, 5, 6]]
    t_ns = _t_ns_from_seconds(d[:, 0], str(path), ln)
    _exact_stamps_ns(path, t_ns, ln)
    check_times(t_ns, str(path), ln)
    return Trajectory(t_ns, *check_poses(d[:, 1:4], q, str(path), ln), str(path))


def read_kitti(path: str | Path, times: str | Path | None = None) -> Trajectory:
    """KITTI: a 3x4 pose matrix per line (row-major); times (s) from ``times`` or the line index."""
    d, ln = read_table(path, 12)
    M = d.reshape(-1, 3, 4)
    off = np.abs(np.einsum("nji,njk->nik", M[:, :, :3], M[:, :, :3]) - np.eye(3)).max(axis=(1, 2))
    bad = ~(off <= 0.1) | ~(np.abs(M[:, :, 3]) <= MAX_ABS_POSITION_M).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(
            f"{path}, line {int(ln[i])}: not a pose (the 3x3 part is not a rotation, or the position "
            f"is beyond {MAX_ABS_POSITION_M:g} m)"
        )
    if times is not None:
        t, lt = read_table(times, 1)
        if len(t) != len(d):
            raise InputError(f"{times}: {len(t)} times for {len(d)} poses in {path}")
        t_ns = _t_ns_from_seconds(t[:, 0], str(times), lt)
        check_times(t_ns, str(times), lt)
    else:
        t_ns = np.arange(len(d), dtype=np.int64) * 100_000_000  # one pose per frame, 10 Hz nominal
    return Trajectory(t_ns, M[:, :, 3].copy(), M[:, :, :3].copy(), str(path))


def read_euroc_gt(path: str | Path) -> Trajectory:
    """EuRoC ground truth csv: ``#timestamp [ns], p x y z, q w x y z, ...`` (more columns ignored);
    commas or spaces; the stamps are read as integers, exactly."""
    p = Path(path)
    if p.is_dir():
        p = p / "mav0" / "state_groundtruth_estimate0" / "data.csv" if (p / "mav0").is_dir() else p
    d, ln, t_ns = read_table_ns(p, (8, 11, 14, 17))
    check_times(t_ns, str(p), ln)
    return Trajectory(t_ns, *check_poses(d[:, 1:4], d[:, 4:8], str(p), ln), str(p))


@dataclass
class StateTruth:
    """A ground-truth navigation state over time (EuRoC ``state_groundtruth_estimate0``): t_ns (N,), pose,
    velocity v_w (N, 3) m/s, gyro and accelerometer biases (N, 3) (measured = true + bias)."""

    traj: Trajectory
    v_w: FloatArray
    gyro_bias: FloatArray
    accel_bias: FloatArray


def read_euroc_state(path: str | Path) -> StateTruth:
    """EuRoC ground-truth state csv, 17 columns: t [ns], p xyz, q wxyz, v xyz, gyro bias xyz, accel bias xyz."""
    p = Path(path)
    if p.is_dir():
        p = p / "mav0" / "state_groundtruth_estimate0" / "data.csv" if (p / "mav0").is_dir() else p
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    try:
        d, _ = read_table(p, 17)
    except InputError as e:
        raise InputError(
            f"{e} (a ground-truth state needs 17 columns: t, p xyz, q wxyz, v xyz, gyro bias xyz, "
            "accel bias xyz, as EuRoC's state_groundtruth_estimate0)"
        ) from None
    traj = read_euroc_gt(p)
    return StateTruth(traj, d[:, 8:11], d[:, 11:14], d[:, 14:17])


def read_bag_poses(path: str | Path, topic: str | None = None) -> Trajectory:
    """``geometry_msgs/PoseStamped`` (or ``nav_msgs/Odometry``, ``PointStamped``) messages of a ROS 1/2
    bag, by header stamp (:meth:`imuslam.io.bag.Bag.trajectory`)."""
    from imuslam.io.bag import Bag

    with Bag(path) as bag:
        return bag.trajectory(topic)


_FORMAT_NAMES = {"tum": "TUM", "kitti": "KITTI", "euroc": "EuRoC csv", "bag": "a bag"}


def detect_trajectory_format(path: str | Path) -> str:
    """The format of a trajectory file by its content: a bag (``.bag``, ``.mcap``, ``.db3`` or a ROS 2
    folder), EuRoC csv (comma-separated, integer ns stamps first), TUM (8 numbers a line) or KITTI (12
    numbers a line: a 3x4 pose matrix). Comment lines (``#``) and a csv header are skipped."""
    p = Path(path)
    if p.is_dir() or p.suffix.lower() in (".bag", ".mcap", ".db3"):
        return "bag"
    with open(p, "rb") as f:
        raw = f.read(1 << 16)
    lines = raw.decode("utf-8", errors="replace").splitlines()
    if len(raw) == 1 << 16 and len(lines) > 1:
        lines = lines[:-1]  # cut by the read
    for n, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s.startswith(("#", "%", "//")):
            continue
        csv = "," in s
        fields = [x.strip() for x in s.split(",")] if csv else s.split()
        try:
            [float(x) for x in fields]
        except ValueError:
            if csv and n == 1:
                continue  # a header
            raise InputError(
                f"{p}: line {n} is not numbers; expected a trajectory (TUM, KITTI or EuRoC csv)"
            ) from None
        if csv and len(fields) >= 8 and fields[0].isdigit():
            return "euroc"
        if not csv and len(fields) == 8:
            return "tum"
        if not csv and len(fields) == 12:
            return "kitti"
        raise InputError(
            f"{p}: line {n} has {len(fields)} {'comma-separated ' if csv else ''}columns; expected "
            "TUM (8 space-separated: t x y z qx qy qz qw), KITTI (12: a 3x4 pose matrix) or EuRoC csv "
            "(ns stamp, position, quaternion wxyz, ...)"
        )
    raise InputError(f"{p}: no pose in the file")


def read_trajectory(
    path: str | Path, fmt: str, topic: str | None = None, times: str | Path | None = None
) -> Trajectory:
    """Read a trajectory in ``fmt`` (tum, kitti, euroc, bag, or auto: :func:`detect_trajectory_format`);
    an unknown format is an InputError, and a file that does not read as ``fmt`` but looks like another
    format says which ``--format`` to give."""
    if fmt not in (*TRAJ_FORMATS, "auto"):
        raise InputError(
            f"{path}: unknown trajectory format '{fmt}'; expected auto, {', '.join(TRAJ_FORMATS)}"
        )
    if not Path(path).exists():
        raise InputError(f"{path}: no such file")
    if fmt == "auto":
        return _read_as(path, detect_trajectory_format(path), topic, times)
    try:
        return _read_as(path, fmt, topic, times)
    except InputError as exc:
        try:
            kind = detect_trajectory_format(path)
        except (InputError, OSError):
            raise exc from None
        if kind == fmt:
            raise
        raise InputError(
            f"{exc}; the file looks like {_FORMAT_NAMES[kind]}: give --format {kind} (or auto)"
        ) from None


def _read_as(path: str | Path, fmt: str, topic: str | None, times: str | Path | None) -> Trajectory:
    if fmt == "tum":
        return read_tum(path)
    if fmt == "kitti":
        return read_kitti(path, times)
    if fmt == "euroc":
        return read_euroc_gt(path)
    return read_bag_poses(path, topic)


def write_tum(traj: Trajectory, path: str | Path) -> None:
    """Write ``t x y z qx qy qz qw`` (s with 9 decimals, exact from ``t_ns``; m), atomically."""
    q = traj.quat_wxyz
    rows = np.column_stack([traj.p_w, q[:, 1:], q[:, :1]])
    sec, frac = np.divmod(traj.t_ns, 1_000_000_000)  # no float64 rounding of epoch stamps
    body = "\n".join(
        f"{s}.{f:09d} " + " ".join(f"{v:.9g}" for v in r)
        for s, f, r in zip(sec, frac, rows, strict=True)
    )
    write_atomic(path, "# t x y z qx qy qz qw\n" + body + "\n")


def write_kitti(traj: Trajectory, path: str | Path) -> None:
    """Write 3x4 row-major pose matrices, one per line, atomically."""
    M = np.concatenate([traj.R_w_b, traj.p_w[:, :, None]], axis=2).reshape(-1, 12)
    write_atomic(path, "\n".join(" ".join(f"{v:.9e}" for v in r) for r in M) + "\n")
