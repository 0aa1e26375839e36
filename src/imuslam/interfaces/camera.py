"""Stereo camera frames: feature observations (simulator, front ends) and optionally the images."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["StereoFrame"]


@dataclass
class StereoFrame:
    """One rectified stereo frame at ``t_ns``.

    ids: (M,) int64 landmark / track ids; uv_left, uv_right: (M, 2) pixels of each id in the left and
    right images (same row after rectification). image_left / image_right: (H, W) uint8 images when
    the frame comes from a camera (None for a simulated feature-only frame).
    """

    t_ns: int
    ids: NDArray[np.int64]
    uv_left: NDArray[np.float64]
    uv_right: NDArray[np.float64]
    image_left: NDArray[np.uint8] | None = None
    image_right: NDArray[np.uint8] | None = None
