"""Ray-cast rendering of rectified stereo images of a :class:`~imuslam.sim.world.World` (numba).

Every pixel's ray (pinhole, no distortion: the images are rectified by construction) is intersected
with every rectangle; the nearest hit is shaded with a procedural texture: three octaves of value noise
(bilinear-interpolated hashed lattice values, smoothstep weights; Perlin, "An image synthesizer", 1985)
in the surface's own metric coordinates, so a point looks the same from every view, as a real wall does.
Octaves finer than the pixel's footprint on the surface fade out (a cheap mip-map), which keeps far,
grazing floor from aliasing into noise. Sensor noise is added per pixel, then the image is quantised to
uint8.

Camera frame c: x right, y down, z forward. The right camera sits at ``+baseline`` along the left x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import NDArray

from imuslam.sim.world import World

FloatArray = NDArray[np.float64]

# texture octaves: lattice cell (m) and amplitude (grey levels)
_CELLS = np.array([0.35, 0.12, 0.045])
_AMPS = np.array([70.0, 45.0, 30.0])


@dataclass
class CameraRig:
    """Rectified stereo intrinsics (px), image size, baseline (m), image noise (grey levels, 1-sigma)."""

    fx: float = 436.0
    fy: float = 436.0
    cx: float = 376.0
    cy: float = 240.0
    width: int = 752
    height: int = 480
    baseline: float = 0.11
    noise: float = 2.0

    @property
    def K(self) -> FloatArray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@nb.njit(cache=True, inline="always")
def _hash(i: int, j: int, s: int) -> float:  # pragma: no cover - compiled
    h = (i * 73856093) ^ (j * 19349663) ^ (s * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF) / 65535.0


@nb.njit(cache=True, inline="always")
def _value_noise(a: float, b: float, s: int) -> float:  # pragma: no cover - compiled
    i = int(np.floor(a))
    j = int(np.floor(b))
    fa = a - i
    fb = b - j
    wa = fa * fa * (3 - 2 * fa)
    wb = fb * fb * (3 - 2 * fb)
    v00 = _hash(i, j, s)
    v10 = _hash(i + 1, j, s)
    v01 = _hash(i, j + 1, s)
    v11 = _hash(i + 1, j + 1, s)
    return (1 - wa) * (1 - wb) * v00 + wa * (1 - wb) * v10 + (1 - wa) * wb * v01 + wa * wb * v11


@nb.njit(cache=True)
def texture(
    a: float, b: float, sid: int, base: float, footprint: float, cells: FloatArray, amps: FloatArray
) -> float:  # pragma: no cover - compiled
    """Grey level of surface ``sid`` at its metric coordinates (a, b); ``footprint`` m per pixel."""
    g = 40.0 + 120.0 * base
    for k in range(cells.shape[0]):
        w = min(1.0, max(0.0, cells[k] / (2.0 * footprint) - 1.0))
        if w > 0:
            g += w * amps[k] * (_value_noise(a / cells[k], b / cells[k], sid * 7 + k) - 0.5) * 2.0
    return g


@nb.njit(cache=True, parallel=True)
def render_image(
    R_w_c: FloatArray,
    p_w_c: FloatArray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    centre: FloatArray,
    u: FloatArray,
    v: FloatArray,
    half: FloatArray,
    sid: NDArray[np.int64],
    base: FloatArray,
    cells: FloatArray,
    amps: FloatArray,
    two_sided: NDArray[np.int64],
    bbox: NDArray[np.int64],
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Noise-free grey image (H, W) float and depth along z (H, W) m (inf: no hit) of a pinhole camera.

    Rectangles with ``two_sided == 0`` are seen only from the side their normal ``u x v`` points to (the
    faces of boxes point outwards); the others (floor, free walls) from both sides. ``bbox`` (Q, 4)
    ``[u_min, u_max, v_min, v_max]`` is each rectangle's conservative pixel bounding box; a pixel tests
    only the rectangles whose box holds it."""
    img = np.zeros((height, width))
    depth = np.full((height, width), np.inf)
    q = centre.shape[0]
    nrm = np.empty((q, 3))
    for k in range(q):
        nrm[k, 0] = u[k, 1] * v[k, 2] - u[k, 2] * v[k, 1]
        nrm[k, 1] = u[k, 2] * v[k, 0] - u[k, 0] * v[k, 2]
        nrm[k, 2] = u[k, 0] * v[k, 1] - u[k, 1] * v[k, 0]
    for r in nb.prange(height):
        yc = (r - cy) / fy
        active = np.empty(q, dtype=np.int64)
        na = 0
        for k in range(q):
            if bbox[k, 2] <= r <= bbox[k, 3]:
                active[na] = k
                na += 1
        for col in range(width):
            xc = (col - cx) / fx
            dx = R_w_c[0, 0] * xc + R_w_c[0, 1] * yc + R_w_c[0, 2]
            dy = R_w_c[1, 0] * xc + R_w_c[1, 1] * yc + R_w_c[1, 2]
            dz = R_w_c[2, 0] * xc + R_w_c[2, 1] * yc + R_w_c[2, 2]
            best = np.inf
            bk = -1
            ba = 0.0
            bb = 0.0
            bcos = 1.0
            for ia in range(na):
                k = active[ia]
                if col < bbox[k, 0] or col > bbox[k, 1]:
                    continue
                den = nrm[k, 0] * dx + nrm[k, 1] * dy + nrm[k, 2] * dz
                if den > -1e-12 and two_sided[k] == 0:
                    continue  # back face of a closed box: hidden behind its front faces
                if abs(den) < 1e-12:
                    continue
                ox = centre[k, 0] - p_w_c[0]
                oy = centre[k, 1] - p_w_c[1]
                oz = centre[k, 2] - p_w_c[2]
                t = (nrm[k, 0] * ox + nrm[k, 1] * oy + nrm[k, 2] * oz) / den
                if t <= 1e-6 or t >= best:
                    continue
                hx = p_w_c[0] + t * dx - centre[k, 0]
                hy = p_w_c[1] + t * dy - centre[k, 1]
                hz = p_w_c[2] + t * dz - centre[k, 2]
                a = hx * u[k, 0] + hy * u[k, 1] + hz * u[k, 2]
                b = hx * v[k, 0] + hy * v[k, 1] + hz * v[k, 2]
                if abs(a) <= half[k, 0] and abs(b) <= half[k, 1]:
                    best = t
                    bk = k
                    ba = a
                    bb = b
                    bcos = abs(den) / np.sqrt(dx * dx + dy * dy + dz * dz)
            if bk >= 0:
                rng = best * np.sqrt(dx * dx + dy * dy + dz * dz)
                fp = rng / fx / max(bcos, 0.05)
                img[r, col] = texture(ba, bb, sid[bk], base[bk], fp, cells, amps)
                depth[r, col] = best  # t along a ray with unit z in the camera: the z-depth
    return img, depth


def _two_sided(world: World) -> NDArray[np.int64]:
    """1 for rectangles that are not faces of a box of the world (a box face is one-sided)."""
    out = np.ones(len(world), dtype=np.int64)
    for lo, hi in world.boxes:
        inside = np.all((world.centre >= lo - 1e-9) & (world.centre <= hi + 1e-9), axis=1)
        out[inside] = 0
    return out


def pixel_bbox(
    world: World, rig: CameraRig, R_w_c: FloatArray, p_w_c: FloatArray
) -> NDArray[np.int64]:
    """(Q, 4) ``[u_min, u_max, v_min, v_max]`` of each rectangle's projection, clipped to the image; the
    whole image when a corner is behind or near the camera plane, an empty box when all are behind."""
    W, H = rig.width, rig.height
    c = (
        world.centre[:, None, :]
        + np.array([-1, 1, 1, -1])[None, :, None] * (world.half[:, None, 0:1] * world.u[:, None, :])
        + np.array([-1, -1, 1, 1])[None, :, None] * (world.half[:, None, 1:2] * world.v[:, None, :])
    )
    pc = (c - p_w_c) @ R_w_c  # (Q, 4, 3) in the camera
    z = pc[..., 2]
    out = np.empty((len(world), 4), dtype=np.int64)
    zs = np.maximum(z, 1e-3)
    u = rig.fx * pc[..., 0] / zs + rig.cx
    v = rig.fy * pc[..., 1] / zs + rig.cy
    out[:, 0] = np.clip(np.floor(u.min(axis=1)) - 1, -1, W)
    out[:, 1] = np.clip(np.ceil(u.max(axis=1)) + 1, -1, W)
    out[:, 2] = np.clip(np.floor(v.min(axis=1)) - 1, -1, H)
    out[:, 3] = np.clip(np.ceil(v.max(axis=1)) + 1, -1, H)
    near = (z < 0.01).any(axis=1)
    out[near] = (0, W - 1, 0, H - 1)
    behind = (z < 0.01).all(axis=1)
    out[behind] = (1, 0, 1, 0)
    return out


def render_stereo(
    world: World,
    rig: CameraRig,
    R_w_c: FloatArray,
    p_w_c: FloatArray,
    rng: np.random.Generator | None = None,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8], FloatArray]:
    """Left and right uint8 images (H, W) from the left camera pose ``(R_w_c, p_w_c)``, and the left
    z-depth (H, W), m. ``rng`` adds the rig's Gaussian image noise."""
    args = (
        rig.fx, rig.fy, rig.cx, rig.cy, rig.width, rig.height, world.centre, world.u, world.v,
        world.half, world.surface_id, world.intensity, _CELLS, _AMPS, _two_sided(world),
    )  # fmt: skip
    R = np.ascontiguousarray(R_w_c, dtype=float)
    pl = np.asarray(p_w_c, dtype=float)
    pr = pl + R[:, 0] * rig.baseline
    left, depth = render_image(R, pl, *args, pixel_bbox(world, rig, R, pl))
    right, _ = render_image(R, pr, *args, pixel_bbox(world, rig, R, pr))
    out = []
    for img in (left, right):
        if rng is not None and rig.noise > 0:
            img = img + rng.normal(size=img.shape) * rig.noise
        out.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return out[0], out[1], depth
