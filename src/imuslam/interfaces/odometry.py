"""Wheel odometry: encoder ticks and the dead-reckoned planar pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["WheelOdometry"]


@dataclass
class WheelOdometry:
    """t_ns: (N,) int64 stamps, ns; ticks: (N, 2) cumulative [left, right] encoder counts (zeros when
    only an odometry pose is known); pose_xy_yaw: (N, 3) dead-reckoned planar pose [x m, y m, yaw rad]
    in the odometry frame."""

    t_ns: NDArray[np.int64]
    ticks: NDArray[np.int64]
    pose_xy_yaw: NDArray[np.float64]

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def t_s(self) -> NDArray[np.float64]:
        """(N,) stamps in seconds."""
        return self.t_ns.astype(np.float64) * 1e-9
