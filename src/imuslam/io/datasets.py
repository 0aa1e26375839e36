"""The one place a dataset reader is picked for a path (KISS-ICP's dataset factory: one class per
format, chosen by what the path holds). ``sensor`` says what the estimator reads; :func:`source_kind`
says what the path holds; the pair names the reader:

    sensor   kind                 reader
    lidar    pcd folder           lidarsets.PcdFolder
    lidar    kitti folder         lidarsets.KittiFolder
    lidar    bag (or other)       lidarsets.BagLidarDataset (PointCloud2, optional Imu)
    stereo   bag                  stereosets.BagStereo (two image topics, Imu; a Kalibr camchain)
    stereo   EuRoC (or other)     stereosets.EurocStereo (its sensor.yaml files, or a camchain)
    laser    bag                  laserload.read_bag_laser (LaserScan / MultiEchoLaserScan, Imu, Odometry)
    laser    sim folder           laserload.read_sim_room (the output of ``imuslam simulate room``)
    laser    file                 carmen.read_carmen / read_breezyslam (by the file's name)

A 2D laser log is read whole into a :class:`~imuslam.io.laserlog.LaserLog` (``laserload.load_laser_log``).

Every reader and the laser log give their IMU by ``imu()`` (``interfaces.sources``). The simulator's datasets are made by
the simulator (``sim``), never here: ``io`` does not import it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, overload

from imuslam.errors import InputError
from imuslam.io.camcalib import read_kalibr_camchain
from imuslam.io.kinds import SourceKind, source_kind
from imuslam.io.laserload import load_laser_log
from imuslam.io.laserlog import LaserLog
from imuslam.io.lidarsets import BagLidarDataset, KittiFolder, PcdFolder
from imuslam.io.stereosets import BagStereo, EurocStereo

Sensor = Literal["lidar", "stereo", "laser"]
LidarFile = PcdFolder | KittiFolder | BagLidarDataset
StereoFile = EurocStereo | BagStereo

__all__ = ["LidarFile", "Sensor", "StereoFile", "open_dataset"]


@overload
def open_dataset(
    path: str | Path,
    sensor: Literal["lidar"],
    *,
    imu_topic: str | None = None,
    points_topic: str | None = None,
    use_imu: bool = True,
) -> LidarFile: ...


@overload
def open_dataset(
    path: str | Path,
    sensor: Literal["stereo"],
    *,
    imu_topic: str | None = None,
    camchain: Path | None = None,
    left_topic: str | None = None,
    right_topic: str | None = None,
) -> StereoFile: ...


@overload
def open_dataset(
    path: str | Path,
    sensor: Literal["laser"],
    *,
    imu_topic: str | None = None,
    use_imu: bool = True,
    fmt: str = "auto",
    scan_topic: str | None = None,
    odom_topic: str | None = None,
) -> LaserLog: ...


def open_dataset(
    path: str | Path,
    sensor: Sensor,
    *,
    imu_topic: str | None = None,
    points_topic: str | None = None,
    use_imu: bool = True,
    camchain: Path | None = None,
    left_topic: str | None = None,
    right_topic: str | None = None,
    fmt: str = "auto",
    scan_topic: str | None = None,
    odom_topic: str | None = None,
) -> LidarFile | StereoFile | LaserLog:
    """The reader of ``path`` for ``sensor`` (table above). Topics name a bag's topics (None: the only
    one of its type); ``use_imu=False`` leaves a LiDAR bag's or a laser log's IMU unread; ``camchain``
    (Kalibr YAML) calibrates the cameras (a stereo bag needs it, an EuRoC folder has its own
    sensor.yaml files); ``fmt`` names a laser log's format (auto: from what the path holds)."""
    p = Path(path)
    if sensor == "laser":
        return load_laser_log(p, fmt, scan_topic, imu_topic, odom_topic, use_imu)
    if sensor == "lidar":
        kind = source_kind(p)
        if kind is SourceKind.MISSING:
            raise InputError(f"{p}: no such bag or folder")
        if kind is SourceKind.PCD_FOLDER:
            return PcdFolder(p)
        if kind is SourceKind.KITTI_FOLDER:
            return KittiFolder(p)
        return BagLidarDataset(p, points_topic, imu_topic, use_imu=use_imu)
    if sensor == "stereo":
        cal = read_kalibr_camchain(camchain) if camchain is not None else None
        if source_kind(p) is SourceKind.BAG:
            if cal is None or left_topic is None or right_topic is None:
                raise InputError(
                    f"{p}: a bag needs --camchain, --left-topic and --right-topic (image topics)"
                )
            return BagStereo(p, cal, left_topic, right_topic, imu_topic)
        return EurocStereo(p, cal)
    raise ValueError(f"sensor {sensor!r}: expected one of lidar, stereo, laser")
