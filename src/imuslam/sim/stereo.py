"""A simulated pinhole stereo pair observing landmarks on the world's surfaces, with known correspondences.

Camera frame c: x right, y down, z forward (optical). The right camera sits at ``+baseline`` along the
left camera's x. A landmark is seen when it is in front, inside both images, closer than ``max_depth`` and
not occluded (the first surface hit along the ray is the landmark's own, within 1 cm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces.camera import StereoFrame
from imuslam.sim.lidar import cast_rays
from imuslam.sim.world import World

FloatArray = NDArray[np.float64]

# body (x forward, y left, z up) -> optical camera (x right, y down, z forward)
R_B_C_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass
class StereoConfig:
    """Pinhole intrinsics (px), image size, baseline (m), pixel noise (px) and depth limit (m)."""

    fx: float = 458.0
    fy: float = 457.0
    cx: float = 367.0
    cy: float = 248.0
    width: int = 752
    height: int = 480
    baseline: float = 0.11
    pixel_noise: float = 0.5
    max_depth: float = 20.0


def project(points_c: FloatArray, cfg: StereoConfig) -> tuple[FloatArray, FloatArray]:
    """Left and right pixels (N, 2) of points in the left camera frame (N, 3)."""
    z = points_c[:, 2]
    u = cfg.fx * points_c[:, 0] / z + cfg.cx
    v = cfg.fy * points_c[:, 1] / z + cfg.cy
    ur = cfg.fx * (points_c[:, 0] - cfg.baseline) / z + cfg.cx
    return np.stack([u, v], axis=1), np.stack([ur, v], axis=1)


def triangulate(uv_left: FloatArray, uv_right: FloatArray, cfg: StereoConfig) -> FloatArray:
    """Points (N, 3) in the left camera frame from rectified stereo pixels: z = f b / disparity."""
    disp = uv_left[:, 0] - uv_right[:, 0]
    z = cfg.fx * cfg.baseline / disp
    x = (uv_left[:, 0] - cfg.cx) * z / cfg.fx
    y = (uv_left[:, 1] - cfg.cy) * z / cfg.fy
    return np.stack([x, y, z], axis=1)


def observe(
    landmarks_w: FloatArray,
    R_w_c: FloatArray,
    p_w_c: FloatArray,
    world: World,
    cfg: StereoConfig,
    rng: np.random.Generator,
    t_ns: int = 0,
) -> StereoFrame:
    """Noisy observations of the visible landmarks from the left camera pose ``(R_w_c, p_w_c)``."""
    pc = (landmarks_w - p_w_c) @ R_w_c  # R_c_w (p - p_c)
    front = (pc[:, 2] > 0.1) & (pc[:, 2] < cfg.max_depth)
    idx = np.flatnonzero(front)
    uvl, uvr = project(pc[idx], cfg)
    inside = (
        (uvl[:, 0] >= 0) & (uvl[:, 0] < cfg.width) & (uvl[:, 1] >= 0) & (uvl[:, 1] < cfg.height)
        & (uvr[:, 0] >= 0) & (uvr[:, 0] < cfg.width)
    )  # fmt: skip
    idx, uvl, uvr = idx[inside], uvl[inside], uvr[inside]
    d = landmarks_w[idx] - p_w_c
    rng_d = np.linalg.norm(d, axis=1)
    dist, _ = cast_rays(
        np.repeat(p_w_c[None], len(idx), axis=0), d / rng_d[:, None], world.centre, world.u, world.v,
        world.half, cfg.max_depth + 1.0,
    )  # fmt: skip
    vis = dist >= rng_d - 0.01
    idx, uvl, uvr = idx[vis], uvl[vis], uvr[vis]
    if cfg.pixel_noise > 0:
        nl = rng.normal(size=uvl.shape) * cfg.pixel_noise
        uvl = uvl + nl
        uvr = uvr + np.stack([rng.normal(size=len(uvr)) * cfg.pixel_noise, nl[:, 1]], axis=1)
    return StereoFrame(t_ns, idx.astype(np.int64), uvl, uvr)
