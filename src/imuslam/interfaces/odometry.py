"""Wheel odometry: encoder ticks, the dead-reckoned planar pose and, from a bag's odometry messages, the
body twist."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["WheelOdometry"]


@dataclass
class WheelOdometry:
    """t_ns: (N,) int64 stamps, ns; ticks: (N, 2) cumulative [left, right] encoder counts (zeros when
    only an odometry pose is known); pose_xy_yaw: (N, 3) dead-reckoned planar pose [x m, y m, yaw rad]
    in the odometry frame; linear_b / angular_b: (N, 3) body twist, m/s and rad/s, when the source gives
    it (a ROS ``nav_msgs/Odometry``), else None; source: where it was read (for messages)."""

    t_ns: NDArray[np.int64]
    ticks: NDArray[np.int64]
    pose_xy_yaw: NDArray[np.float64]
    linear_b: NDArray[np.float64] | None = None
    angular_b: NDArray[np.float64] | None = None
    source: str = field(default="")

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def t_s(self) -> NDArray[np.float64]:
        """(N,) stamps in seconds."""
        return self.t_ns.astype(np.float64) * 1e-9
