"""Readers and writers of logs: imu_tk text, EuRoC, generic CSV, ROS 1 / ROS 2 bags and MCAP, TUM, KITTI."""

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog

__all__ = ["ImuLog", "InputError"]
