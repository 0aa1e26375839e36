"""The 2-axis gimbal that turns the IMU through its calibration poses (the online calibration on a gimbal,
source 000): its joints' range and resolution, and what a driver provides. The simulator and the
hardware drivers both implement :class:`Gimbal`; the pose planner reads the resolution."""

from __future__ import annotations

from typing import Protocol

#: The source gimbal's joints: 4096 steps per turn (0.088 deg), roll within +-90 deg, pitch a full turn.
GIMBAL_RESOLUTION_DEG = 360.0 / 4096.0
ROLL_LIMITS_DEG = (-90.0, 90.0)
PITCH_LIMITS_DEG = (-180.0, 180.0)


class Gimbal(Protocol):
    """Two joints [roll, pitch] in degrees."""

    limits_deg: tuple[tuple[float, float], tuple[float, float]]

    def move_to(self, angles_deg: tuple[float, float]) -> None: ...

    def angles_deg(self) -> tuple[float, float]: ...

    def settle_time_s(self, target_deg: tuple[float, float]) -> float: ...
