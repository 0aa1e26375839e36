"""From a deskewed scan to the points that are registered: LOAM features or voxel-downsampled points."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imuslam.lio.config import FrontEndConfig
from imuslam.lio.features import FeatureParams, loam_features, voxel_downsample

FloatArray = NDArray[np.float64]


def select_points(
    points_l: FloatArray,
    t_s: FloatArray,
    ring: NDArray[np.integer] | None,
    cfg: FrontEndConfig,
) -> tuple[FloatArray, FloatArray]:
    """Plane-like points (N, 3) and edge points (E, 3) of a deskewed scan (LiDAR frame).

    ``features`` mode needs the ring of each point; without it the direct mode is used.
    """
    r = np.linalg.norm(points_l, axis=1)
    keep = (r >= cfg.min_range) & (r <= cfg.max_range)
    pts, t = points_l[keep], t_s[keep]
    if cfg.mode == "direct" or ring is None:
        return pts[voxel_downsample(pts, cfg.scan_voxel)], np.zeros((0, 3))
    rg = np.asarray(ring)[keep]
    params = FeatureParams(edge_threshold=cfg.edge_threshold, plane_threshold=cfg.plane_threshold)
    e_idx, p_idx, _ = loam_features(pts, rg, t, params)
    planes = pts[p_idx]
    return planes[voxel_downsample(planes, cfg.scan_voxel)], pts[e_idx]
