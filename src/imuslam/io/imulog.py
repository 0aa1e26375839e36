"""Moved to :mod:`imuslam.interfaces.imu`; this re-export keeps old imports working for now."""

from imuslam.errors import InputError
from imuslam.interfaces.imu import AccelUnit, GyroUnit, ImuLog

__all__ = ["AccelUnit", "GyroUnit", "ImuLog", "InputError"]
