"""What a path holds, decided in one place: :func:`imuslam.io.datasets.open_dataset` (the LiDAR and
stereo datasets), the IMU loader and the 2D laser loader ask :func:`source_kind` and map the answer to
their reader (:func:`format_of`), as KISS-ICP's dataset factory does with a file's kind."""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from pathlib import Path
from typing import TypeVar

from imuslam.errors import InputError

T = TypeVar("T")

BAG_SUFFIXES = (".bag", ".mcap", ".db3")


class SourceKind(StrEnum):
    BAG = "bag"  # a ROS 1 .bag, an .mcap, a .db3, or a ROS 2 bag folder (metadata.yaml)
    EUROC = "euroc"  # an EuRoC / ASL folder (mav0/, or imu0/ beside cam0/)
    PCD_FOLDER = "pcd folder"  # a folder of .pcd scans
    KITTI_FOLDER = "kitti folder"  # a folder of KITTI .bin scans, or one holding velodyne/
    SIM_FOLDER = "sim folder"  # the output of ``imuslam simulate`` (sim.npz)
    FOLDER = "folder"  # any other folder
    FILE = "file"  # any other file (text logs: the readers tell them apart by content)
    MISSING = "missing"


def is_bag(path: str | Path) -> bool:
    p = Path(path)
    return p.suffix in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


def source_kind(path: str | Path) -> SourceKind:
    """The kind of ``path`` from its name and, for a folder, the files it holds (nothing is parsed)."""
    p = Path(path)
    if is_bag(p):
        return SourceKind.BAG
    if not p.exists():
        return SourceKind.MISSING
    if not p.is_dir():
        return SourceKind.FILE
    if (p / "mav0").is_dir() or (p / "imu0").is_dir():
        return SourceKind.EUROC
    if (p / "sim.npz").is_file():
        return SourceKind.SIM_FOLDER
    if any(p.glob("*.pcd")):
        return SourceKind.PCD_FOLDER
    if any(p.glob("*.bin")) or (p / "velodyne").is_dir():
        return SourceKind.KITTI_FOLDER
    return SourceKind.FOLDER


def format_of(path: Path, formats: Mapping[SourceKind, T], other_folder: str) -> T | None:
    """A loader's format for ``path``: ``formats[source_kind(path)]``; a folder of another kind is one
    line ``"{path}: {other_folder}"`` (InputError); None for a file of another kind (the loader tells
    it by its name or content)."""
    kind = source_kind(path)
    if kind in formats:
        return formats[kind]
    if path.is_dir():
        raise InputError(f"{path}: {other_folder}")
    return None
