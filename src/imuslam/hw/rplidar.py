"""RPLIDAR A2 scans through an existing Python driver (``rplidar-roboticia``), as LaserScan records
(:class:`imuslam.sim.lidar.Scan2d`, the same record the simulator produces).

The driver yields each revolution as ``(quality, angle_deg, distance_mm)`` tuples, angles clockwise from
the sensor's front; a LaserScan is counter-clockwise (REP-103), so angles are negated and binned at
0.45 deg (the A2's resolution). Empty bins are ``inf``.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator

import numpy as np

from imuslam.interfaces.lidar import Scan2d


def scan_from_measurements(
    meas: Iterable[tuple[float, float, float]],
    t_ns: int,
    increment_deg: float = 0.45,
    range_min: float = 0.2,
    range_max: float = 12.0,
) -> Scan2d:
    """Bin one revolution of (quality, angle_deg clockwise, distance_mm) into a LaserScan (m, rad, CCW)."""
    m = np.asarray(list(meas), dtype=float).reshape(-1, 3)
    nb = int(round(360.0 / increment_deg))
    ranges = np.full(nb, np.inf, dtype=np.float32)
    inten = np.zeros(nb, dtype=np.float32)
    if m.size:
        ang_ccw = (-m[:, 1] + 180.0) % 360.0  # bin 0 at -180 deg
        r = m[:, 2] / 1000.0
        ok = (r >= range_min) & (r <= range_max) & (m[:, 0] > 0)
        b = (np.round(ang_ccw[ok] / increment_deg).astype(int)) % nb
        order = np.argsort(-r[ok])  # the nearest return wins a bin
        ranges[b[order]] = r[ok][order]
        inten[b[order]] = m[ok, 0][order]
    inc = np.deg2rad(increment_deg)
    return Scan2d(t_ns, -np.pi, float(inc), 0.0, 0.0, range_min, range_max, ranges, inten)


def rplidar_scans(port: str = "/dev/ttyUSB0", baud: int = 115200) -> Iterator[Scan2d]:
    """Scans from an RPLIDAR A2 (requires the ``hw`` extra: pip install imuslam[hw])."""
    from rplidar import RPLidar  # optional dependency

    lidar = RPLidar(port, baudrate=baud)
    try:
        for scan in lidar.iter_scans():
            yield scan_from_measurements(scan, time.time_ns())
    finally:
        lidar.stop()
        lidar.disconnect()
