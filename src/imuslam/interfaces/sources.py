"""Dataset protocols: what an estimator pipeline asks of a dataset (a bag, EuRoC, KITTI, the simulator).

A dataset implements whichever it can; a pipeline states the ones it needs in its signature, e.g.
``def run(data: ImuSource & LidarSource)`` written as a Protocol that inherits both. No ``hasattr``
checks: ``isinstance(data, LidarSource)`` works (``runtime_checkable``).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, runtime_checkable

from imuslam.interfaces.camera import StereoFrame
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan2d, Scan3d
from imuslam.interfaces.odometry import WheelOdometry
from imuslam.interfaces.trajectory import Trajectory

__all__ = [
    "GroundTruthSource",
    "ImuSource",
    "LidarSource",
    "Scan2dSource",
    "StereoSource",
    "WheelSource",
]


@runtime_checkable
class ImuSource(Protocol):
    def imu(self) -> ImuLog:
        """The whole IMU log, SI units (m/s^2, rad/s), sensor frame."""
        ...


@runtime_checkable
class LidarSource(Protocol):
    def lidar_scans(self) -> Iterator[Scan3d]:
        """3D scans in time order."""
        ...


@runtime_checkable
class StereoSource(Protocol):
    def stereo_frames(self) -> Iterator[StereoFrame]:
        """Rectified stereo frames in time order."""
        ...


@runtime_checkable
class Scan2dSource(Protocol):
    def laser_scans(self) -> Iterator[Scan2d]:
        """2D laser scans in time order."""
        ...


@runtime_checkable
class WheelSource(Protocol):
    def wheel_odometry(self) -> WheelOdometry:
        """All wheel-odometry samples."""
        ...


@runtime_checkable
class GroundTruthSource(Protocol):
    def ground_truth(self) -> Trajectory:
        """Reference poses (motion capture, RTK, the simulator's truth)."""
        ...
