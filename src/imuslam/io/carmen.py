"""CARMEN logs (plain, ``.gz`` or ``.bz2``) and BreezySLAM ``.dat`` logs -> :class:`LaserLog`.

CARMEN (carmen.sourceforge.net, logger format):
``FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp``
(front laser, 180 degrees from -90 deg); ``ROBOTLASER1 type start_angle fov resolution max_range accuracy
remission_mode n r_1..r_n m rem_1..rem_m laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
forward_safety side_safety turn_axis ipc_timestamp ipc_hostname logger_timestamp``;
``ODOM x y theta tv rv accel ipc_timestamp ...``. Scan stamps are the ipc timestamp. The odometry of a
scan is the odometry pose on its own line (raw logs: FLASER's x y theta equal odom_x...; corrected logs:
x y theta are the corrected laser pose, kept in :attr:`CarmenLog.laser_pose_xy_yaw`).

BreezySLAM (github.com/simondlevy/BreezySLAM, examples/exp*.dat): one scan per line: field 1 time in us,
fields 3-4 left and right wheel ticks (2000 per turn, wheels 77 mm, half axle 165 mm; BreezySLAM's own
reader takes these two), then from field 25 the ranges
of a Hokuyo URG-04LX in mm (682 beams over 240 degrees, 0 = no return, mounted 145 mm ahead of the axle).
"""

from __future__ import annotations

import bz2
import gzip
import io
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.io.laserlog import LaserLog, check_time_order, clean_ranges, odometry_jumps

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)

#: SICK scanners of the Radish logs report no return as ~81.9 m; their usable range is far below.
CARMEN_RANGE_MAX = 50.0
MAX_ODOM_SPEED = 3.0  # m/s; faster odometry steps are jumps
MAX_ODOM_YAW_RATE = 6.0  # rad/s


@dataclass
class CarmenLog:
    """A CARMEN log: the scans (with the wheel odometry of each) and the laser pose written beside each
    scan ((N, 3) [x, y, theta]; in a corrected log this is the corrected pose)."""

    laser: LaserLog
    laser_pose_xy_yaw: FloatArray


def open_text(path: str | Path) -> str:
    """The text of a plain, gzip or bzip2 file (by content, not by name)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    raw = p.read_bytes()
    try:
        if raw[:2] == b"\x1f\x8b":
            raw = gzip.decompress(raw)
        elif raw[:3] == b"BZh":
            raw = bz2.decompress(raw)
    except (OSError, EOFError, ValueError) as exc:
        raise InputError(f"{p}: corrupt compressed file ({exc})") from None
    return raw.decode("ascii", errors="replace")


def _floats(tok: list[str], where: str) -> FloatArray:
    try:
        return np.array(tok, dtype=float)
    except ValueError:
        bad = next(t for t in tok if not _is_float(t))
        raise InputError(f"{where}: '{bad}' is not a number") from None


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def read_carmen(path: str | Path, range_max: float = CARMEN_RANGE_MAX) -> CarmenLog:
    """Read the front-laser scans (FLASER or ROBOTLASER1) of a CARMEN log, in file order.

    Raises :class:`InputError` naming the line for a malformed line, a beam count that changes, times
    that go backwards, or a log without scans.
    """
    p = Path(path)
    text = open_text(p)
    t_list: list[float] = []
    ranges: list[FloatArray] = []
    pose: list[FloatArray] = []
    odom: list[FloatArray] = []
    angle_min = angle_inc = float("nan")
    n_beams = -1
    x_offset = 0.0
    for lineno, line in enumerate(io.StringIO(text), start=1):
        if not line.startswith(("FLASER", "ROBOTLASER1", "PARAM robot_frontlaser_offset")):
            continue
        tok = line.split()
        where = f"{p}:{lineno}"
        if tok[0] == "PARAM":
            if len(tok) >= 3 and _is_float(tok[2]):
                x_offset = float(tok[2])
            continue
        try:
            if tok[0] == "FLASER":
                n = int(tok[1])
                head = 2
                a_min, a_inc = -np.pi / 2, np.pi / (2 * (n // 2)) if n > 1 else np.pi
                rest = tok[head + n :]
                vals = _floats(tok[head : head + n] + rest[:6] + rest[6:7], where)
            else:  # ROBOTLASER1
                n = int(tok[8])
                a_min, fov, a_inc = float(tok[2]), float(tok[3]), float(tok[4])
                if (
                    n > 1
                    and abs(fov / (n - 1) - a_inc) > 0.01 * abs(a_inc)
                    and abs(fov / n - a_inc) > 0.01 * abs(a_inc)
                ):
                    raise InputError(
                        f"{where}: field of view {fov:.6g} rad, resolution {a_inc:.6g} rad and "
                        f"{n} readings disagree"
                    )
                m = int(tok[9 + n])
                rest = tok[10 + n + m :]
                vals = _floats(tok[9 : 9 + n] + rest[:6] + rest[11:12], where)
        except (IndexError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(
                f"{where}: malformed {tok[0]} line (expected the CARMEN field layout)"
            ) from None
        if len(vals) != n + 7:
            raise InputError(
                f"{where}: {tok[0]} line is cut short (expected {n} ranges, 6 pose values, a time)"
            )
        if n_beams < 0:
            n_beams, angle_min, angle_inc = n, a_min, a_inc
        elif n != n_beams:
            raise InputError(f"{where}: scan has {n} readings, earlier scans {n_beams}")
        ranges.append(vals[:n])
        pose.append(vals[n : n + 3])
        odom.append(vals[n + 3 : n + 6])
        t_list.append(vals[n + 6])
    if not ranges:
        raise InputError(f"{p}: no laser scans (no FLASER or ROBOTLASER1 line)")
    t = np.array(t_list)
    t_ns = _seconds_to_ns(t)
    warnings: dict[str, int] = {}
    check_time_order(t_ns, str(p), warnings)
    r = clean_ranges(np.array(ranges), 0.01, range_max, warnings)
    odo, jumped = odometry_jumps(np.array(odom), t_ns, MAX_ODOM_SPEED, MAX_ODOM_YAW_RATE, warnings)
    laser = LaserLog(
        t_ns, r, angle_min, angle_inc, 0.01, range_max, odo, np.array([x_offset, 0.0, 0.0]),
        None, str(p), warnings, odom_jumped=jumped,
    )  # fmt: skip
    return CarmenLog(laser, np.array(pose))


def _seconds_to_ns(t: FloatArray) -> NDArray[np.int64]:
    t0 = np.floor(t[0]) if len(t) else 0.0
    return np.int64(t0) * 1_000_000_000 + np.round((t - t0) * 1e9).astype(np.int64)


BREEZY_TICKS_PER_REV = 2000
BREEZY_WHEEL_RADIUS = 0.077
BREEZY_HALF_AXLE = 0.165
BREEZY_BEAMS = 682
BREEZY_FOV_DEG = 240.0
BREEZY_LASER_X = 0.145
BREEZY_RANGE_MAX = 4.0


def read_breezyslam(path: str | Path) -> LaserLog:
    """Read a BreezySLAM ``.dat`` log (wheel ticks -> dead-reckoned odometry; Hokuyo ranges -> m)."""
    p = Path(path)
    text = open_text(p)
    rows: list[FloatArray] = []
    for lineno, line in enumerate(io.StringIO(text), start=1):
        tok = line.split()
        if not tok:
            continue
        if len(tok) < 24 + BREEZY_BEAMS:
            raise InputError(
                f"{p}:{lineno}: {len(tok)} fields; expected at least {24 + BREEZY_BEAMS} (time, odometry "
                f"fields, {BREEZY_BEAMS} ranges from field 25)"
            )
        rows.append(_floats(tok[: 24 + BREEZY_BEAMS], f"{p}:{lineno}"))
    if not rows:
        raise InputError(f"{p}: no scans")
    a = np.array(rows)
    t_ns = np.round(a[:, 0] * 1e3).astype(np.int64)
    ticks = a[:, 2:4]
    d = (
        np.diff(ticks, axis=0, prepend=ticks[:1])
        / BREEZY_TICKS_PER_REV
        * 2
        * np.pi
        * BREEZY_WHEEL_RADIUS
    )
    ds = d.mean(axis=1)
    dyaw = (d[:, 1] - d[:, 0]) / (2 * BREEZY_HALF_AXLE)
    yaw = np.cumsum(dyaw)
    mid = yaw - dyaw / 2
    odo = np.stack([np.cumsum(ds * np.cos(mid)), np.cumsum(ds * np.sin(mid)), yaw], axis=1)
    warnings: dict[str, int] = {}
    check_time_order(t_ns, str(p), warnings)
    # first reading at -120 degrees (right), counter-clockwise: with this order the scan matcher's
    # heading follows the wheel odometry's turns (the reverse order turns the other way)
    r = clean_ranges(a[:, 24:] * 1e-3, 0.02, BREEZY_RANGE_MAX, warnings)
    odo, jumped = odometry_jumps(odo, t_ns, MAX_ODOM_SPEED, MAX_ODOM_YAW_RATE, warnings)
    inc = np.deg2rad(BREEZY_FOV_DEG) / (BREEZY_BEAMS - 1)
    return LaserLog(
        t_ns, r, -np.deg2rad(BREEZY_FOV_DEG) / 2, inc, 0.02, BREEZY_RANGE_MAX, odo,
        np.array([BREEZY_LASER_X, 0.0, 0.0]), None, str(p), warnings, odom_jumped=jumped,
    )  # fmt: skip
