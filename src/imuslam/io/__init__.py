"""Readers and writers of logs: imu_tk text, EuRoC, generic CSV, ROS 1 / ROS 2 bags and MCAP, TUM, KITTI;
the estimators' datasets (PCD and KITTI folders, LiDAR and stereo bags, EuRoC stereo), one class per
format, picked for a path by ``imuslam.io.datasets.open_dataset``.

The package itself imports nothing heavy (``imuslam.io.results`` is used by every command's option
checks before numpy is needed); ``ImuLog`` is re-exported lazily."""

from typing import Any

from imuslam.errors import InputError

__all__ = ["ImuLog", "InputError"]


def __getattr__(name: str) -> Any:
    if name == "ImuLog":
        from imuslam.interfaces.imu import ImuLog

        return ImuLog
    raise AttributeError(f"module 'imuslam.io' has no attribute {name!r}")
