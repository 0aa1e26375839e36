"""The navigation scenarios a study's cells drive: trajectory, world and IMU rate by name (as
``sim/scenario.py``)."""

from __future__ import annotations

from imuslam.sim.trajectory import (
    CarLoop,
    CorridorDrive,
    DiffDriveFigureEight,
    EulerTrajectory,
    Handheld,
    SquareLoopCcwCw,
)
from imuslam.sim.world import World, corridor, room_8x8, urban_block


def scene(name: str) -> tuple[EulerTrajectory, World, float]:
    """Trajectory, world and IMU rate of a navigation scenario (as ``sim/scenario.py``)."""
    if name == "room":
        return DiffDriveFigureEight(), room_8x8(), 100.0
    if name == "square":  # seed 000's validation drive: round the room CCW, turn at A, CW back
        return SquareLoopCcwCw(), room_8x8(), 100.0
    if name == "street":
        return CarLoop(), urban_block(), 200.0
    if name == "corridor":
        return CorridorDrive(), corridor(), 100.0
    if name == "handheld":
        return Handheld(), room_8x8(), 200.0
    raise ValueError(f"unknown scenario '{name}'")
