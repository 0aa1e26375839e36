"""Readers and writers of logs: imu_tk text, EuRoC, generic CSV, ROS 1 / ROS 2 bags and MCAP, TUM, KITTI."""

from imuslam.io.imulog import ImuLog, InputError

__all__ = ["ImuLog", "InputError"]
