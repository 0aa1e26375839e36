"""Open any 2D laser log by its kind: CARMEN (``.clf``, ``.log``, ``.gz``, ``.bz2``), BreezySLAM
(``.dat``), or a folder written by ``imuslam simulate room`` (``sim.npz``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from imuslam.errors import InputError
from imuslam.io.carmen import read_breezyslam, read_carmen
from imuslam.io.imulog import ImuLog
from imuslam.io.laserlog import LaserLog, check_time_order, clean_ranges, odometry_jumps

LaserFormat = Literal["auto", "carmen", "breezyslam", "sim"]
LASER_FORMATS = ("auto", "carmen", "breezyslam", "sim")


def detect_format(path: Path) -> str:
    if path.is_dir():
        if (path / "sim.npz").is_file():
            return "sim"
        raise InputError(
            f"{path}: a folder without sim.npz (expected the output of imuslam simulate)"
        )
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
    try:
        d = np.load(f)
        t_ns = d["scan_t_ns"]
        ranges = d["scan_ranges"]
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{f}: not a simulation with 2D scans ({exc})") from None
    if len(t_ns) == 0:
        raise InputError(f"{f}: the simulation holds no laser scans")
    warnings: dict[str, int] = {}
    check_time_order(t_ns, str(f), warnings)
    r = clean_ranges(ranges, 0.2, 12.0, warnings)
    odo = None
    if "wheel_t_ns" in d:
        wt = d["wheel_t_ns"].astype(float)
        wo = d["wheel_odom_xy_yaw"]
        ts = t_ns.astype(float)
        odo = np.column_stack([np.interp(ts, wt, wo[:, 0]), np.interp(ts, wt, wo[:, 1]),
                               np.interp(ts, wt, np.unwrap(wo[:, 2]))])  # fmt: skip
        odo = odometry_jumps(odo, t_ns, 3.0, 6.0, warnings)
    imu = None
    if with_imu and "imu_t_ns" in d:
        imu = ImuLog(d["imu_t_ns"], d["imu_accel"], d["imu_gyro"], source=f"{f}:imu")
    return LaserLog(
        t_ns, r, float(d["scan_angle_min"]), float(d["scan_angle_increment"]), 0.2, 12.0, odo,
        np.zeros(3), imu, str(f), warnings, 0.1 / ranges.shape[1],  # the simulator's scanner turns at 10 Hz
    )  # fmt: skip


def load_laser_log(path: str | Path, fmt: str = "auto") -> LaserLog:
    """Read a 2D laser log of any supported kind."""
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
    return read_sim_room(p)
