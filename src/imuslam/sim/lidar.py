"""Simulated spinning 3D LiDAR and 2D laser scanner, ray-cast against a :class:`World` (numba).

Each column (3D) or beam (2D) fires at its own time with the sensor pose at that time, so points carry
the motion distortion of a moving sensor; points are reported in the sensor frame at their firing time,
as a real LiDAR reports them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces.lidar import Scan2d, Scan3d
from imuslam.sim.world import World

FloatArray = NDArray[np.float64]
PoseFn = Callable[
    [FloatArray], tuple[FloatArray, FloatArray]
]  # t_s (M,) -> R_w_l (M,3,3), p_w (M,3)

VLP16_ELEVATIONS_DEG = tuple(float(e) for e in np.arange(-15.0, 15.1, 2.0))
OS1_32_ELEVATIONS_DEG = tuple(float(e) for e in np.linspace(-16.6, 16.6, 32))


@numba.njit(cache=True, parallel=True)
def cast_rays(
    origins: FloatArray,
    dirs: FloatArray,
    centre: FloatArray,
    u: FloatArray,
    v: FloatArray,
    half: FloatArray,
    max_range: float,
) -> tuple[FloatArray, NDArray[np.int64]]:  # pragma: no cover - compiled
    """First hit distance (R,) along unit rays (inf for none) and the rectangle hit (-1 for none)."""
    R = dirs.shape[0]
    Q = centre.shape[0]
    dist = np.full(R, np.inf)
    hit = np.full(R, -1, dtype=np.int64)
    for r in numba.prange(R):
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        best = max_range
        bq = -1
        for q in range(Q):
            nx = u[q, 1] * v[q, 2] - u[q, 2] * v[q, 1]
            ny = u[q, 2] * v[q, 0] - u[q, 0] * v[q, 2]
            nz = u[q, 0] * v[q, 1] - u[q, 1] * v[q, 0]
            den = dx * nx + dy * ny + dz * nz
            if abs(den) < 1e-12:
                continue
            cx, cy, cz = centre[q, 0] - ox, centre[q, 1] - oy, centre[q, 2] - oz
            t = (cx * nx + cy * ny + cz * nz) / den
            if t <= 1e-9 or t >= best:
                continue
            px, py, pz = dx * t - cx, dy * t - cy, dz * t - cz  # hit point relative to the centre
            if abs(px * u[q, 0] + py * u[q, 1] + pz * u[q, 2]) > half[q, 0]:
                continue
            if abs(px * v[q, 0] + py * v[q, 1] + pz * v[q, 2]) > half[q, 1]:
                continue
            best = t
            bq = q
        if bq >= 0:
            dist[r] = best
            hit[r] = bq
    return dist, hit


def cast_rays_reference(
    origins: FloatArray, dirs: FloatArray, world: World, max_range: float
) -> tuple[FloatArray, NDArray[np.int64]]:
    """Slow numpy version of :func:`cast_rays` (all rays against all rectangles), for tests."""
    n = world.normal
    den = dirs @ n.T  # (R, Q)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("rqk,qk->rq", world.centre[None] - origins[:, None], n) / den
    p = origins[:, None] + t[..., None] * dirs[:, None] - world.centre[None]
    inside = (np.abs(np.einsum("rqk,qk->rq", p, world.u)) <= world.half[:, 0]) & (
        np.abs(np.einsum("rqk,qk->rq", p, world.v)) <= world.half[:, 1]
    )
    ok = inside & (t > 1e-9) & (t < max_range) & (np.abs(den) >= 1e-12)
    t = np.where(ok, t, np.inf)
    q = np.argmin(t, axis=1)
    d = t[np.arange(len(t)), q]
    return d, np.where(np.isfinite(d), q, -1)


@dataclass
class Lidar3dConfig:
    """Spinning LiDAR: beam elevations (deg), columns per turn, turn rate, range limits and noise."""

    elevations_deg: tuple[float, ...] = VLP16_ELEVATIONS_DEG
    columns: int = 1800  # 0.2 deg at 10 Hz
    rate_hz: float = 10.0
    min_range: float = 0.5
    max_range: float = 100.0
    range_noise_std: float = 0.02


MoversFn = Callable[[float], World]  # t_s -> the moving objects' rectangles at that time


def _movers_hit(
    movers: MoversFn, t_col: FloatArray, o_w: FloatArray, d_w: FloatArray, B: int,
    dist: FloatArray, hit: NDArray[np.int64], max_range: float, chunks: int = 10,
) -> tuple[FloatArray, NDArray[np.int64], FloatArray]:  # fmt: skip
    """The rays (C * B) cast again against the moving objects, placed where they are at each of
    ``chunks`` slices of the turn (a car at 11 m/s moves 11 cm in a slice at 10 Hz: the points on it
    are outliers to the matcher, whose shape within a slice does not matter): the nearer hit
    wins. Returns the distances, the hit ids (moving objects' ids after the world's: Q + j) and the
    hit intensities (NaN where the static world was hit)."""
    C = len(t_col)
    inten = np.full(len(dist), np.nan)
    for cols in np.array_split(np.arange(C), min(chunks, C)):
        if not len(cols):
            continue
        m = movers(float(t_col[cols[len(cols) // 2]]))
        if not len(m):
            continue
        sl = slice(int(cols[0]) * B, (int(cols[-1]) + 1) * B)
        dm, hm = cast_rays(np.ascontiguousarray(o_w[sl]), np.ascontiguousarray(d_w[sl]),
                           m.centre, m.u, m.v, m.half, max_range)  # fmt: skip
        nearer = dm < dist[sl]
        idx = np.flatnonzero(nearer) + sl.start
        dist[idx] = dm[nearer]
        hit[idx] = 1_000_000 + hm[nearer]
        inten[idx] = m.intensity[hm[nearer]]
    return dist, hit, inten


def simulate_lidar3d_scan(
    world: World,
    pose_w_l: PoseFn,
    t0_s: float,
    config: Lidar3dConfig,
    rng: np.random.Generator,
    movers: MoversFn | None = None,
) -> Scan3d:
    """One turn of the spinning LiDAR starting at ``t0_s``; ``movers``: objects moving through the
    scene (cars, pedestrians; ``sim.faults``), their surface ids 1000000 and up."""
    C = config.columns
    el = np.deg2rad(np.asarray(config.elevations_deg))
    B = el.size
    scan_time = 1.0 / config.rate_hz
    t_col = t0_s + np.arange(C) * scan_time / C
    az = 2.0 * np.pi * np.arange(C) / C
    d_l = np.stack(
        [np.cos(el)[None, :] * np.cos(az)[:, None], np.cos(el)[None, :] * np.sin(az)[:, None],
         np.broadcast_to(np.sin(el)[None, :], (C, B))], axis=-1,
    )  # (C, B, 3)  # fmt: skip
    R, p = pose_w_l(t_col)
    d_w = np.einsum("cij,cbj->cbi", R, d_l).reshape(-1, 3)
    o_w = np.repeat(p, B, axis=0)
    dist, hit = cast_rays(
        o_w, np.ascontiguousarray(d_w), world.centre, world.u, world.v, world.half, config.max_range
    )
    inten = world.intensity[np.maximum(hit, 0)]
    if movers is not None:
        dist, hit, im = _movers_hit(movers, t_col, o_w, d_w, B, dist, hit, config.max_range)
        inten = np.where(np.isnan(im), inten, im)
    r = (
        dist + rng.normal(size=dist.shape) * config.range_noise_std
        if config.range_noise_std > 0
        else dist
    )
    ok = np.isfinite(dist) & (r >= config.min_range) & (r <= config.max_range)
    pts = d_l.reshape(-1, 3)[ok] * r[ok, None]
    ring = np.tile(np.arange(B, dtype=np.uint16), C)[ok]
    toff = np.repeat(t_col - t0_s, B)[ok]
    return Scan3d(
        int(round(t0_s * 1e9)), pts.astype(np.float32), toff.astype(np.float32), ring,
        inten[ok].astype(np.float32), hit[ok],
    )  # fmt: skip


def simulate_lidar3d(
    world: World,
    pose_w_l: PoseFn,
    t_start_s: float,
    n_scans: int,
    config: Lidar3dConfig,
    rng: np.random.Generator,
) -> list[Scan3d]:
    """``n_scans`` consecutive turns from ``t_start_s``."""
    return [
        simulate_lidar3d_scan(world, pose_w_l, t_start_s + k / config.rate_hz, config, rng)
        for k in range(n_scans)
    ]


@dataclass
class Lidar2dConfig:
    """A 2D laser scanner; defaults are an RPLIDAR A2 (0.45 deg, 10 Hz, 0.2-12 m)."""

    angle_increment_deg: float = 0.45
    rate_hz: float = 10.0
    min_range: float = 0.2
    max_range: float = 12.0
    range_noise_std: float = 0.01


def simulate_lidar2d_scan(
    world: World, pose_w_l: PoseFn, t0_s: float, config: Lidar2dConfig, rng: np.random.Generator
) -> Scan2d:
    """One revolution of a 2D scanner (beams in the sensor's x-y plane, counter-clockwise from -pi)."""
    inc = np.deg2rad(config.angle_increment_deg)
    nb = int(round(2 * np.pi / inc))
    scan_time = 1.0 / config.rate_hz
    ang = -np.pi + np.arange(nb) * inc
    t_b = t0_s + np.arange(nb) * scan_time / nb
    d_l = np.stack([np.cos(ang), np.sin(ang), np.zeros(nb)], axis=1)
    R, p = pose_w_l(t_b)
    d_w = np.einsum("bij,bj->bi", R, d_l)
    dist, hit = cast_rays(
        p, np.ascontiguousarray(d_w), world.centre, world.u, world.v, world.half, config.max_range
    )
    r = (
        dist + rng.normal(size=nb) * config.range_noise_std
        if config.range_noise_std > 0
        else dist.copy()
    )
    ok = np.isfinite(dist) & (r >= config.min_range) & (r <= config.max_range)
    ranges = np.where(ok, r, np.inf).astype(np.float32)
    inten = np.where(ok, world.intensity[np.maximum(hit, 0)], 0.0).astype(np.float32)
    return Scan2d(
        int(round(t0_s * 1e9)), float(ang[0]), float(inc), scan_time / nb, scan_time,
        config.min_range, config.max_range, ranges, inten,
    )  # fmt: skip
