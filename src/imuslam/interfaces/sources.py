"""Dataset protocols: what an estimator pipeline asks of a dataset (a bag, EuRoC, KITTI, the simulator).

A dataset implements whichever it can; a pipeline states the ones it needs in its signature, as a
Protocol that inherits them (``lio.pipeline.LidarDataset`` is a ``LidarSource`` with an optional IMU).
Every dataset gives its IMU the one way, ``imu()`` (an :class:`ImuLog`; ``None`` from a dataset that may
have none). No ``hasattr`` checks: ``isinstance(data, LidarSource)`` works (``runtime_checkable``).
The readers are in ``imuslam.io`` (``io.datasets.open_dataset`` picks one for a path).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan3d

__all__ = ["ImuSource", "LidarSource", "StereoRectification", "StereoSource"]

U8Image = NDArray[np.uint8]


@runtime_checkable
class ImuSource(Protocol):
    def imu(self) -> ImuLog:
        """The whole IMU log, SI units (m/s^2, rad/s), sensor frame."""
        ...


@runtime_checkable
class LidarSource(Protocol):
    def lidar_scans(self) -> Iterator[Scan3d]:
        """3D scans in time order."""
        ...


class StereoRectification(Protocol):
    """A rectified stereo pair's geometry: intrinsics ``K`` (3, 3) shared by both images, baseline (m,
    right camera at +x), image size (pixels), the rectified left frame's pose in the body ``R_b_r``,
    ``p_b_r``, and the map from raw to rectified images."""

    K: NDArray[np.float64]
    baseline: float
    width: int
    height: int
    R_b_r: NDArray[np.float64]
    p_b_r: NDArray[np.float64]

    @property
    def f(self) -> float: ...

    def rectify(self, left: U8Image, right: U8Image) -> tuple[Any, Any]: ...


@runtime_checkable
class StereoSource(ImuSource, Protocol):
    """What the VIO pipeline reads: stereo pairs in time order, the IMU, the rectification; ``source``
    names the dataset in messages."""

    source: str

    def __len__(self) -> int: ...

    def rectification(self) -> StereoRectification: ...

    def skipped_frames(self) -> dict[str, int]:
        """Pairs listed but not given: ``{"missing": n, "unreadable": n}``."""
        ...

    def frames(self) -> Iterator[tuple[int, U8Image | None, U8Image | None]]:
        """(t_ns, left, right) in time order; None images for a pair that could not be decoded."""
        ...
