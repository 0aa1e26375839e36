"""Open any 2D laser log by its kind: CARMEN (``.clf``, ``.log``, ``.gz``, ``.bz2``), BreezySLAM
(``.dat``), a bag (ROS 1 ``.bag``, ROS 2 folder, ``.mcap``: LaserScan / MultiEchoLaserScan, Imu,
Odometry), or a folder written by ``imuslam simulate room`` (``sim.npz``)."""

from __future__ import annotations

import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Literal, TypeVar

import numpy as np

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog
from imuslam.io.carmen import read_breezyslam, read_carmen
from imuslam.io.kinds import SourceKind, format_of
from imuslam.io.laserlog import LaserLog, check_time_order, clean_ranges, odometry_jumps

LaserFormat = Literal["auto", "carmen", "breezyslam", "sim", "bag"]
LASER_FORMATS = ("auto", "carmen", "breezyslam", "sim", "bag")


def detect_format(path: Path) -> str:
    """The format of ``path`` from :func:`~imuslam.io.kinds.source_kind` (a bag, a simulation folder),
    else from the file's name."""
    kind = format_of(
        path,
        {SourceKind.BAG: "bag", SourceKind.SIM_FOLDER: "sim"},
        "a folder without sim.npz (expected the output of imuslam simulate)",
    )
    if kind is not None:
        return kind
    name = path.name.lower()
    if name.endswith(".dat"):
        return "breezyslam"
    if name.endswith(".npz"):
        return "sim"
    for ext in (".clf", ".log", ".clf.gz", ".clf.bz2", ".log.gz", ".log.bz2", ".gz", ".bz2"):
        if name.endswith(ext):
            return "carmen"
    raise InputError(
        f"{path}: unknown log kind; expected a CARMEN log (.clf/.log, optionally .gz/.bz2), a BreezySLAM "
        ".dat or an imuslam simulate folder"
    )


def read_sim_room(path: str | Path, with_imu: bool = True) -> LaserLog:
    """Scans, wheel odometry (dead-reckoned, interpolated to the scan times) and IMU of a simulated robot."""
    p = Path(path)
    f = p / "sim.npz" if p.is_dir() else p
    try:  # every array read here: a damaged member of the archive fails now, not later
        with np.load(f) as z:
            d = {k: z[k] for k in z.files}
        t_ns = d["scan_t_ns"]
        ranges = d["scan_ranges"]
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputError(
            f"{f}: not a simulation with 2D scans ({type(exc).__name__}: {exc})"
        ) from None
    if len(t_ns) == 0:
        raise InputError(f"{f}: the simulation holds no laser scans")
    warnings: dict[str, int] = {}
    check_time_order(t_ns, str(f), warnings)
    r = clean_ranges(ranges, 0.2, 12.0, warnings)
    odo = None
    jumped = None
    if "wheel_t_ns" in d:
        wt = d["wheel_t_ns"].astype(float)
        wo = d["wheel_odom_xy_yaw"]
        ts = t_ns.astype(float)
        odo = np.column_stack([np.interp(ts, wt, wo[:, 0]), np.interp(ts, wt, wo[:, 1]),
                               np.interp(ts, wt, np.unwrap(wo[:, 2]))])  # fmt: skip
        odo, jumped = odometry_jumps(odo, t_ns, 3.0, 6.0, warnings)
    imu = None
    if with_imu and "imu_t_ns" in d:
        imu = ImuLog(d["imu_t_ns"], d["imu_accel"], d["imu_gyro"], source=f"{f}:imu")
    return LaserLog(
        t_ns, r, float(d["scan_angle_min"]), float(d["scan_angle_increment"]), 0.2, 12.0, odo,
        np.zeros(3), imu, str(f), warnings, 0.1 / ranges.shape[1],  # the simulator's scanner turns at 10 Hz
        jumped,
    )  # fmt: skip


T = TypeVar("T")


def _named(read: Callable[[], T], option: str) -> T:
    """``read()``; a topic it cannot find or choose is reported with the option that names it."""
    try:
        return read()
    except InputError as exc:
        if "topic" not in str(exc):
            raise
        raise InputError(f"{exc}; choose it with {option}") from None


def read_bag_laser(
    path: str | Path, scan_topic: str | None = None, imu_topic: str | None = None,
    odom_topic: str | None = None, with_imu: bool = True,
) -> LaserLog:  # fmt: skip
    """The scans of a LaserScan / MultiEchoLaserScan topic (first echo), the Imu topic if the bag has one
    (or ``imu_topic``; none without ``with_imu``), and the Odometry topic's planar pose interpolated at
    the scan stamps. A topic missing or to be chosen is one line naming the option that chooses it."""
    from imuslam.io import rosmsg
    from imuslam.io.bag import Bag

    with Bag(path) as b:
        topics = b.topics()
        scans = _named(lambda: list(b.scans2d(scan_topic)), "--scan-topic")
        src = f"{path}:{scan_topic or 'scan'}"
        if not scans:
            raise InputError(f"{src}: the topic has no scans")
        imu = None
        if with_imu and (imu_topic is not None or any(m == rosmsg.IMU for m in topics.values())):
            imu = _named(lambda: b.imu(imu_topic), "--imu-topic")
        odo_traj = None
        if odom_topic is not None or any(m == rosmsg.ODOMETRY for m in topics.values()):
            odo_traj = _named(
                lambda: b.trajectory(
                    odom_topic or next(t for t, m in topics.items() if m == rosmsg.ODOMETRY)
                ),
                "--odom-topic",
            )
    nb = len(scans[0].ranges)
    for k, sc in enumerate(scans):
        if len(sc.ranges) != nb or abs(sc.angle_increment - scans[0].angle_increment) > 1e-9 * max(
            1.0, nb
        ):
            raise InputError(f"{src}: scan {k} has {len(sc.ranges)} beams / increment {sc.angle_increment:.6g}; "
                             f"scan 0 has {nb} / {scans[0].angle_increment:.6g}")  # fmt: skip
    t_ns = np.array([sc.t_ns for sc in scans], np.int64)
    warnings: dict[str, int] = {}
    check_time_order(t_ns, src, warnings)
    r_min = float(min(sc.range_min for sc in scans))
    r_max = float(max(sc.range_max for sc in scans))
    ranges = clean_ranges(np.array([sc.ranges for sc in scans]), max(r_min, 1e-3), r_max, warnings)
    odo = None
    jumped = None
    if odo_traj is not None:
        yaw = np.unwrap(np.arctan2(odo_traj.R_w_b[:, 1, 0], odo_traj.R_w_b[:, 0, 0]))
        ot = odo_traj.t_ns.astype(float)
        ts = t_ns.astype(float)
        odo = np.column_stack([np.interp(ts, ot, odo_traj.p_w[:, 0]), np.interp(ts, ot, odo_traj.p_w[:, 1]),
                               np.interp(ts, ot, yaw)])  # fmt: skip
        odo, jumped = odometry_jumps(odo, t_ns, 3.0, 6.0, warnings)
    s0 = scans[0]
    return LaserLog(t_ns, ranges, s0.angle_min, s0.angle_increment, max(r_min, 1e-3), r_max, odo, np.zeros(3),
                    imu, src, warnings, max(float(s0.time_increment), 0.0), jumped)  # fmt: skip


def load_laser_log(
    path: str | Path, fmt: str = "auto", scan_topic: str | None = None, imu_topic: str | None = None,
    odom_topic: str | None = None, with_imu: bool = True,
) -> LaserLog:  # fmt: skip
    """Read a 2D laser log of any supported kind (topics: bags only); without ``with_imu`` the IMU is
    not read at all (a log's IMU the run leaves out cannot stop it or warn)."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if fmt not in LASER_FORMATS:
        raise InputError(f"--format: '{fmt}'; expected one of {', '.join(LASER_FORMATS)}")
    kind = detect_format(p) if fmt == "auto" else fmt
    if kind == "carmen":
        return read_carmen(p).laser
    if kind == "breezyslam":
        return read_breezyslam(p)
    if kind == "bag":
        return read_bag_laser(p, scan_topic, imu_topic, odom_topic, with_imu)
    return read_sim_room(p, with_imu)
