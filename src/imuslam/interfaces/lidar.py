"""LiDAR scans: a 3D point cloud with per-point time and ring, and a 2D laser scan."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["Scan2d", "Scan3d"]


class _StampAlias:
    """``t0_ns``: the old name of ``t_ns``, kept while other code moves over."""

    t_ns: int

    @property
    def t0_ns(self) -> int:
        return self.t_ns

    @t0_ns.setter
    def t0_ns(self, value: int) -> None:
        self.t_ns = value


@dataclass
class Scan3d(_StampAlias):
    """One sweep of a 3D LiDAR.

    t_ns: the scan's stamp, ns (the header stamp; per-point times are relative to it).
    points_l: (P, 3) float32 points, m, in the sensor frame at each point's firing time.
    t_offset_s: (P,) float32 firing time of each point, s after ``t_ns`` (may be negative when a
        driver stamps the end of the sweep).
    ring: (P,) uint16 beam index (0 = lowest elevation); intensity: (P,) float32.
    surface_id: (P,) int64, simulator truth only (the surface each point hit), empty otherwise.
    """

    t_ns: int
    points_l: NDArray[np.float32]
    t_offset_s: NDArray[np.float32]
    ring: NDArray[np.uint16]
    intensity: NDArray[np.float32]
    surface_id: NDArray[np.int64] = field(repr=False, default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return int(self.points_l.shape[0])


@dataclass
class Scan2d(_StampAlias):
    """A planar laser scan (``sensor_msgs/LaserScan``): ranges (B,) float32, m, with inf for no return;
    beam i at ``angle_min + i * angle_increment`` rad (counter-clockwise about the sensor's z), fired
    at ``t_ns + i * time_increment`` s."""

    t_ns: int
    angle_min: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: NDArray[np.float32]
    intensities: NDArray[np.float32]

    @property
    def angles(self) -> NDArray[np.float64]:
        """(B,) beam angles, rad."""
        n = self.ranges.shape[0]
        return np.asarray(self.angle_min + np.arange(n) * self.angle_increment, dtype=np.float64)
