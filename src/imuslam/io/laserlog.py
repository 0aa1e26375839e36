"""A 2D laser log: consecutive planar scans with the wheel odometry at each scan, and optionally an IMU.

Every 2D reader (CARMEN, BreezySLAM, bags, the simulator) returns a :class:`LaserLog`; the 2D SLAM
consumes it. It gives its IMU as every dataset does, by ``imu()`` (``interfaces.sources``); a pipeline's
``imu=`` overrides it (e.g. after calibration), the log is never changed after reading. Readings that are no return (inf, NaN, outside [range_min, range_max]) are stored as NaN
and counted in ``warnings``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog

FloatArray = NDArray[np.float64]


@dataclass
class LaserLog:
    """Scans of one planar scanner.

    t_ns: (N,) int64 scan times (the log's own stamps), in recording order (see :func:`check_time_order`).
    ranges: (N, B) float32 ranges, m; NaN for no return.
    angle_min, angle_increment: beam b points at ``angle_min + b * angle_increment`` rad in the laser
    frame (x forward, y left).
    odom_xy_yaw: (N, 3) wheel-odometry pose [x m, y m, yaw rad] at each scan, or None (no odometry).
    T_b_l: (3,) the laser's pose in the body (odometry) frame [x, y, yaw].
    imu_log: an IMU log over the same time (body frame = IMU frame), or None; read it by :meth:`imu`.
    warnings: counted repairs, e.g. ``{"dropped readings (inf/NaN/out of range)": 1234}``.
    time_increment: s between beams (beam b fired at ``t_ns + b * time_increment``; 0 = all at once).
    odom_jumped: (N,) bool, True where the odometry step into the scan was a jump replaced by no motion
    (:func:`odometry_jumps`), or None (none found, or no odometry).
    """

    t_ns: NDArray[np.int64]
    ranges: NDArray[np.float32]
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    odom_xy_yaw: FloatArray | None = None
    T_b_l: FloatArray = field(default_factory=lambda: np.zeros(3))
    imu_log: ImuLog | None = None
    source: str = "<memory>"
    warnings: dict[str, int] = field(default_factory=dict)
    time_increment: float = 0.0
    odom_jumped: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64)
        self.ranges = np.asarray(self.ranges, dtype=np.float32)
        n = self.t_ns.shape[0]
        if n == 0:
            raise InputError(f"{self.source}: the log holds no laser scans")
        if self.ranges.ndim != 2 or self.ranges.shape[0] != n:
            raise InputError(
                f"{self.source}: expected ranges (N, B) for {n} scans, got {self.ranges.shape}"
            )
        if self.odom_jumped is not None:
            self.odom_jumped = np.asarray(self.odom_jumped, dtype=bool)
            if self.odom_jumped.shape != (n,):
                raise InputError(
                    f"{self.source}: expected odom_jumped (N,) for {n} scans, got {self.odom_jumped.shape}"
                )
        if self.odom_xy_yaw is not None:
            self.odom_xy_yaw = np.asarray(self.odom_xy_yaw, dtype=float)
            if self.odom_xy_yaw.shape != (n, 3):
                raise InputError(
                    f"{self.source}: expected odometry (N, 3) for {n} scans, got {self.odom_xy_yaw.shape}"
                )
            if not np.isfinite(self.odom_xy_yaw).all():
                raise InputError(
                    f"{self.source}: odometry of scan {int(np.argmax(~np.isfinite(self.odom_xy_yaw).all(axis=1)))} "
                    "is NaN or infinite"
                )
        if not (np.isfinite(self.angle_increment) and self.angle_increment != 0.0):
            raise InputError(f"{self.source}: angle_increment must be finite and non-zero")
        self.T_b_l = np.asarray(self.T_b_l, dtype=float)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def imu(self) -> ImuLog | None:
        """The log's IMU as recorded (None: the log has none, or it was not read)."""
        return self.imu_log

    @property
    def n_beams(self) -> int:
        return int(self.ranges.shape[1])

    @property
    def angles(self) -> FloatArray:
        """(B,) beam angles, rad, laser frame."""
        return np.asarray(
            self.angle_min + np.arange(self.n_beams) * self.angle_increment, dtype=np.float64
        )

    @property
    def duration_s(self) -> float:
        return float(self.t_ns[-1] - self.t_ns[0]) * 1e-9

    def slice(self, start: int, stop: int) -> LaserLog:
        """Scans ``start:stop`` (the IMU is kept whole)."""
        odo = None if self.odom_xy_yaw is None else self.odom_xy_yaw[start:stop]
        jumped = None if self.odom_jumped is None else self.odom_jumped[start:stop]
        return LaserLog(
            self.t_ns[start:stop], self.ranges[start:stop], self.angle_min, self.angle_increment,
            self.range_min, self.range_max, odo, self.T_b_l, self.imu_log, self.source, dict(self.warnings),
            self.time_increment, jumped,
        )  # fmt: skip


def clean_ranges(
    ranges: NDArray[np.floating], range_min: float, range_max: float, warnings: dict[str, int]
) -> NDArray[np.float32]:
    """Readings that are inf, NaN or outside [range_min, range_max) -> NaN, counted in ``warnings``."""
    r = np.asarray(ranges, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(r) | (r < range_min) | (r >= range_max)
    nbad = int(bad.sum())
    if nbad:
        key = "readings dropped (inf/NaN/out of range)"
        warnings[key] = warnings.get(key, 0) + nbad
        r = np.where(bad, np.float32(np.nan), r)
    return r


def check_beam_count(
    angle_min: float, angle_max: float, angle_increment: float, n: int, where: str
) -> None:
    """A LaserScan's angle fields must agree with its number of ranges (to half a beam)."""
    if angle_increment == 0 or not np.isfinite(angle_increment):
        raise InputError(f"{where}: angle_increment is {angle_increment}; expected a non-zero step")
    expected = (angle_max - angle_min) / angle_increment + 1.0
    if abs(expected - n) > 1.01:
        raise InputError(
            f"{where}: angle_min {angle_min:.6g}, angle_max {angle_max:.6g} and angle_increment "
            f"{angle_increment:.6g} give {expected:.1f} beams but the scan has {n} ranges"
        )


def odometry_jumps(
    odom_xy_yaw: FloatArray,
    t_ns: NDArray[np.int64],
    max_speed: float,
    max_yaw_rate: float,
    warnings: dict[str, int],
) -> tuple[FloatArray, NDArray[np.bool_] | None]:
    """Odometry steps faster than ``max_speed`` m/s or ``max_yaw_rate`` rad/s are jumps (a reset, a glitch):
    the step is replaced by no motion (the scan matcher bridges it) and counted. Returns the repaired poses
    and (N,) True at the scans whose incoming step was replaced (None when there was no jump)."""
    d = np.diff(odom_xy_yaw, axis=0)
    dt = np.diff(t_ns).astype(float) * 1e-9
    dt = np.maximum(
        dt, max(float(np.median(dt)), 0.02)
    )  # stamps that go backwards get the usual step
    dyaw = np.angle(np.exp(1j * d[:, 2]))
    jump = (np.hypot(d[:, 0], d[:, 1]) > max_speed * dt) | (np.abs(dyaw) > max_yaw_rate * dt)
    if not jump.any():
        return odom_xy_yaw, None
    warnings["odometry jumps (step replaced by no motion)"] = int(jump.sum())
    # rebuild the path from the relative steps expressed in the previous pose's frame
    c, s = np.cos(odom_xy_yaw[:-1, 2]), np.sin(odom_xy_yaw[:-1, 2])
    lx, ly = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    lx[jump] = 0.0
    ly[jump] = 0.0
    dyaw[jump] = 0.0
    out = np.empty_like(odom_xy_yaw)
    out[0] = odom_xy_yaw[0]
    yaw = odom_xy_yaw[0, 2] + np.concatenate([[0.0], np.cumsum(dyaw)])
    cy, sy = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    out[1:, 0] = odom_xy_yaw[0, 0] + np.cumsum(cy * lx - sy * ly)
    out[1:, 1] = odom_xy_yaw[0, 1] + np.cumsum(sy * lx + cy * ly)
    out[:, 2] = yaw
    return out, np.concatenate([[False], jump])


def check_time_order(
    t_ns: NDArray[np.int64], where: str, warnings: dict[str, int], max_fraction: float = 0.1
) -> None:
    """Stamps that go backwards: a few (a clock glitch; the recording order is kept, as the odometry
    confirms it on the Radish logs) are counted; more than ``max_fraction`` of the scans is an error."""
    back = np.flatnonzero(np.diff(t_ns) < 0)
    if back.size > max_fraction * max(len(t_ns), 1):
        raise InputError(
            f"{where}: {back.size} of {len(t_ns)} scans are stamped before the previous one "
            f"(first: scan {int(back[0]) + 1}); the scans are not in time order"
        )
    if back.size:
        warnings["scan stamps earlier than the previous scan (recording order kept)"] = int(
            back.size
        )
