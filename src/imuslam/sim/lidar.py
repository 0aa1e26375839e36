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


RAY_CHUNK = 64  # rays sharing one candidate list in :func:`cast_rays`
RAY_SUBCHUNK = 8  # rays of a chunk sharing a list drawn from the chunk's


@numba.njit(cache=True)
def _rect_radius(u: FloatArray, v: FloatArray, half: FloatArray) -> FloatArray:  # pragma: no cover
    """Bounding radius (Q,) of each rectangle about its centre: the largest |p| over the corners of
    {p in span(u, v): |p.u| <= hu, |p.v| <= hv} (u, v need not be unit nor orthogonal); inf for a
    degenerate (u nearly parallel to v) or non-finite one."""
    Q = u.shape[0]
    rad = np.full(Q, np.inf)
    for q in range(Q):
        guu = u[q, 0] * u[q, 0] + u[q, 1] * u[q, 1] + u[q, 2] * u[q, 2]
        gvv = v[q, 0] * v[q, 0] + v[q, 1] * v[q, 1] + v[q, 2] * v[q, 2]
        guv = u[q, 0] * v[q, 0] + u[q, 1] * v[q, 1] + u[q, 2] * v[q, 2]
        det = guu * gvv - guv * guv
        if not det > 1e-6 * guu * gvv:
            continue
        a = abs(half[q, 0])
        r2 = 0.0
        for b in (abs(half[q, 1]), -abs(half[q, 1])):
            # p = al u + be v with p.u = a, p.v = b; |p|^2 = al (p.u) + be (p.v)
            al = (a * gvv - b * guv) / det
            be = (b * guu - a * guv) / det
            r2 = max(r2, al * a + be * b)
        if np.isfinite(r2):
            rad[q] = np.sqrt(r2)
    return rad


@numba.njit(cache=True)
def _chunk_candidates(
    origins: FloatArray,
    dirs: FloatArray,
    r0: int,
    r1: int,
    centre: FloatArray,
    rad: FloatArray,
    max_range: float,
    src: NDArray[np.int64],
    n_src: int,
    cand: NDArray[np.int64],
) -> int:  # pragma: no cover - compiled
    """Writes into ``cand`` (in their order) the rectangles of ``src[:n_src]`` that rays ``r0:r1`` may
    hit and returns their count: all of them unless the rays' origins fit in a ball (centre ``oc``, radius ``ro``) and their
    directions in a cone (axis ``ax``, half-angle ``th`` <= 1 rad). A ray from an origin within ``ro``
    of ``oc`` that meets a rectangle's bounding sphere (radius ``rad``) before ``max_range`` |d| is a
    ray from ``oc`` that meets the sphere grown by ``ro``, at distance ``L`` along the direction to it
    at an angle of at most asin(grown radius / L), so within that angle plus ``th`` of ``ax``. The
    radius, range and angle are widened by far more than their rounding (1e-6 relative, 1e-5 rad)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    ax = np.zeros(3)
    dmax = 0.0
    full = not (abs(max_range) < np.inf)
    for r in range(r0, r1):
        nd = np.sqrt(dirs[r, 0] * dirs[r, 0] + dirs[r, 1] * dirs[r, 1] + dirs[r, 2] * dirs[r, 2])
        if not (0.0 < nd < np.inf):
            full = True
        dmax = max(dmax, nd)
        for k in range(3):
            if not abs(origins[r, k]) < np.inf:
                full = True
            lo[k] = min(lo[k], origins[r, k])
            hi[k] = max(hi[k], origins[r, k])
            ax[k] += dirs[r, k] / nd
    na = np.sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2])
    if not full and na > 0.5 * (r1 - r0):
        ax /= na
        cmin = 1.0
        for r in range(r0, r1):
            nd = np.sqrt(
                dirs[r, 0] * dirs[r, 0] + dirs[r, 1] * dirs[r, 1] + dirs[r, 2] * dirs[r, 2]
            )
            cmin = min(cmin, (dirs[r, 0] * ax[0] + dirs[r, 1] * ax[1] + dirs[r, 2] * ax[2]) / nd)
        th = np.arccos(max(-1.0, cmin)) + 1e-5
        full = not th < 1.0
    else:
        full = True
    if full:
        cand[:n_src] = src[:n_src]
        return n_src
    oc = 0.5 * (lo + hi)
    ro = 0.5 * np.sqrt((hi[0] - lo[0]) ** 2 + (hi[1] - lo[1]) ** 2 + (hi[2] - lo[2]) ** 2)
    reach = max_range * dmax
    cth, sth = np.cos(th), np.sin(th)
    n = 0
    for j in range(n_src):
        q = src[j]
        wx, wy, wz = centre[q, 0] - oc[0], centre[q, 1] - oc[1], centre[q, 2] - oc[2]
        L = np.sqrt(wx * wx + wy * wy + wz * wz)
        rr = rad[q] + ro
        rr += 1e-6 * (L + rr + abs(reach)) + 1e-6
        if L > rr:  # oc outside the grown sphere (NaN or inf anywhere keeps the rectangle)
            if L - rr >= reach:
                continue
            sb = rr / L  # sin of the sphere's angular radius
            cb = np.sqrt(1.0 - sb * sb)
            if (wx * ax[0] + wy * ax[1] + wz * ax[2]) / L < cth * cb - sth * sb:
                continue  # angle to the sphere's centre > th + its angular radius (th + it < pi)
        cand[n] = q
        n += 1
    return n


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
    """First hit distance (R,) along unit rays (inf for none) and the rectangle hit (-1 for none).

    Each ``RAY_CHUNK`` rays keep the rectangles :func:`_chunk_candidates` finds within their reach,
    each ``RAY_SUBCHUNK`` of them those of these within theirs, and every ray tests its list in index
    order with the arithmetic of a test against all rectangles: the ones left out are never hit
    within the range, so the distances and the rectangles hit (the first of equal distances) are
    those of testing every rectangle."""
    R = dirs.shape[0]
    Q = centre.shape[0]
    dist = np.full(R, np.inf)
    hit = np.full(R, -1, dtype=np.int64)
    every = np.arange(Q)
    normal = np.empty((Q, 3))
    for q in range(Q):
        normal[q, 0] = u[q, 1] * v[q, 2] - u[q, 2] * v[q, 1]
        normal[q, 1] = u[q, 2] * v[q, 0] - u[q, 0] * v[q, 2]
        normal[q, 2] = u[q, 0] * v[q, 1] - u[q, 1] * v[q, 0]
    rad = _rect_radius(u, v, half)
    n_chunks = (R + RAY_CHUNK - 1) // RAY_CHUNK
    for c in numba.prange(n_chunks):
        r0 = c * RAY_CHUNK
        r1 = min(R, r0 + RAY_CHUNK)
        near = np.empty(Q, dtype=np.int64)
        n_near = _chunk_candidates(origins, dirs, r0, r1, centre, rad, max_range, every, Q, near)
        cand = np.empty(Q, dtype=np.int64)
        for s0 in range(r0, r1, RAY_SUBCHUNK):
            s1 = min(r1, s0 + RAY_SUBCHUNK)
            nc = _chunk_candidates(
                origins, dirs, s0, s1, centre, rad, max_range, near, n_near, cand
            )
            for r in range(s0, s1):
                ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
                dx, dy, dz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
                best = max_range
                bq = -1
                for k in range(nc):
                    q = cand[k]
                    nx, ny, nz = normal[q, 0], normal[q, 1], normal[q, 2]
                    den = dx * nx + dy * ny + dz * nz
                    if abs(den) < 1e-12:
                        continue
                    cx, cy, cz = centre[q, 0] - ox, centre[q, 1] - oy, centre[q, 2] - oz
                    t = (cx * nx + cy * ny + cz * nz) / den
                    if t <= 1e-9 or t >= best:
                        continue
                    # the hit point relative to the centre
                    px, py, pz = dx * t - cx, dy * t - cy, dz * t - cz
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
    """A 3D LiDAR: range limits and noise, the scan rate, and its pattern. ``spinning``: beams at
    ``elevations_deg`` fired together at each of ``columns`` azimuths per turn (a VLP-16 by default;
    ``os1(128)`` / ``os1(64)``: an Ouster OS1's uniform beams over 45 deg, 1024 columns). ``rosette``:
    a solid-state LiDAR looking along +x whose two counter-rotating prisms (Risley) draw a
    non-repetitive rosette over a ``fov_deg`` cone, ``points_per_s`` points each with its own time
    (``livox()``: a Livox Avia-like 70 deg cone at 240k points/s)."""

    elevations_deg: tuple[float, ...] = VLP16_ELEVATIONS_DEG
    columns: int = 1800  # 0.2 deg at 10 Hz
    rate_hz: float = 10.0
    min_range: float = 0.5
    max_range: float = 100.0
    range_noise_std: float = 0.02
    pattern: str = "spinning"
    fov_deg: float = 70.0
    points_per_s: float = 240_000.0
    prism_hz: tuple[float, float] = (121.37, 87.19)  # incommensurate: the rosette never repeats

    @classmethod
    def os1(cls, beams: int = 128, columns: int = 1024) -> Lidar3dConfig:
        """An Ouster OS1 (``beams`` uniform over -22.5..22.5 deg, ``columns`` per turn, 10 Hz, 0.3-100 m,
        3 cm range noise): 128 x 1024 = 131k rays a scan."""
        el = tuple(float(e) for e in np.linspace(-22.5, 22.5, beams))
        return cls(el, columns, 10.0, 0.3, 100.0, 0.03)

    @classmethod
    def livox(cls) -> Lidar3dConfig:
        """A Livox Avia-like solid-state LiDAR: a 70 deg rosette, 240k points/s at 10 Hz, 1-100 m, 2 cm."""
        return cls(min_range=1.0, pattern="rosette", fov_deg=70.0, points_per_s=240_000.0)


def scan_rays(
    config: Lidar3dConfig,
) -> tuple[FloatArray, NDArray[np.int64], FloatArray, NDArray[np.uint16]]:
    """The rays of one scan: firing times (U,) s from the scan start, each ray's index into them (R,),
    unit directions (R, 3) in the sensor frame, and beam indices (R,) (0 for the rosette)."""
    scan_time = 1.0 / config.rate_hz
    if config.pattern == "spinning":
        C = config.columns
        el = np.deg2rad(np.asarray(config.elevations_deg))
        B = el.size
        az = 2.0 * np.pi * np.arange(C) / C
        d_l = np.stack(
            [np.cos(el)[None, :] * np.cos(az)[:, None], np.cos(el)[None, :] * np.sin(az)[:, None],
             np.broadcast_to(np.sin(el)[None, :], (C, B))], axis=-1,
        ).reshape(-1, 3)  # fmt: skip
        ring = np.tile(np.arange(B, dtype=np.uint16), C)
        return np.arange(C) * scan_time / C, np.repeat(np.arange(C), B), d_l, ring
    if config.pattern == "rosette":
        n = int(round(config.points_per_s * scan_time))
        t = np.arange(n) * scan_time / n
        return (
            t,
            np.arange(n),
            rosette_directions(t, config.fov_deg, config.prism_hz),
            np.zeros(n, np.uint16),
        )
    raise ValueError(f"unknown LiDAR pattern {config.pattern!r}; expected spinning or rosette")


def rosette_directions(
    t_s: FloatArray, fov_deg: float, prism_hz: tuple[float, float]
) -> FloatArray:
    """Unit directions (N, 3) of a Risley-prism rosette at times ``t_s`` (absolute, so consecutive scans
    continue the pattern): the beam's offset from +x is the sum of two equal vectors turning in opposite
    directions at ``prism_hz``, |offset| <= half the field of view."""
    half = np.deg2rad(fov_deg) / 2.0
    a1, a2 = 2 * np.pi * prism_hz[0] * t_s, -2 * np.pi * prism_hz[1] * t_s
    oy = 0.5 * half * (np.cos(a1) + np.cos(a2))
    oz = 0.5 * half * (np.sin(a1) + np.sin(a2))
    rho, psi = np.hypot(oy, oz), np.arctan2(oz, oy)
    return np.stack([np.cos(rho), np.sin(rho) * np.cos(psi), np.sin(rho) * np.sin(psi)], axis=1)


MoversFn = Callable[[float], World]  # t_s -> the moving objects' rectangles at that time


def _movers_hit(
    movers: MoversFn, t_ray: FloatArray, o_w: FloatArray, d_w: FloatArray,
    dist: FloatArray, hit: NDArray[np.int64], max_range: float, chunks: int = 10,
) -> tuple[FloatArray, NDArray[np.int64], FloatArray]:  # fmt: skip
    """The rays (R,) fired at ``t_ray`` (in time order) cast again against the moving objects, placed
    where they are at each of
    ``chunks`` slices of the turn (a car at 11 m/s moves 11 cm in a slice at 10 Hz: the points on it
    are outliers to the matcher, whose shape within a slice does not matter): the nearer hit
    wins. Returns the distances, the hit ids (moving objects' ids after the world's: Q + j) and the
    hit intensities (NaN where the static world was hit)."""
    R = len(t_ray)
    inten = np.full(len(dist), np.nan)
    for rays in np.array_split(np.arange(R), min(chunks, R)):
        if not len(rays):
            continue
        m = movers(float(t_ray[rays[len(rays) // 2]]))
        if not len(m):
            continue
        sl = slice(int(rays[0]), int(rays[-1]) + 1)
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
    """One scan starting at ``t0_s`` (a turn of a spinning LiDAR, a tenth of a second of a rosette);
    ``movers``: objects moving through the scene (cars, pedestrians; ``sim.faults``), their surface
    ids 1000000 and up."""
    t_u, idx, d_l, ring_all = scan_rays(config)
    if config.pattern == "rosette":  # the prisms turn on: the pattern continues from scan to scan
        d_l = rosette_directions(t0_s + t_u, config.fov_deg, config.prism_hz)
    R, p = pose_w_l(t0_s + t_u)
    d_w = np.einsum("rij,rj->ri", R[idx], d_l)
    o_w = p[idx]
    dist, hit = cast_rays(
        o_w, np.ascontiguousarray(d_w), world.centre, world.u, world.v, world.half, config.max_range
    )
    inten = world.intensity[np.maximum(hit, 0)]
    if movers is not None:
        dist, hit, im = _movers_hit(movers, t0_s + t_u[idx], o_w, d_w, dist, hit, config.max_range)
        inten = np.where(np.isnan(im), inten, im)
    r = (
        dist + rng.normal(size=dist.shape) * config.range_noise_std
        if config.range_noise_std > 0
        else dist
    )
    ok = np.isfinite(dist) & (r >= config.min_range) & (r <= config.max_range)
    pts = d_l[ok] * r[ok, None]
    ring = ring_all[ok] if config.pattern == "spinning" else np.zeros(0, np.uint16)
    toff = t_u[idx][ok]
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
