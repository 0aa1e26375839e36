"""The stereo + IMU datasets: an EuRoC folder and a ROS 1 / ROS 2 / MCAP bag with two image topics.

A dataset lists its stereo pairs (time, and how to load both images), gives the IMU log by ``imu()`` and
the rectification of its stereo calibration (``interfaces.StereoSource``). Pairs listed but absent are
counted as missing; pairs that cannot be decoded as unreadable; an image whose size disagrees with the
calibration is an input error. :func:`imuslam.io.datasets.open_dataset` picks one for a path.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog
from imuslam.io.bag import Bag
from imuslam.io.camcalib import Rectification, StereoCalibration, read_calibration
from imuslam.io.rosmsg import image_from_msg, stamp_ns

U8Image = NDArray[np.uint8]


@dataclass
class FrameCounts:
    """What the reader skipped: listed but missing files, undecodable files."""

    listed: int = 0
    missing: int = 0
    unreadable: int = 0
    missing_names: list[str] = field(default_factory=list)


class _Stereo:
    """What both readers share: the calibration, the IMU log, the counts of skipped pairs, the check of
    an image's size against the calibration."""

    calibration: StereoCalibration
    counts: FrameCounts
    source: str
    _imu: ImuLog

    def imu(self) -> ImuLog:
        return self._imu

    def rectification(self) -> Rectification:
        return self.calibration.rectification()

    def skipped_frames(self) -> dict[str, int]:
        return {"missing": self.counts.missing, "unreadable": self.counts.unreadable}

    def _check_size(self, left: U8Image, right: U8Image, where: tuple[str, str]) -> None:
        """An image of another size than its camera's calibration is an InputError naming it
        (``where``: how to name the left and the right image)."""
        cal = self.calibration
        for img, cam, name in ((left, cal.left, where[0]), (right, cal.right, where[1])):
            if img.shape != (cam.height, cam.width):
                raise InputError(
                    f"{name} is {img.shape[1]}x{img.shape[0]}; the calibration "
                    f"({cal.source}) says {cam.width}x{cam.height}"
                )


def _read_list(csv_path: Path) -> dict[int, str]:
    if not csv_path.is_file():
        raise InputError(
            f"{csv_path}: not found; expected the EuRoC image list (timestamp, filename)"
        )
    out: dict[int, str] = {}
    with open(csv_path) as fh:
        for i, row in enumerate(csv.reader(fh), start=1):
            if not row or row[0].lstrip().startswith("#"):
                continue
            if len(row) < 2:
                raise InputError(f"{csv_path}, line {i}: expected 'timestamp [ns],filename'")
            try:
                out[int(row[0])] = row[1].strip()
            except ValueError:
                raise InputError(
                    f"{csv_path}, line {i}: timestamp '{row[0]}' is not an integer"
                ) from None
    return out


def load_gray(path: Path) -> U8Image | None:
    """A grayscale uint8 image, or None when the file cannot be decoded."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    return None if img is None else np.asarray(img, dtype=np.uint8)


class EurocStereo(_Stereo):
    """An EuRoC ``mav0`` folder: ``cam0``, ``cam1`` (``data.csv`` + ``data/*.png``), ``imu0/data.csv``,
    ``cam*/sensor.yaml``. A Kalibr camchain can replace the ``sensor.yaml`` calibration."""

    def __init__(self, path: str | Path, calibration: StereoCalibration | None = None) -> None:
        from imuslam.io.readers import read_euroc

        p = Path(path)
        root = p / "mav0" if (p / "mav0").is_dir() else p
        if not (root / "cam0").is_dir():
            raise InputError(f"{p}: not an EuRoC folder (no mav0/cam0)")
        if not (root / "cam1").is_dir():
            raise InputError(f"{p}: no cam1 folder; stereo VO needs the second camera")
        self.source = str(root)
        self.calibration = calibration or read_calibration(root)
        self._imu = read_euroc(root / "imu0" / "data.csv")
        left = _read_list(root / "cam0" / "data.csv")
        right = _read_list(root / "cam1" / "data.csv")
        self.counts = FrameCounts()
        t_all = sorted(set(left) | set(right))
        self.counts.listed = len(t_all)
        self._pairs: list[tuple[int, Path, Path]] = []
        for t in t_all:
            if t not in left or t not in right:
                self.counts.missing += 1
                self.counts.missing_names.append(f"{t}: listed for one camera only")
                continue
            pl, pr = root / "cam0" / "data" / left[t], root / "cam1" / "data" / right[t]
            gone = [str(q) for q in (pl, pr) if not q.is_file()]
            if gone:
                self.counts.missing += 1
                self.counts.missing_names.extend(gone)
                continue
            self._pairs.append((t, pl, pr))
        if not self._pairs:
            raise InputError(f"{root}: none of the {len(t_all)} listed stereo pairs exists on disk")

    def __len__(self) -> int:
        return len(self._pairs)

    @property
    def t_ns(self) -> NDArray[np.int64]:
        """The listed pairs' times (the tracks are scored at them)."""
        return np.array([t for t, _, _ in self._pairs], dtype=np.int64)

    def frames(self) -> Iterator[tuple[int, U8Image | None, U8Image | None]]:
        for t, pl, pr in self._pairs:
            a, b = load_gray(pl), load_gray(pr)
            if a is None or b is None:
                self.counts.unreadable += 1
                yield t, None, None
                continue
            self._check_size(a, b, (f"{pl}: image", f"{pr}: image"))
            yield t, a, b


class BagStereo(_Stereo):
    """A ROS 1 / ROS 2 / MCAP bag with two image topics (``sensor_msgs/Image`` mono8 / bgr8, or
    ``CompressedImage``) and an IMU topic, calibrated by a Kalibr camchain. Left and right images pair by
    equal header stamps (within ``max_dt_ns``); an image without its partner is counted as missing, one
    that cannot be decoded as unreadable."""

    def __init__(
        self,
        path: str | Path,
        calibration: StereoCalibration,
        left_topic: str,
        right_topic: str,
        imu_topic: str | None = None,
        max_dt_ns: int = 1_000_000,
    ) -> None:
        self.path = Path(path)
        self.source = str(path)
        self.calibration = calibration
        self.left_topic, self.right_topic, self.max_dt_ns = left_topic, right_topic, max_dt_ns
        types = ["sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"]
        with Bag(self.path) as b:
            b.connections_of([left_topic, right_topic], types)
            self._imu = b.imu(imu_topic)
            self._n = min(b.count(left_topic), b.count(right_topic))
            listed = b.count(left_topic) + b.count(right_topic)
        self.counts = FrameCounts(listed=listed)

    def __len__(self) -> int:
        return self._n

    @staticmethod
    def _gray(msg: object) -> U8Image | None:
        import cv2

        try:
            _, img = image_from_msg(msg)
        except InputError:
            return None
        if img.dtype != np.uint8:
            return None
        if img.ndim == 3:
            img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY)
        return np.ascontiguousarray(img)

    def frames(self) -> Iterator[tuple[int, U8Image | None, U8Image | None]]:
        pending: dict[str, dict[int, object]] = {self.left_topic: {}, self.right_topic: {}}
        with Bag(self.path) as b:
            for topic, _, msg in b.messages([self.left_topic, self.right_topic]):
                t = stamp_ns(msg)
                other = self.right_topic if topic == self.left_topic else self.left_topic
                match = next((k for k in pending[other] if abs(k - t) <= self.max_dt_ns), None)
                if match is None:
                    pending[topic][t] = msg
                    continue
                partner = pending[other].pop(match)
                lm, rm = (msg, partner) if topic == self.left_topic else (partner, msg)
                # older unmatched images will not find a partner any more
                for tp in pending:
                    for k in [k for k in pending[tp] if k < t - 10 * self.max_dt_ns]:
                        del pending[tp][k]
                        self.counts.missing += 1
                a, c = self._gray(lm), self._gray(rm)
                if a is None or c is None:
                    self.counts.unreadable += 1
                    yield t, None, None
                    continue
                at = f"image at {t} ns"
                names = (
                    f"{self.path}: {self.left_topic} {at}",
                    f"{self.path}: {self.right_topic} {at}",
                )
                self._check_size(a, c, names)
                yield t, a, c
        self.counts.missing += sum(len(v) for v in pending.values())
