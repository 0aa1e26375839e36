"""Is the loop closed? Scans that come back to the start, matched against the map of the start.

A map is built from the first scans of the log at their estimated poses; every scan that comes back
within ``radius`` of the start after ``min_gap_fraction`` of the log is matched against it by an
exhaustive search (every pose of a +-``window`` m, +-``angular_window_deg`` deg lattice, no prior), then
refined. The match gives the scan's pose in the start map's frame independently of the trajectory; the
trajectory's own pose of that scan, before loop closure (local SLAM) and after (optimised), disagrees
with it by the loop's remaining error. The score means something when it is (1) near the run's usual
local match score (the scan fits the start map as well as consecutive scans fit each other) and (2)
above every pose of the window farther than ``peak_radius`` / ``peak_angle_deg`` from the match (the
peak is unique, not one of a corridor's many equally good places).

With ``context_scans`` > 1 each returning scan is matched with the ``context_scans`` - 1 scans before it,
rendered at their local-SLAM poses relative to it (a short stretch of local SLAM drifts little), as
Cartographer matches a node against a submap: more of the place than one scan's 240 deg / 4 m sees. The
share of its points that land in cells the start map observed says whether the two overlap at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.io.laserlog import LaserLog
from imuslam.slam2d import pose2
from imuslam.slam2d.config import Slam2dConfig
from imuslam.slam2d.matching import angular_step, refine_pose, score_volume
from imuslam.slam2d.pipeline import render_map, scan_points
from imuslam.slam2d.records import Slam2dResult

FloatArray = NDArray[np.float64]


@dataclass
class RevisitCheck:
    """One returning scan matched against the start map. Poses [x, y, theta] in the map frame."""

    scan: int
    distance_to_start_m: float  # its optimised position to the nearest start scan's
    matched_xy_yaw: FloatArray
    score: float  # mean probability at its points in the start map, refined
    second_peak: float  # the best lattice score farther than the peak radius / angle from the match
    before_m: float  # local-SLAM pose against the match
    before_deg: float
    after_m: float  # optimised pose against the match
    after_deg: float
    points: int = 0  # points matched (one scan's, or the context's, thinned)
    observed_share: float = 0.0  # of them at the match, in cells the start map observed


@dataclass
class RevisitReport:
    start_scans: int
    median_local_score: float  # the run's median local match score
    checks: list[RevisitCheck]


def check_revisits(
    log_: LaserLog,
    res: Slam2dResult,
    cfg: Slam2dConfig,
    start_fraction: float = 0.1,
    min_gap_fraction: float = 0.25,
    radius: float = 1.5,
    window: float = 2.0,
    angular_window_deg: float = 30.0,
    peak_radius: float = 0.5,
    peak_angle_deg: float = 10.0,
    max_checks: int = 10,
    context_scans: int = 1,
) -> RevisitReport:
    """Match up to ``max_checks`` returning scans (evenly spread over those that qualify) against the map
    of the first ``start_fraction`` of the scans, rendered at their optimised poses."""
    n = len(log_)
    n0 = max(20, int(n * start_fraction))
    P = res.pose_xy_yaw
    start = render_map(
        log_.slice(0, n0), P[:n0], cfg.model_copy(update={"map_resolution": cfg.resolution})
    )
    prob, known, x0, y0 = start.cropped_known()
    d = np.min(np.hypot(P[:, None, 0] - P[None, :n0, 0], P[:, None, 1] - P[None, :n0, 1]), axis=1)
    cand = np.flatnonzero((np.arange(n) >= max(n0, int(n * min_gap_fraction))) & (d < radius))
    if len(cand) > max_checks:
        cand = cand[np.linspace(0, len(cand) - 1, max_checks).round().astype(int)]
    pts_all = scan_points(log_, cfg, with_time=True)
    r = cfg.resolution
    lin = int(round(window / r))
    checks = []
    L = res.local_xy_yaw

    def unwarped(j: int) -> FloatArray:
        q = pts_all[j][:, :2]
        if log_.time_increment > 0 and j > 0:
            # unwarped with the local SLAM's motion over the scan, as the SLAM and render_map do
            dt = max(float(log_.t_ns[j] - log_.t_ns[j - 1]) * 1e-9, 1e-3)
            step_j = pose2.between(L[j - 1], L[j])
            q = pose2.act_each(step_j[None] * (pts_all[j][:, 2] / dt)[:, None], q)
        return q

    for k in cand:
        pts = np.concatenate(
            [pose2.act(pose2.between(L[k], L[j]), unwarped(j))
             for j in range(max(0, int(k) - context_scans + 1), int(k) + 1)]
        )  # fmt: skip
        if context_scans > 1 and len(pts) > 1:
            key = np.floor(pts / r).astype(np.int64)  # one point per cell of the matched grid
            _, first = np.unique(key[:, 0] * 1_000_003 + key[:, 1], return_index=True)
            pts = pts[np.sort(first)]
        if len(pts) < 10:
            continue
        step = angular_step(
            r, min(float(np.max(np.hypot(pts[:, 0], pts[:, 1]))), cfg.loop.step_range)
        )
        n_ang = int(np.ceil(np.deg2rad(angular_window_deg) / step))
        vol = score_volume(prob, x0, y0, r, pts, P[k], lin, n_ang, step, start.params.p_unknown)
        a, iy, ix = np.unravel_index(int(np.argmax(vol)), vol.shape)
        # the best pose away from the peak: mask the peak's neighbourhood
        A, Y, X = np.meshgrid(
            (np.arange(vol.shape[0]) - a) * step, (np.arange(vol.shape[1]) - iy) * r,
            (np.arange(vol.shape[2]) - ix) * r, indexing="ij",
        )  # fmt: skip
        far = (np.hypot(X, Y) > peak_radius) | (np.abs(A) > np.deg2rad(peak_angle_deg))
        second = float(vol[far].max()) if far.any() else 0.0
        lattice = np.array(
            [P[k, 0] + (ix - lin) * r, P[k, 1] + (iy - lin) * r, P[k, 2] + (a - n_ang) * step]
        )
        m, score = refine_pose(
            prob, x0, y0, r, pts, lattice, lattice, 1.0, 0.0, 0.0, start.params.p_unknown, 30
        )
        cx = np.floor((pose2.act(m, pts)[:, 0] - x0) / r).astype(np.int64)
        cy = np.floor((pose2.act(m, pts)[:, 1] - y0) / r).astype(np.int64)
        inside = (cx >= 0) & (cy >= 0) & (cx < prob.shape[1]) & (cy < prob.shape[0])
        seen = np.zeros(len(pts), bool)
        seen[inside] = known[cy[inside], cx[inside]]
        db = pose2.between(m, res.local_xy_yaw[k])
        da = pose2.between(m, P[k])
        checks.append(
            RevisitCheck(
                int(k),
                float(d[k]),
                m,
                float(score),
                second,
                float(np.hypot(db[0], db[1])),
                float(np.rad2deg(abs(pose2.wrap(db[2])))),
                float(np.hypot(da[0], da[1])),
                float(np.rad2deg(abs(pose2.wrap(da[2])))),
                len(pts),
                float(seen.mean()),
            )  # fmt: skip
        )
    return RevisitReport(n0, float(np.nanmedian(res.match_score)), checks)
