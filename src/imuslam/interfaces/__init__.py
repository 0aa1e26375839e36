"""Records and dataset protocols shared by every layer above (imports only numpy, errors, geometry).

The simulator and the readers produce these; the estimators and evaluators consume them. Nobody imports
the simulator or a reader to get a type.
"""

from imuslam.interfaces.camera import StereoFrame
from imuslam.interfaces.imu import AccelUnit, GyroUnit, ImuLog
from imuslam.interfaces.lidar import Scan2d, Scan3d
from imuslam.interfaces.nav import ImuBias, NavState
from imuslam.interfaces.odometry import WheelOdometry
from imuslam.interfaces.sources import ImuSource, LidarSource, StereoRectification, StereoSource
from imuslam.interfaces.trajectory import Trajectory

__all__ = [
    "AccelUnit",
    "GyroUnit",
    "ImuBias",
    "ImuLog",
    "ImuSource",
    "LidarSource",
    "NavState",
    "Scan2d",
    "Scan3d",
    "StereoFrame",
    "StereoRectification",
    "StereoSource",
    "Trajectory",
    "WheelOdometry",
]
