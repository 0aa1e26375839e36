"""Quality of a 2D map and trajectory against a simulated truth: SE(2) alignment (Umeyama without scale),
ATE, loop error, and map sharpness against the true walls (the fraction of occupied cells farther than
a distance from any surface, and the thickness of the walls)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.sim.world import World, distance_to_surfaces

FloatArray = NDArray[np.float64]


def align_se2(est_xy: FloatArray, ref_xy: FloatArray) -> FloatArray:
    """[x, y, theta] that maps ``est_xy`` (N, 2) onto ``ref_xy`` best in least squares (Umeyama 1991,
    no scale)."""
    me, mr = est_xy.mean(axis=0), ref_xy.mean(axis=0)
    H = (est_xy - me).T @ (ref_xy - mr)
    th = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    c, s = np.cos(th), np.sin(th)
    t = mr - np.array([[c, -s], [s, c]]) @ me
    return np.array([t[0], t[1], th])


def transform(T: FloatArray, xy_yaw: FloatArray) -> FloatArray:
    c, s = np.cos(T[2]), np.sin(T[2])
    xy = xy_yaw[:, :2] @ np.array([[c, s], [-s, c]]) + T[:2]
    return np.column_stack([xy, xy_yaw[:, 2] + T[2]])


@dataclass
class MapQuality:
    ate_rmse_m: float
    ate_max_m: float
    loop_error_m: float
    loop_error_deg: float
    occupied_cells: int
    frac_far: float  # occupied cells farther than ``far_m`` from any true surface
    wall_thickness_m: (
        float  # mean over the room's four walls of the 5-95 % spread of occupied cells
    )


@dataclass
class HitSharpness:
    """The scans' hits placed with the aligned poses, against the true walls: no grid, so the score moves
    with the poses and the range noise only, not with which side of a cell border a wall falls.

    rms_m: RMS distance of the hits from the nearest true surface (the seed's "walls sharp").
    wall_width_m: mean over the room's four walls of the 5-95 % spread of the hits across the wall."""

    rms_m: float
    wall_width_m: float
    hits: int


def hit_sharpness(hits_w: FloatArray, world: World, height: float) -> HitSharpness:
    """Score ``hits_w`` (N, 2), the scan endpoints in the world frame, against ``world``'s surfaces at
    the scanner's ``height``."""
    if not len(hits_w):
        return HitSharpness(float("nan"), float("nan"), 0)
    d = distance_to_surfaces(world, np.column_stack([hits_w, np.full(len(hits_w), height)]))
    return HitSharpness(float(np.sqrt(np.mean(d**2))), wall_thickness(hits_w), len(hits_w))


def occupied_centres(prob: FloatArray, known: NDArray[np.bool_], x0: float, y0: float, res: float,
                     thresh: float = 0.65) -> FloatArray:  # fmt: skip
    iy, ix = np.nonzero(known & (prob >= thresh))
    return np.column_stack([x0 + (ix + 0.5) * res, y0 + (iy + 0.5) * res])


def wall_thickness(xy: FloatArray, half: float = 4.0, band: float = 0.3) -> float:
    """Mean over the four walls at |x| = half, |y| = half of the 5-95 % width of the occupied cells
    within ``band`` of the wall's inner face (corners excluded)."""
    widths = []
    for axis in (0, 1):
        other = 1 - axis
        for sign in (-1.0, 1.0):
            d = sign * xy[:, axis] - half
            m = (np.abs(d) < band) & (np.abs(xy[:, other]) < half - band)
            if m.sum() >= 10:
                lo, hi = np.percentile(d[m], [5, 95])
                widths.append(hi - lo)
    return float(np.mean(widths)) if widths else float("nan")


def map_quality(
    est_xy_yaw: FloatArray, truth_xy_yaw: FloatArray, occupied_w: Callable[[FloatArray], FloatArray],
    world: World, height: float, far_m: float = 0.05,
) -> MapQuality:  # fmt: skip
    """Align the estimate to the truth (SE(2), positions), then score the trajectory, and the map that
    ``occupied_w(aligned poses)`` renders (occupied cell centres (M, 2) in the world frame, so that its
    raster is the world's), against the world's surfaces at the scanner's height."""
    T = align_se2(est_xy_yaw[:, :2], truth_xy_yaw[:, :2])
    al = transform(T, est_xy_yaw)
    e = np.hypot(*(al[:, :2] - truth_xy_yaw[:, :2]).T)
    d_true = truth_xy_yaw[-1] - truth_xy_yaw[0]
    d_est = est_xy_yaw[-1] - est_xy_yaw[0]
    loop_m = float(np.hypot(*(d_est[:2] - d_true[:2])))
    loop_deg = float(np.rad2deg(abs(np.angle(np.exp(1j * (d_est[2] - d_true[2]))))))
    occ = occupied_w(al)
    if len(occ):
        dist = distance_to_surfaces(world, np.column_stack([occ, np.full(len(occ), height)]))
        far = float(np.mean(dist > far_m))
    else:
        far = float("nan")
    return MapQuality(float(np.sqrt(np.mean(e**2))), float(e.max()), loop_m, loop_deg, len(occ), far,
                      wall_thickness(occ))  # fmt: skip


# ---------------------------------------------------------------------------------------------
# without ground truth: how crisp the map of a recorded log is


@dataclass
class PointMapQuality:
    """Sharpness of a point map (2D or 3D) without ground truth (Razlaw et al., "Evaluation of
    registration methods for sparse 3D laser scans", ECMR 2015): around each query point, the covariance
    S of the map's points within ``radius_m``.

    map_entropy: mean map entropy, the mean over the queries of ``0.5 ln det(2 pi e S)`` (nats; lower is
        crisper; comparable only between maps of the same log, radius and dimension).
    plane_variance_m2: mean plane variance, the mean of the smallest eigenvalue of S (m^2): in 3D the
        spread of the points about their local plane, in 2D about their local line (a wall's cut).
    wall_spread_cm: its square root in cm, the RMS distance of the points from their local wall.
    queries: neighbourhoods used (those with at least ``min_points`` points).
    """

    map_entropy: float
    plane_variance_m2: float
    wall_spread_cm: float
    queries: int
    points: int


def point_map_quality(
    points: FloatArray, radius_m: float = 0.2, min_points: int = 10, max_queries: int = 5000,
    seed: int = 0, queries: FloatArray | None = None,
) -> PointMapQuality:  # fmt: skip
    """:class:`PointMapQuality` of ``points`` (N, 2) or (N, 3), world frame, m. The queries are
    ``max_queries`` of the points drawn with ``seed`` (all of them when there are fewer), so two maps of
    the same log are scored on the same number of neighbourhoods; or the given ``queries`` (Q, dim)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    dim = p.shape[1]
    if len(p) < min_points:
        return PointMapQuality(float("nan"), float("nan"), float("nan"), 0, len(p))
    rng = np.random.default_rng(seed)
    if queries is not None:
        q = np.asarray(queries, dtype=float)
    else:
        q = p if len(p) <= max_queries else p[rng.choice(len(p), max_queries, replace=False)]
    tree = cKDTree(p)
    ent, lam = [], []
    for nb in tree.query_ball_point(q, radius_m, workers=1):
        if len(nb) < min_points:
            continue
        x = p[nb]
        S = np.cov(x, rowvar=False)
        ev = np.linalg.eigvalsh(S)
        if ev[0] <= 0:
            continue
        ent.append(0.5 * (dim * np.log(2 * np.pi * np.e) + np.sum(np.log(ev))))
        lam.append(ev[0])
    if not lam:
        return PointMapQuality(float("nan"), float("nan"), float("nan"), 0, len(p))
    mpv = float(np.mean(lam))
    return PointMapQuality(float(np.mean(ent)), mpv, 100 * float(np.sqrt(mpv)), len(lam), len(p))
