"""Dataset protocols: what an estimator pipeline asks of a dataset (a bag, EuRoC, KITTI, the simulator).

A dataset implements whichever it can; a pipeline states the ones it needs in its signature, as a
Protocol that inherits them (``lio.pipeline.LidarDataset`` is a ``LidarSource`` with an optional IMU).
No ``hasattr`` checks: ``isinstance(data, LidarSource)`` works (``runtime_checkable``).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, runtime_checkable

from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan3d

__all__ = ["ImuSource", "LidarSource"]


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
