"""The one place a dataset reader is picked for a path (KISS-ICP's dataset factory: one class per
format, chosen by what the path holds). ``sensor`` says what the estimator reads; :func:`source_kind`
says what the path holds; the pair names the reader:

    sensor   kind                 reader
    lidar    pcd folder           lidarsets.PcdFolder
    lidar    kitti folder         lidarsets.KittiFolder
    lidar    bag (or other)       lidarsets.BagLidarDataset (PointCloud2, optional Imu)
    stereo   bag                  stereosets.BagStereo (two image topics, Imu; a Kalibr camchain)
    stereo   EuRoC (or other)     stereosets.EurocStereo (its sensor.yaml files, or a camchain)

Every reader gives its IMU by ``imu()`` (``interfaces.sources``). The simulator's datasets are made by
the simulator (``sim``), never here: ``io`` does not import it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, overload

from imuslam.errors import InputError
from imuslam.io.camcalib import read_kalibr_camchain
from imuslam.io.kinds import SourceKind, source_kind
from imuslam.io.lidarsets import BagLidarDataset, KittiFolder, PcdFolder
from imuslam.io.stereosets import BagStereo, EurocStereo

Sensor = Literal["lidar", "stereo"]
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
) -> LidarFile | StereoFile:
    """The reader of ``path`` for ``sensor`` (table above). Topics name a bag's topics (None: the only
    one of its type); ``use_imu=False`` leaves a LiDAR bag's IMU unread; ``camchain`` (Kalibr YAML)
    calibrates the cameras (a stereo bag needs it, an EuRoC folder has its own sensor.yaml files)."""
    p = Path(path)
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
    raise ValueError(f"sensor {sensor!r}: expected one of lidar, stereo")
