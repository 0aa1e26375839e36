"""The LiDAR datasets: scans already in memory, a folder of PCD scans, a KITTI-style folder of ``.bin``
scans with times, and a ROS 1 / ROS 2 / MCAP bag. Each yields :class:`Scan3d` in time order
(``interfaces.LidarSource``) and gives its IMU log by ``imu()`` (None when it has none);
:func:`imuslam.io.datasets.open_dataset` picks one for a path.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces import Scan3d
from imuslam.interfaces.imu import ImuLog
from imuslam.io import rosmsg
from imuslam.io.bag import Bag
from imuslam.io.pointcloud import read_kitti_bin, read_pcd

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


def azimuth_times(points_l: FloatArray, scan_period_s: float) -> NDArray[np.float32]:
    """Per-point time offsets (N,) s from the azimuth of each point, for scans without a time field: a
    counter-clockwise sweep from the -x axis over ``scan_period_s``."""
    az = np.arctan2(points_l[:, 1], points_l[:, 0]) + np.pi  # [0, 2 pi)
    return (az / (2 * np.pi) * scan_period_s).astype(np.float32)


class MemoryDataset:
    """Scans and an optional IMU log already in memory (the simulator, a test)."""

    def __init__(
        self, scans: list[Scan3d], imu: ImuLog | None = None, name: str = "<memory>"
    ) -> None:
        self._scans = scans
        self._imu = imu
        self.name = name

    def lidar_scans(self) -> Iterator[Scan3d]:
        return iter(self._scans)

    def imu(self) -> ImuLog | None:
        return self._imu

    def __len__(self) -> int:
        return len(self._scans)


def _natural(p: Path) -> list[object]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


class _FolderDataset:
    name: str
    files: list[Path]
    t_ns: NDArray[np.int64]
    scan_period_s: float

    def _times(self, folder: Path, times: Path | None, rate_hz: float) -> None:
        if times is not None:
            try:
                t = np.loadtxt(times, ndmin=1, usecols=0)
            except (OSError, ValueError) as exc:
                raise InputError(
                    f"{times}: cannot read scan times (one time in seconds per line): {exc}"
                ) from exc
            if len(t) < len(self.files):
                raise InputError(f"{times}: {len(t)} times for {len(self.files)} scans in {folder}")
            t = t[: len(self.files)]
            if np.any(np.diff(t) <= 0):
                k = int(np.argmax(np.diff(t) <= 0)) + 1
                raise InputError(
                    f"{times}: line {k + 1}: scan times go back ({t[k]:.6f} s after {t[k - 1]:.6f} s)"
                )
            self.t_ns = np.round(t * 1e9).astype(np.int64)
            self.scan_period_s = float(np.median(np.diff(t))) if len(t) > 1 else 1.0 / rate_hz
        else:
            log.warning(
                "%s: no scan times given; scans are taken %.3g s apart", folder, 1.0 / rate_hz
            )
            self.t_ns = np.round(np.arange(len(self.files)) / rate_hz * 1e9).astype(np.int64)
            self.scan_period_s = 1.0 / rate_hz

    def imu(self) -> ImuLog | None:
        return None

    def __len__(self) -> int:
        return len(self.files)


class PcdFolder(_FolderDataset):
    """``*.pcd`` scans of a folder in natural order; times from ``times`` (one per line, s) or ``rate_hz``.
    Points are timed from their azimuth unless the PCD has a time field (``t``/``time``/``timestamp``)."""

    def __init__(self, folder: str | Path, times: str | Path | None = None, rate_hz: float = 10.0,
                 deskew: bool = False) -> None:  # fmt: skip
        f = Path(folder)
        self.files = sorted(f.glob("*.pcd"), key=_natural)
        if not self.files:
            raise InputError(f"{f}: no .pcd files")
        self.name = str(f)
        self.deskew = deskew
        self._times(f, Path(times) if times else None, rate_hz)

    def lidar_scans(self) -> Iterator[Scan3d]:
        for path, t in zip(self.files, self.t_ns, strict=True):
            d = read_pcd(path)
            pts = np.column_stack([d["x"], d["y"], d["z"]]).astype(np.float32)
            tf = next((d[k] for k in ("t", "time", "timestamp") if k in d), None)
            toff: NDArray[np.float32]
            if tf is not None:
                tf64 = np.asarray(tf, np.float64)
                toff = (tf64 - tf64.min()).astype(np.float32)
            elif self.deskew:
                toff = azimuth_times(pts.astype(float), self.scan_period_s)
            else:  # a registered (already motion-compensated) scan: all points at its stamp
                toff = np.zeros(len(pts), np.float32)
            ring = np.asarray(d["ring"], np.uint16) if "ring" in d else np.zeros(0, np.uint16)
            inten = np.asarray(d.get("intensity", np.zeros(len(pts))), np.float32)
            yield Scan3d(int(t), pts, toff, ring, inten)


class KittiFolder(_FolderDataset):
    """A KITTI odometry sequence: ``velodyne/*.bin`` (or ``*.bin`` in the folder) and ``times.txt``.
    KITTI scans are already motion-compensated, so all points take the scan time."""

    def __init__(self, folder: str | Path, rate_hz: float = 10.0) -> None:
        f = Path(folder)
        sub = f / "velodyne"
        self.files = sorted((sub if sub.is_dir() else f).glob("*.bin"), key=_natural)
        if not self.files:
            raise InputError(f"{f}: no .bin scans (looked in {sub} and {f})")
        self.name = str(f)
        times = f / "times.txt"
        self._times(f, times if times.exists() else None, rate_hz)

    def lidar_scans(self) -> Iterator[Scan3d]:
        for path, t in zip(self.files, self.t_ns, strict=True):
            pts, refl = read_kitti_bin(path)
            yield Scan3d(int(t), pts.astype(np.float32), np.zeros(len(pts), np.float32),
                         np.zeros(0, np.uint16), refl.astype(np.float32))  # fmt: skip


class BagLidarDataset:
    """A ROS 1 / ROS 2 / MCAP bag with a PointCloud2 topic and (optionally) an Imu topic.

    Checks what readers leave to us: a scan without a per-point time field is timed from its azimuth
    (one warning); a time field whose span in a scan is not a plausible sweep (1e-4 .. 1 s) is an
    InputError naming the scan (an unknown unit, e.g. microseconds as floats); a ring field that is all
    zeros is treated as absent. NaN points dropped by the reader are counted.
    """

    def __init__(self, path: str | Path, points_topic: str | None = None, imu_topic: str | None = None,
                 use_imu: bool = True) -> None:  # fmt: skip
        self.path = Path(path)
        self.name = str(self.path)
        with Bag(self.path) as b:
            self.points_topic = b.topic_of_type([rosmsg.POINTCLOUD2], points_topic)
            self.n_scans = b.count(self.points_topic)
            has_imu = any(m == rosmsg.IMU for m in b.topics().values())
            self.imu_topic = (
                b.topic_of_type([rosmsg.IMU], imu_topic)
                if (use_imu and (has_imu or imu_topic))
                else None
            )
        self.n_nan_dropped = 0
        self.n_azimuth_timed = 0
        self._imu: ImuLog | None = None

    def __len__(self) -> int:
        return self.n_scans

    def imu(self) -> ImuLog | None:
        if self.imu_topic is None:
            return None
        if self._imu is None:
            with Bag(self.path) as b:
                self._imu = b.imu(self.imu_topic)
        return self._imu

    def lidar_scans(self) -> Iterator[Scan3d]:
        prev_stamp: int | None = None
        with Bag(self.path) as b:
            for k, (_, _, msg) in enumerate(b.messages([self.points_topic])):
                s = rosmsg.scan3d_from_msg(msg)
                self.n_nan_dropped += int(msg.width) * int(msg.height) - len(s)
                period = (
                    (s.t_ns - prev_stamp) * 1e-9
                    if prev_stamp is not None and s.t_ns > prev_stamp
                    else 0.1
                )
                prev_stamp = s.t_ns
                if len(s):
                    span = float(np.max(s.t_offset_s) - np.min(s.t_offset_s))
                    if span == 0.0:
                        if self.n_azimuth_timed == 0:
                            log.warning("%s: scans have no per-point time field; points are timed from their "
                                        "azimuth over %.3g s", self.points_topic, period)  # fmt: skip
                        self.n_azimuth_timed += 1
                        s.t_offset_s = azimuth_times(
                            s.points_l.astype(np.float64), min(period, 0.2)
                        )
                    elif not 1e-4 <= span <= 1.0:
                        raise InputError(
                            f"{self.path}:{self.points_topic}: scan {k}: point times span {span:.6g} "
                            "after conversion to seconds; the time field is in an unknown unit "
                            "(expected float seconds or integer nanoseconds)"
                        )
                    if len(s.ring) and not np.any(s.ring):
                        s.ring = np.zeros(0, np.uint16)
                yield s
