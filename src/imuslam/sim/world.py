"""A world of rectangles (finite planes) for ray casting: boxes are six rectangles.

A rectangle is a centre ``c``, two orthogonal unit edge directions ``u``, ``v`` with half-extents
``hu``, ``hv``; its normal is ``u x v``. Ready-made worlds: the 8 m x 8 m room of seed 000, an urban
block (seed 001) and a corridor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass
class World:
    """Rectangles as arrays: centre (Q, 3), u (Q, 3), v (Q, 3), half-extents (Q, 2), surface id (Q,),
    intensity (Q,) in [0, 1], and a name."""

    centre: FloatArray
    u: FloatArray
    v: FloatArray
    half: FloatArray
    surface_id: NDArray[np.int64]
    intensity: FloatArray
    name: str = "world"
    boxes: list[tuple[FloatArray, FloatArray]] = field(default_factory=list)

    @property
    def normal(self) -> FloatArray:
        return np.cross(self.u, self.v)

    @property
    def area(self) -> FloatArray:
        return 4.0 * self.half[:, 0] * self.half[:, 1]

    def __len__(self) -> int:
        return int(self.centre.shape[0])


class WorldBuilder:
    """Collects rectangles and boxes, then builds a :class:`World`."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._rects: list[tuple[FloatArray, FloatArray, FloatArray, float, float, float]] = []
        self._boxes: list[tuple[FloatArray, FloatArray]] = []

    def rect(
        self,
        c: list[float],
        u: list[float],
        v: list[float],
        hu: float,
        hv: float,
        intensity: float = 0.5,
    ) -> None:
        uu = np.asarray(u, float) / np.linalg.norm(u)
        vv = np.asarray(v, float) / np.linalg.norm(v)
        self._rects.append((np.asarray(c, float), uu, vv, hu, hv, intensity))

    def box(self, lo: list[float], hi: list[float], intensity: float = 0.5) -> None:
        """An axis-aligned box from corner ``lo`` to corner ``hi`` (m)."""
        a, b = np.asarray(lo, float), np.asarray(hi, float)
        c, h = (a + b) / 2, (b - a) / 2
        ex, ey, ez = np.eye(3)
        for sgn in (-1.0, 1.0):
            self.rect(list(c + sgn * h[0] * ex), list(ey), list(ez * sgn), h[1], h[2], intensity)
            self.rect(list(c + sgn * h[1] * ey), list(ez), list(ex * sgn), h[2], h[0], intensity)
            self.rect(list(c + sgn * h[2] * ez), list(ex), list(ey * sgn), h[0], h[1], intensity)
        self._boxes.append((a, b))

    def build(self) -> World:
        c, u, v, hu, hv, it = zip(*self._rects, strict=True)
        return World(
            np.array(c), np.array(u), np.array(v), np.stack([hu, hv], axis=1),
            np.arange(len(c), dtype=np.int64), np.array(it), self.name, list(self._boxes),
        )  # fmt: skip


def room_8x8(height: float = 2.5) -> World:
    """Seed 000's test field: an 8 m x 8 m room (walls 0.2 m thick, inner faces at +-4 m), floor, and a
    few boxes as obstacles near the walls, so that the centre stays free for the robot."""
    b = WorldBuilder("room_8x8")
    b.rect([0, 0, 0], [1, 0, 0], [0, 1, 0], 4.5, 4.5, 0.3)  # floor, normal +z
    for lo, hi in (
        ([-4.2, -4.2, 0], [4.2, -4.0, height]), ([-4.2, 4.0, 0], [4.2, 4.2, height]),
        ([-4.2, -4.0, 0], [-4.0, 4.0, height]), ([4.0, -4.0, 0], [4.2, 4.0, height]),
    ):  # fmt: skip
        b.box(lo, hi, 0.7)
    for lo, hi in (
        ([-3.9, -3.9, 0], [-3.3, -3.1, 0.8]), ([3.2, 3.3, 0], [3.9, 3.9, 1.2]), ([3.4, -3.9, 0], [3.9, -3.5, 0.5]),
        ([-3.9, 3.0, 0], [-3.5, 3.9, 1.0]),
    ):  # fmt: skip
        b.box(lo, hi, 0.5)
    return b.build()


def corridor(length: float = 40.0, width: float = 2.0, height: float = 2.6) -> World:
    """A long straight corridor along x with a few door recesses: degenerate for scan matching along x."""
    b = WorldBuilder("corridor")
    b.rect([length / 2, 0, 0], [1, 0, 0], [0, 1, 0], length / 2 + 1, width / 2 + 1, 0.3)
    b.rect([length / 2, 0, height], [0, 1, 0], [1, 0, 0], width / 2 + 1, length / 2 + 1, 0.3)
    b.box([-1, width / 2, 0], [length + 1, width / 2 + 0.2, height], 0.6)
    b.box([-1, -width / 2 - 0.2, 0], [length + 1, -width / 2, height], 0.6)
    b.box([-1.2, -width / 2, 0], [-1.0, width / 2, height], 0.6)
    b.box([length + 1.0, -width / 2, 0], [length + 1.2, width / 2, height], 0.6)
    for x in np.arange(5.0, length, 8.0):
        b.box([x, width / 2 - 0.15, 0], [x + 0.3, width / 2, 2.0], 0.9)  # door frames
    return b.build()


def urban_block(rng_seed: int = 0) -> World:
    """Seed 001's outdoor loop: a ground plane, a block of buildings in the middle (the street runs around
    it at about 40 m x 30 m), buildings across the street, and poles and parked cars as small boxes."""
    rng = np.random.default_rng(rng_seed)
    b = WorldBuilder("urban_block")
    b.rect([0, 0, 0], [1, 0, 0], [0, 1, 0], 90, 80, 0.2)
    # the inner block
    for x0 in (-32, -12, 8):
        b.box([x0, -20, 0], [x0 + 18, -2, 8 + rng.uniform(0, 10)], 0.6)
        b.box([x0, 2, 0], [x0 + 18, 20, 8 + rng.uniform(0, 10)], 0.6)
    # buildings across the street
    for x0 in range(-60, 60, 20):
        b.box([x0, 42, 0], [x0 + 16, 55, 10 + rng.uniform(0, 15)], 0.6)
        b.box([x0, -55, 0], [x0 + 16, -42, 10 + rng.uniform(0, 15)], 0.6)
    for y0 in range(-40, 40, 20):
        b.box([-75, y0, 0], [-60, y0 + 16, 12 + rng.uniform(0, 10)], 0.6)
        b.box([60, y0, 0], [75, y0 + 16, 12 + rng.uniform(0, 10)], 0.6)
    # poles and parked cars along the outer sidewalk
    for x in range(-50, 55, 12):
        b.box([x, 39, 0], [x + 0.3, 39.3, 4], 0.9)
        b.box([x, -39.3, 0], [x + 0.3, -39, 4], 0.9)
    for x in range(-45, 50, 25):
        b.box([x, 34, 0], [x + 4.2, 35.8, 1.5], 0.8)
    return b.build()


def sample_surface_points(
    world: World, n: int, rng: np.random.Generator
) -> tuple[FloatArray, NDArray[np.int64]]:
    """``n`` points (n, 3) uniformly over the surfaces (area-weighted), and their surface ids."""
    p = world.area / world.area.sum()
    q = rng.choice(len(world), size=n, p=p)
    a = rng.uniform(-1, 1, size=(n, 2)) * world.half[q]
    pts = world.centre[q] + a[:, :1] * world.u[q] + a[:, 1:] * world.v[q]
    return pts, world.surface_id[q]


def distance_to_surfaces(world: World, points: FloatArray, chunk: int = 20000) -> FloatArray:
    """Distance (N,) of each point to the nearest rectangle, m."""
    pts = np.asarray(points, dtype=float)
    out = np.empty(len(pts))
    for s in range(0, len(pts), chunk):
        d = pts[s : s + chunk, None, :] - world.centre[None]  # (n, Q, 3)
        a = np.clip(np.einsum("nqk,qk->nq", d, world.u), -world.half[:, 0], world.half[:, 0])
        b = np.clip(np.einsum("nqk,qk->nq", d, world.v), -world.half[:, 1], world.half[:, 1])
        closest = world.centre[None] + a[..., None] * world.u[None] + b[..., None] * world.v[None]
        out[s : s + chunk] = np.min(
            np.linalg.norm(pts[s : s + chunk, None, :] - closest, axis=2), axis=1
        )
    return out


def calibration_room(height: float = 2.6) -> World:
    """A 7 m x 6 m room with a ceiling, furniture and two slanted panels: every direction of a LiDAR
    waved in its middle sees planes close by (the site of a LiDAR-IMU calibration)."""
    b = WorldBuilder("calibration_room")
    b.rect([0, 0, 0], [1, 0, 0], [0, 1, 0], 4.0, 3.5, 0.3)  # floor, normal +z
    b.rect([0, 0, height], [0, 1, 0], [1, 0, 0], 3.5, 4.0, 0.4)  # ceiling, normal -z
    for lo, hi in (
        ([-3.7, -3.2, 0], [3.7, -3.0, height]), ([-3.7, 3.0, 0], [3.7, 3.2, height]),
        ([-3.7, -3.0, 0], [-3.5, 3.0, height]), ([3.5, -3.0, 0], [3.7, 3.0, height]),
    ):  # fmt: skip
        b.box(lo, hi, 0.7)
    for lo, hi in (
        ([-3.4, -2.9, 0], [-2.4, -2.1, 0.8]), ([2.3, 2.2, 0], [3.4, 2.9, 1.9]), ([2.6, -2.9, 0], [3.4, -2.3, 0.5]),
        ([-3.4, 1.8, 0], [-2.9, 2.9, 1.1]), ([-0.6, 2.6, 0], [0.4, 2.9, 2.1]),
    ):  # fmt: skip
        b.box(lo, hi, 0.5)
    b.rect(
        [-1.5, -2.5, 1.4], [1, 0, 0], [0, 0.6, 0.8], 0.8, 0.6, 0.6
    )  # panels leaning on the walls
    b.rect([3.0, 0.5, 1.6], [0, 1, 0], [-0.7, 0, 0.7], 0.7, 0.5, 0.6)
    return b.build()
