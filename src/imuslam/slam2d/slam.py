"""2D SLAM with wheel odometry and an IMU, the Cartographer way (Hess, Kohler, Rapp, Andor, "Real-Time
Loop Closure in 2D LIDAR SLAM", ICRA 2016):

local SLAM   each scan is matched against the current submap: a motion prior from the wheel odometry
             and the IMU's yaw rate (the rate about the gravity direction; scans taken while the IMU
             reports a tilt above ``max_tilt_deg`` are not inserted), a real-time correlative search
             (Olson 2009), then Gauss-Newton refinement on the interpolated probability grid. Scans that
             moved enough (the motion filter) become nodes and are inserted into the two active submaps;
             a submap is finished after ``scans_per_submap`` nodes. A scan scoring far below the run's
             median is searched again over a wide window by branch and bound (an odometry jump), or not
             inserted.
global SLAM  nodes are matched against finished submaps by branch and bound (Hess 2016, section V);
             accepted matches are loop constraints with a Huber loss in a pose graph of the nodes
             (consecutive nodes tied by their local-SLAM relative pose), optimised with gtsam
             (Levenberg-Marquardt), as the graph grows and once at the end.

Poses are [x, y, theta] of the body (odometry frame) in the map frame; the first scan is at the origin.
"""

from __future__ import annotations

import bisect
import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from imuslam.errors import EstimatorError
from imuslam.io.laserlog import LaserLog
from imuslam.slam2d import pose2
from imuslam.slam2d.grid import GridParams, ProbabilityGrid
from imuslam.slam2d.matching import (
    SubmapIndex,
    angular_step,
    bnb_match,
    bnb_match_distinct,
    bnb_match_peaks,
    correlative_search,
    make_index,
    match_information,
    refine_pose,
)

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)


class MatcherConfig(BaseModel):
    """Local scan matching (Cartographer's names where they exist)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    use_correlative: bool = True
    linear_window: float = Field(0.15, ge=0, description="correlative search half-window, m")
    angular_window_deg: float = Field(10.0, ge=0, description="correlative search half-window, deg")
    step_range: float = Field(
        10.0, gt=0, description="angular step: one cell at this range, m (Olson 2009)"
    )
    translation_delta_cost_weight: float = Field(0.1, ge=0)
    rotation_delta_cost_weight: float = Field(0.1, ge=0)
    occupied_space_weight: float = Field(1.0, gt=0)
    # Cartographer's 2D default is 10: it pulls each scan towards the wheel odometry's translation, which
    # kept our relation errors near the odometry's on ACES and MIT-CSAIL (0.057 / 0.058 m); 3 lets the
    # scan decide while still holding the pose along featureless corridors (1 lost ACES's corridors)
    translation_weight: float = Field(3.0, ge=0, description="pull towards the prior, per m")
    rotation_weight: float = Field(40.0, ge=0, description="pull towards the prior, per rad")
    max_iterations: int = Field(20, ge=1)
    interpolation: Literal["bilinear", "bicubic"] = Field(
        "bilinear", description="of the probability grid in the refinement (Cartographer: bicubic)"
    )
    # a scan whose match scores this far below the running median is searched again over a wide window
    # by branch and bound against the same submap (an odometry jump, a slip while turning: on ACES a
    # 61 deg turn in 0.16 s is read as a jump and replaced by no motion; the +-10 deg window cannot
    # bridge it and the local SLAM kept a 68 deg error for the rest of the log)
    recovery_score_ratio: float = Field(
        0.6, ge=0, lt=1, description="wide search when the score < ratio x the running median"
    )
    # Where the wheel odometry is trusted, its prior cannot be off by a quarter turn: on the BreezySLAM
    # logs the +-90 deg search at a poorly matching corner turned the drive by -89 deg (exp1; exp2 twice
    # +89 deg, each at the window's edge, scoring 0.38-0.43 against a run median of 0.63) where the
    # wheels turned a few degrees, and the rest of the map folded over itself; the true re-localisations
    # of fr079 and MIT-CSAIL are 0-20 deg from the prior. So with odometry the full angular window is
    # searched only where the prior is suspect (``recovery_when: suspect``): within
    # ``recovery_suspect_scans`` scans after an odometry jump the reader replaced by no motion, or after a
    # pause of ``recovery_gap_s`` in the scans (ACES's 61 deg turn in 0.16 s follows a 3 s pause);
    # elsewhere +-``recovery_trusted_window_deg``. Without odometry, or ``always``, the full window.
    recovery_when: Literal["suspect", "always"] = Field(
        "suspect", description="the full angular window only where the odometry prior is suspect"
    )
    recovery_suspect_scans: int = Field(
        50, ge=1, description="scans after an odometry jump or a scan gap that get the full window"
    )
    recovery_gap_s: float = Field(
        1.0, gt=0, description="a pause in the scans this long is a gap, s"
    )
    recovery_trusted_window_deg: float = Field(
        30.0,
        gt=0,
        le=180.0,
        description="wide search half-window where the odometry is trusted, deg",
    )
    recovery_linear_window: float = Field(1.0, gt=0, description="wide search half-window, m")
    # +-90 deg: a corridor scores almost as well turned by 180 deg (MIT-CSAIL with +-180: a scan flipped
    # at 0.44 against a run median of 0.68, and the map broke)
    recovery_angular_window_deg: float = Field(90.0, gt=0, le=180.0)
    recovery_min_gain: float = Field(
        0.15,
        gt=0,
        description="the wide search's pose must score this much more than the local one "
        "and no longer be poor (at least recovery_score_ratio x the running median)",
    )


class LoopConfig(BaseModel):
    """Loop closure and pose graph."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    enabled: bool = True
    background: bool = Field(
        True,
        description="search constraints in a background thread (as Cartographer's constraint builder); "
        "the intermediate optimisations then see the constraints found so far, so runs can differ slightly",
    )
    # The worker's constraints join the graph when collected; while it lags, the main thread picks the
    # next nodes' candidate submaps from global poses that lack them (ACES: 53 constraints against 71
    # inline, ATE 0.24 against 0.13 m). Past this many queued jobs the main thread waits for the oldest.
    max_pending_jobs: int = Field(
        4,
        ge=1,
        description="background loop jobs queued before the main thread waits for the oldest",
    )
    every_n_nodes: int = Field(5, ge=1, description="search constraints for one node in this many")
    max_submaps_per_node: int = Field(
        3, ge=1, description="the nearest finished submaps searched per node"
    )
    step_range: float = Field(15.0, gt=0, description="angular step: one cell at this range, m")
    max_distance: float = Field(10.0, gt=0, description="only submaps this close to the node, m")
    linear_window: float = Field(3.0, gt=0, description="branch-and-bound half-window, m")
    angular_window_deg: float = Field(20.0, gt=0)
    min_score: float = Field(0.6, gt=0, lt=1)
    depth: int = Field(
        5, ge=1, le=8, description="branch-and-bound levels (root step 2^depth cells)"
    )
    optimize_every_n_nodes: int = Field(60, ge=1)
    # loop constraints as soft as a 10 cm / 3 deg match and a Huber threshold of one sigma: with 5 cm,
    # 1.1 deg and k = 5, ACES's loop edges bent the local SLAM (relation error 0.051 -> 0.057 m)
    huber_k: float = Field(1.0, gt=0, description="Huber threshold on whitened loop residuals")
    local_sigma_m: float = Field(0.004, gt=0)
    local_sigma_rad: float = Field(0.0015, gt=0)
    # "information": each local edge's covariance from its scan match (J^T J of the refinement's
    # residuals plus the prior's weights, inverted, scaled so its median translation sigma is
    # local_sigma_m and capped at 25x): loop closures may then stretch a corridor along its axis where
    # the scan could not fix the pose (MIT-CSAIL's corridor slip) instead of bending every edge alike
    local_edges: Literal["fixed", "information"] = "fixed"
    loop_sigma_m: float = Field(0.1, gt=0)
    loop_sigma_rad: float = Field(0.05, gt=0)
    skip_recent_submaps: int = Field(
        2, ge=0, description="the newest finished submaps are local SLAM's"
    )
    # acceptance beyond the absolute score (a corridor, a row of equal rooms: a match can score well at
    # several places). 1) the peak must be distinct: a second branch and bound over the same window,
    # without the poses near the best, finds nothing within ``distinct_margin`` of its score (Olson's
    # local uniqueness test, Robotics and Autonomous Systems 57(12), 2009; 0 switches it off).
    # 2) candidates must agree with each other: a candidate is accepted once ``consistent_min`` - 1
    # candidates of other nodes within ``consistency_window_nodes`` imply the same relative pose between
    # their nodes as the local SLAM (pairwise consistency, as Olson's single-cluster graph partitioning
    # and Latif et al.'s RRR group loop hypotheses; Cartographer relies on the Huber loss alone). 1: off.
    # With 3) on, a peak of another node's ambiguous match may be the agreeing one (never a disagreeing
    # one: an ambiguous match's peaks scatter by nature). Without that, a group of true candidates
    # whose neighbours' matches fall just short of the distinct-peak test loses its support: on
    # MIT-CSAIL with the background search, node 1420 found nothing above the minimum score and 1430
    # came out ambiguous (its peak the same pose) after 1 cm shifts of their search guesses, and the
    # distinct candidates of nodes 1410, 1415 and 1590 were rejected for want of two agreeing nodes (60
    # distinct constraints of 67, ATE 0.36 -> 0.44 m; with the lost ones restored offline, 0.36 m)
    distinct_margin: float = Field(
        0.05, ge=0, description="best score minus the best clearly different pose's, at least"
    )
    peak_radius: float = Field(0.5, gt=0, description="'clearly different': this far, m ...")
    peak_angle_deg: float = Field(10.0, gt=0, description="... or turned this much, deg")
    consistent_min: int = Field(
        3, ge=1, description="mutually consistent candidates (of distinct nodes) to accept one"
    )
    consistency_window_nodes: int = Field(30, ge=1)
    consistency_ratio: float = Field(
        2.0, ge=0, description="agreeing nodes at least this many times the disagreeing ones"
    )
    consistency_tol_m: float = Field(0.2, gt=0, description="plus 2 % of the nodes' distance")
    consistency_tol_deg: float = Field(2.0, gt=0)
    # 3) consistency over time for matches with no distinct peak: the best ``peaks_per_match`` peaks of
    # each are kept, and one becomes a constraint when a majority of the ``temporal_window`` consecutive
    # nodes searched against the same submap have a peak implying the same pose of it (each peak composed
    # with the local SLAM's relative poses, within ``temporal_tol_m`` / ``temporal_tol_deg``): wrong peaks
    # scatter, the true one recurs (the consistent-set acceptance of Olson 2009 and of Latif et al.'s RRR,
    # "Robust loop closing over time for pose graph SLAM", IJRR 32(14), 2013). 0 peaks: off.
    peaks_per_match: int = Field(
        3, ge=0, description="peaks kept per ambiguous match for the consistency over time (0: off)"
    )
    temporal_window: int = Field(
        10, ge=2, description="consecutive nodes searched against a submap that vote"
    )
    # 2 cells and 2 deg: the refined peaks of exp1's returning scans that agree scatter by about +-1.5 deg
    # (with 1 cell / 1 deg only 2 of its 9 were accepted)
    temporal_tol_m: float = Field(0.1, gt=0, description="same implied pose: within this, m ...")
    temporal_tol_deg: float = Field(2.0, gt=0, description="... and this, deg")
    # consecutive scans that see a repeated structure from nearly the same place alias alike, so their
    # wrong peaks can agree too (exp2: 5 nodes agreed on a 3 m / 20 deg correction against a submap
    # mapped 7 m of path before). The correction a peak implies is gated by the drift the local SLAM can
    # have accumulated since the submap's first node (the individual-compatibility gate of Neira and
    # Tardos, IEEE T-RA 17(6), 2001, with a drift that grows with the path instead of a covariance)
    temporal_drift: float = Field(
        0.05, gt=0, description="largest correction: tol_m + this x the path since the submap, m/m"
    )
    temporal_drift_deg_per_m: float = Field(
        0.5, gt=0, description="... and tol_deg + this x the path, deg/m"
    )


class Slam2dConfig(BaseModel):
    """Everything the 2D SLAM reads; written beside every result as config.yaml."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    resolution: float = Field(0.05, gt=0.005, le=1.0, description="grid cell, m")
    min_range: float = Field(0.1, ge=0)
    max_range: float = Field(30.0, gt=0, description="readings beyond are not used, m")
    voxel_size: float = Field(0.025, ge=0, description="scan points thinned to one per voxel, m")
    scans_per_submap: int = Field(
        60, ge=2, description="nodes inserted into a submap before it is finished"
    )
    motion_min_distance: float = Field(
        0.1, ge=0, description="motion filter: a new node after this, m"
    )
    motion_min_angle_deg: float = Field(2.0, ge=0)
    motion_max_time_s: float = Field(5.0, gt=0)
    use_odometry: bool = True
    use_imu: bool = True
    max_tilt_deg: float = Field(
        5.0, gt=0, description="scans with a larger IMU tilt are not inserted"
    )
    matcher: MatcherConfig = Field(default_factory=MatcherConfig)
    loop: LoopConfig = Field(default_factory=LoopConfig)
    map_resolution: float = Field(0.05, gt=0.005, le=1.0, description="output map cell, m")


@dataclass
class LoopConstraint:
    """A node matched against a finished submap, kept as the pose-graph edge it gives: the node's pose
    relative to the submap's anchor node (the first node inserted into it)."""

    node: int  # index into the nodes
    submap: int
    T_submap_node: FloatArray
    score: float
    anchor: int
    T_anchor_node: FloatArray
    peak: int = (
        0  # 0: a distinct match; k >= 1: the k-th best peak of a match without a distinct one
    )


@dataclass
class Slam2dResult:
    """t_ns (N,) the log's stamps; pose_xy_yaw (N, 3) optimised map-frame pose per scan; local_xy_yaw
    (N, 3) local-SLAM poses; odom_xy_yaw (N, 3) or None; node_scans (M,) scans that became nodes."""

    t_ns: NDArray[np.int64]
    pose_xy_yaw: FloatArray
    local_xy_yaw: FloatArray
    odom_xy_yaw: FloatArray | None
    node_scans: NDArray[np.int64]
    n_submaps: int
    loops: list[LoopConstraint]
    loops_searched: int
    timing_s: dict[str, float]
    warnings: dict[str, int]
    mean_match_score: float
    config: Slam2dConfig
    source: str = ""
    rejected_tilt: int = 0
    extra: dict[str, float] = field(default_factory=dict)
    # (N,) the local match's score (mean probability at the scan's points), NaN where not matched
    match_score: FloatArray = field(default_factory=lambda: np.zeros(0))


def scan_points(log_: LaserLog, cfg: Slam2dConfig, with_time: bool = False) -> list[FloatArray]:
    """Per scan, the valid hit points (P, 2) in the body frame, thinned by the voxel filter; with
    ``with_time`` (P, 3): the third column the beam's firing time after the scan's stamp, s."""
    ang = log_.angles
    ca, sa = np.cos(ang), np.sin(ang)
    r = log_.ranges.astype(float)
    ok = np.isfinite(r) & (r >= cfg.min_range) & (r <= cfg.max_range)
    T = log_.T_b_l
    c, s = np.cos(T[2]), np.sin(T[2])
    lx, ly = np.where(ok, r * ca, 0.0), np.where(ok, r * sa, 0.0)
    bx, by = c * lx - s * ly + T[0], s * lx + c * ly + T[1]
    out: list[FloatArray] = []
    v = cfg.voxel_size
    for k in range(len(log_)):
        m = ok[k]
        p = np.column_stack([bx[k, m], by[k, m]])
        if with_time:
            p = np.column_stack([p, np.flatnonzero(m) * log_.time_increment])
        if v > 0 and len(p) > 1:
            key = np.floor(p[:, :2] / v).astype(np.int64)
            _, first = np.unique(key[:, 0] * 1_000_003 + key[:, 1], return_index=True)
            p = p[np.sort(first)]
        out.append(p)
    return out


def imu_yaw_and_tilt(log_: LaserLog) -> tuple[FloatArray, FloatArray] | None:
    """Integrated yaw (rad) at each scan time about the gravity direction, and the tilt of the IMU's z
    axis from gravity (deg) at each scan (the accelerometer averaged over 1 s); None without an IMU."""
    imu = log_.imu
    if imu is None or len(imu) < 2:
        return None
    t = (imu.t_ns - log_.t_ns[0]).astype(float) * 1e-9
    acc = imu.accel * (9.80665 if imu.accel_unit == "g" else 1.0)
    gyr = imu.gyro * (np.pi / 180 if imu.gyro_unit == "deg/s" else 1.0)
    dt_med = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
    w = max(1, int(round(1.0 / max(dt_med, 1e-4))))
    kern = np.ones(w) / w
    up = np.column_stack([np.convolve(acc[:, i], kern, mode="same") for i in range(3)])
    up /= np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-9)
    rate = np.einsum("ij,ij->i", gyr, up)  # rate about the up direction
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    ts = (log_.t_ns - log_.t_ns[0]).astype(float) * 1e-9
    tilt = np.rad2deg(np.arccos(np.clip(up[:, 2], -1, 1)))
    return np.interp(ts, t, yaw), np.interp(ts, t, tilt)


class _Submap:
    def __init__(self, params: GridParams, centre: FloatArray, half: float) -> None:
        self.grid = ProbabilityGrid(params, centre, half)
        self.anchor_node = -1
        # the grid's cells are addressed in the local-SLAM frame: that frame is the submap's frame
        self.T_local_submap = np.zeros(3)
        self.n_nodes = 0
        self.index: SubmapIndex | None = None
        self.finished = False


class Slam2d:
    """The estimator: ``add_scan`` per scan; ``finish`` runs the final optimisation."""

    def __init__(self, cfg: Slam2dConfig) -> None:
        self.cfg = cfg
        self.params = GridParams(resolution=cfg.resolution)
        self.submaps: list[_Submap] = []
        self.active: list[int] = []
        self.node_scan: list[int] = []
        self.node_local: list[FloatArray] = []
        self.node_global: list[FloatArray] = []
        self.node_points: list[FloatArray] = []
        self.loops: list[LoopConstraint] = []
        # per node: the information (3 x 3, local frame) of its scan match and prior, None if unmatched
        self.node_info: list[FloatArray | None] = []
        self.last_info: FloatArray | None = None
        self.loops_searched = 0
        self.last_node_t = -1e18
        # loop_search: wall time of the matching jobs; loop_search_cpu: their thread's CPU time
        self.timing = {"local": 0.0, "loop_search": 0.0, "loop_search_cpu": 0.0, "optimise": 0.0}
        self.scores: list[float] = []
        self._nodes_since_opt = 0
        self._loops_since_opt = 0
        self.sensor_b = np.zeros((1, 2))  # the laser's origin in the body frame
        # loop-closure work (submap indices, branch and bound, refinement) runs in order on one worker
        # thread when cfg.loop.background: the numba kernels release the GIL, so it uses the second core
        self._pool: ThreadPoolExecutor | None = None
        if cfg.loop.enabled and cfg.loop.background:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="slam2d-loops")
        # the worker's jobs in submission order, each with the node it searched for (-1: a submap index)
        self._pending: list[tuple[Future[tuple[list[LoopConstraint], float, float]], int]] = []
        self._searched_upto = -1  # every node up to this one has had its loop search collected
        self.main_loop_time = 0.0  # loop-closure time spent on the main thread
        # loop candidates (matches above min_score) waiting for the consistency check, and the counts:
        # matched, rejected as ambiguous (on the worker), rejected as inconsistent
        self._candidates: list[LoopConstraint] = []
        self._decided: set[int] = set()  # id() of the candidates in _candidates already decided
        # the peaks of ambiguous matches (consistency over time on): they can support a candidate in
        # the pairwise check, never count against it
        self._support: list[LoopConstraint] = []
        self.loop_stats = {"candidates": 0, "ambiguous": 0, "inconsistent": 0, "temporal": 0}
        # consistency over time (cfg.loop.peaks_per_match): per submap, the nodes searched against it
        # and the peaks of their matches (distinct ones vote too); nodes already decided
        self._searched_against: dict[int, list[int]] = {}
        self._peaks: dict[int, dict[int, list[LoopConstraint]]] = {}
        self._peaks_open: set[tuple[int, int]] = (
            set()
        )  # (submap, node) of ambiguous peaks undecided

    # ---------------------------------------------------------------- local SLAM
    def match(self, pts: FloatArray, prior: FloatArray) -> tuple[FloatArray, float]:
        """Pose of a scan in the local frame, from the prior, against the oldest active submap (and, for
        information-weighted local edges, ``last_info``: the match's information)."""
        self.last_info = None
        if not self.active:
            return prior, 0.0
        g = self.submaps[self.active[0]].grid
        if g.n_scans == 0 or len(pts) < 3:
            return prior, 0.0
        m = self.cfg.matcher
        p = self.params
        init = prior
        if m.use_correlative and (m.linear_window > 0 or m.angular_window_deg > 0):
            d_max = min(float(np.max(np.hypot(pts[:, 0], pts[:, 1]))), m.step_range)
            step = angular_step(p.resolution, d_max)
            n_ang = int(np.ceil(np.deg2rad(m.angular_window_deg) / step))
            init, _ = correlative_search(
                g.prob, g.x0, g.y0, p.resolution, pts, prior, int(round(m.linear_window / p.resolution)),
                n_ang, step, m.translation_delta_cost_weight, m.rotation_delta_cost_weight, p.p_unknown,
            )  # fmt: skip
        # Cartographer's targets: the translation of the prediction, the rotation of the search result
        target = np.array([prior[0], prior[1], init[2]])
        pose, score = refine_pose(
            g.prob, g.x0, g.y0, p.resolution, pts, init, target, m.occupied_space_weight,
            m.translation_weight, m.rotation_weight, p.p_unknown, m.max_iterations,
            m.interpolation == "bicubic",
        )  # fmt: skip
        if self.cfg.loop.enabled and self.cfg.loop.local_edges == "information":
            info = match_information(
                g.prob, g.x0, g.y0, p.resolution, pts, pose, m.occupied_space_weight, p.p_unknown
            )
            self.last_info = info + np.diag(
                [m.translation_weight**2, m.translation_weight**2, m.rotation_weight**2]
            )
        return pose, float(score)

    def relocalise(
        self,
        pts: FloatArray,
        prior: FloatArray,
        score: float,
        median: float,
        full_window: bool = True,
    ) -> tuple[FloatArray, float] | None:
        """Branch and bound of a scan against the oldest active submap over the recovery window around
        ``prior`` (the trusted-odometry angular window unless ``full_window``), refined; the pose and score
        when it beats ``score`` by the recovery gain and is no longer poor against the run's ``median``
        score, else None."""
        m = self.cfg.matcher
        window_deg = (
            m.recovery_angular_window_deg
            if full_window
            else min(m.recovery_trusted_window_deg, m.recovery_angular_window_deg)
        )
        need = max(score + m.recovery_min_gain, m.recovery_score_ratio * median)
        g = self.submaps[self.active[0]].grid
        prob, x0, y0 = g.cropped()
        idx = make_index(prob, x0, y0, self.params.resolution, self.cfg.loop.depth)
        pose, sc = bnb_match(
            idx, pts, prior, m.recovery_linear_window, np.deg2rad(window_deg),
            need, self.cfg.loop.step_range,
        )  # fmt: skip
        if sc < 0:
            return None
        p = self.params
        refined, sc2 = refine_pose(
            prob, x0, y0, p.resolution, pts, pose, pose, m.occupied_space_weight, m.translation_weight,
            m.rotation_weight, p.p_unknown, m.max_iterations, m.interpolation == "bicubic",
        )  # fmt: skip
        if sc2 < need:
            return None
        return refined, float(sc2)

    def wants_node(self, local: FloatArray, t_s: float) -> bool:
        if not self.node_local:
            return True
        d = pose2.between(self.node_local[-1], local)
        return bool(
            np.hypot(d[0], d[1]) >= self.cfg.motion_min_distance
            or abs(d[2]) >= np.deg2rad(self.cfg.motion_min_angle_deg)
            or t_s - self.last_node_t >= self.cfg.motion_max_time_s
        )

    def add_node(self, scan: int, local: FloatArray, pts: FloatArray, t_s: float) -> None:
        """Insert a scan into the active submaps, start/finish submaps, search loops, optimise."""
        cfg = self.cfg
        j = len(self.node_local)
        if self.node_global:
            prev = len(self.node_local) - 1
            glob = pose2.compose(
                self.node_global[prev], pose2.between(self.node_local[prev], local)
            )
        else:
            glob = local.copy()
        self.node_scan.append(scan)
        self.node_local.append(local.copy())
        self.node_global.append(glob)
        self.node_points.append(pts)
        self.node_info.append(self.last_info)
        self.last_node_t = t_s
        if not self.active or self.submaps[self.active[-1]].n_nodes >= cfg.scans_per_submap // 2:
            if len(self.active) < 2:
                sm = _Submap(self.params, local[:2], float(min(cfg.max_range, 10.0)))
                sm.anchor_node = j
                self.submaps.append(sm)
                self.active.append(len(self.submaps) - 1)
        w = pose2.act(local, pts)
        for s in self.active:
            self.submaps[s].grid.insert(pose2.act(local, self.sensor_b)[0], w)
            self.submaps[s].n_nodes += 1
        if self.submaps[self.active[0]].n_nodes >= cfg.scans_per_submap:
            done = self.active.pop(0)
            sm = self.submaps[done]
            sm.finished = True
            if cfg.loop.enabled:
                t0 = time.perf_counter()
                prob, x0, y0 = sm.grid.cropped()
                sm.grid.prob = prob
                sm.grid.logodds = np.zeros((1, 1), np.float32)
                sm.grid.stamp = np.zeros((1, 1), np.int32)
                sm.grid.x0, sm.grid.y0 = x0, y0
                self.main_loop_time += time.perf_counter() - t0
                self._run(self._index_job, done)
        if cfg.loop.enabled:
            if j % cfg.loop.every_n_nodes == 0:
                self.search_loops(j)
            self.collect_loops()
            self._nodes_since_opt += 1
            if self._loops_since_opt and self._nodes_since_opt >= cfg.loop.optimize_every_n_nodes:
                self.optimise()

    # ---------------------------------------------------------------- global SLAM
    def submap_global(self, s: int) -> FloatArray:
        sm = self.submaps[s]
        a = sm.anchor_node
        return pose2.compose(
            self.node_global[a], pose2.between(self.node_local[a], sm.T_local_submap)
        )

    @property
    def in_background(self) -> bool:
        return self._pool is not None

    def _run(
        self,
        fn: Callable[..., tuple[list[LoopConstraint], float, float]],
        *args: object,
        node: int = -1,
    ) -> None:
        """``fn(*args)`` on the loop worker (or here without one); its constraints join the graph
        when collected (``node``: the node whose loop search it is)."""
        if self._pool is not None:
            self._pending.append((self._pool.submit(fn, *args), node))
            while len(self._pending) > self.cfg.loop.max_pending_jobs:
                fut, n = self._pending.pop(0)
                self._add_loops(*fut.result(), n)
        else:
            self._add_loops(*fn(*args), node)

    def _add_loops(
        self, loops: list[LoopConstraint], dt: float, dt_cpu: float, node: int = -1
    ) -> None:
        self.timing["loop_search"] += dt
        self.timing["loop_search_cpu"] += dt_cpu
        self._searched_upto = max(self._searched_upto, node)
        self.add_candidates(loops)

    def add_candidates(self, loops: list[LoopConstraint]) -> None:
        """Loop matches that passed the search's tests: constraints at once when the consistency check is
        off, else waiting for it (``vet_candidates``)."""
        if self.cfg.loop.peaks_per_match > 0:
            for c in loops:
                self._peaks.setdefault(c.submap, {}).setdefault(c.node, []).append(c)
                if c.peak:
                    self._peaks_open.add((c.submap, c.node))
            self._support.extend(c for c in loops if c.peak)
            loops = [c for c in loops if c.peak == 0]
            self.vet_peaks(final=False)
        if not loops:
            return
        self.loop_stats["candidates"] += len(loops)
        if self.cfg.loop.consistent_min <= 1:
            self.loops.extend(loops)
            self._loops_since_opt += len(loops)
            return
        self._candidates.extend(loops)
        self.vet_candidates(final=False)

    def _consistent(self, c1: LoopConstraint, c2: LoopConstraint) -> bool:
        """Whether two loop candidates of different nodes imply the relative pose of their nodes that the
        local SLAM gives (each candidate puts its node at anchor's global pose x its constraint)."""
        cfg = self.cfg.loop
        g1 = pose2.compose(self.node_global[c1.anchor], c1.T_anchor_node)
        g2 = pose2.compose(self.node_global[c2.anchor], c2.T_anchor_node)
        implied = pose2.between(g1, g2)
        local = pose2.between(self.node_local[c1.node], self.node_local[c2.node])
        d = pose2.between(implied, local)
        tol = cfg.consistency_tol_m + 0.02 * float(np.hypot(local[0], local[1]))
        return bool(
            np.hypot(d[0], d[1]) <= tol
            and abs(pose2.wrap(d[2])) <= np.deg2rad(cfg.consistency_tol_deg)
        )

    def vet_candidates(self, final: bool) -> None:
        """Decide every waiting candidate whose window (the nodes within ``consistency_window_nodes``) has
        been searched (all when ``final``): accepted when candidates of at least ``consistent_min`` - 1
        other nodes agree with it and those nodes outnumber the ones whose candidates all disagree by
        ``consistency_ratio`` (two groups of matches that contradict each other: neither is trusted,
        the "global sufficiency" side of Olson 2009). With the consistency over time on, a node whose
        ambiguous match has a peak that agrees counts as agreeing; its other peaks never disagree."""
        cfg = self.cfg.loop
        t0 = time.perf_counter()
        W = cfg.consistency_window_nodes
        cands = self._candidates
        for c in cands:
            # settled once every node within the window after it has been searched (the background
            # worker can lag far behind the newest node)
            if id(c) in self._decided or not (final or c.node + W < self._searched_upto):
                continue
            self._decided.add(id(c))
            agree: set[int] = set()
            others: set[int] = set()
            for o in cands:
                if o.node != c.node and abs(o.node - c.node) <= W:
                    others.add(o.node)
                    if o.node not in agree and self._consistent(c, o):
                        agree.add(o.node)
            for o in self._support:
                if (
                    o.node != c.node
                    and abs(o.node - c.node) <= W
                    and o.node not in agree
                    and self._consistent(c, o)
                ):
                    agree.add(o.node)
            disagree = len(others - agree)
            if (
                len(agree) + 1 >= cfg.consistent_min
                and len(agree) >= cfg.consistency_ratio * disagree
            ):
                self.loops.append(c)
                self._loops_since_opt += 1
            else:
                self.loop_stats["inconsistent"] += 1
        # a candidate is kept while an undecided one may still count it
        keep = [c for c in cands if not final and c.node + 2 * W >= self._searched_upto]
        self._decided &= {id(c) for c in keep}
        self._candidates = keep
        self._support = [
            c for c in self._support if not final and c.node + 2 * W >= self._searched_upto
        ]
        self.main_loop_time += time.perf_counter() - t0

    def collect_loops(self, wait: bool = False) -> None:
        """Constraints of the finished background jobs (all of them with ``wait``), in submission order."""
        while self._pending and (wait or self._pending[0][0].done()):
            fut, node = self._pending.pop(0)
            self._add_loops(*fut.result(), node)

    def close(self) -> None:
        """Wait for the loop worker and stop it."""
        if self._pool is not None:
            try:
                self.collect_loops(wait=True)
            finally:
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None

    def _index_job(self, s: int) -> tuple[list[LoopConstraint], float, float]:
        t0, c0 = time.perf_counter(), time.thread_time()
        g = self.submaps[s].grid
        self.submaps[s].index = make_index(
            g.prob, g.x0, g.y0, self.params.resolution, self.cfg.loop.depth
        )
        return [], time.perf_counter() - t0, time.thread_time() - c0

    def search_loops(self, j: int) -> None:
        """Queue the search of node ``j`` against the nearest finished submaps (candidates chosen here from
        the current global poses, matched on the loop worker)."""
        cfg = self.cfg.loop
        t0 = time.perf_counter()
        finished = [s for s, sm in enumerate(self.submaps) if sm.finished]
        if cfg.skip_recent_submaps:
            finished = finished[: max(0, len(finished) - cfg.skip_recent_submaps)]
        g = self.node_global[j]
        pts = self.node_points[j]
        cands: list[tuple[float, int, FloatArray]] = []
        for s in finished:
            T_s_n = pose2.between(self.submap_global(s), g)
            # the submap covers the surroundings of its nodes: distance to its first node
            a = self.node_global[self.submaps[s].anchor_node]
            d = float(np.hypot(a[0] - g[0], a[1] - g[1]))
            if d <= cfg.max_distance:
                cands.append((d, s, T_s_n))
        cands.sort(key=lambda c: c[0])
        jobs = [(s, T_s_n) for _, s, T_s_n in cands[: cfg.max_submaps_per_node]]
        self.loops_searched += len(jobs)
        if cfg.peaks_per_match > 0:
            for s, _ in jobs:
                self._searched_against.setdefault(s, []).append(j)
        self.main_loop_time += time.perf_counter() - t0
        if jobs:
            self._run(self._match_job, j, pts, jobs, node=j)

    def _match_job(
        self, j: int, pts: FloatArray, jobs: list[tuple[int, FloatArray]]
    ) -> tuple[list[LoopConstraint], float, float]:
        """Branch and bound, then refinement, of node ``j``'s points in each submap of ``jobs`` (submap,
        T_submap_node guess); reads only finished submaps and past nodes' local poses."""
        cfg = self.cfg.loop
        t0, c0 = time.perf_counter(), time.thread_time()
        out: list[LoopConstraint] = []
        for s, T_s_n in jobs:
            idx = self.submaps[s].index
            assert idx is not None  # built by an earlier job of the same worker
            if cfg.distinct_margin > 0:
                pose, score, second = bnb_match_distinct(
                    idx, pts, T_s_n, cfg.linear_window, np.deg2rad(cfg.angular_window_deg),
                    cfg.min_score, cfg.step_range, cfg.peak_radius, np.deg2rad(cfg.peak_angle_deg),
                    cfg.distinct_margin,
                )  # fmt: skip
                if score >= 0 and second >= 0:
                    # one writer (the single worker); read after it has finished
                    self.loop_stats["ambiguous"] += 1
                    if cfg.peaks_per_match > 0:
                        out.extend(self._peak_candidates(j, s, pts, T_s_n))
                    continue
            else:
                pose, score = bnb_match(
                    idx, pts, T_s_n, cfg.linear_window, np.deg2rad(cfg.angular_window_deg),
                    cfg.min_score, cfg.step_range,
                )  # fmt: skip
            if score < 0:
                continue
            grid = self.submaps[s].grid
            refined, sc2 = refine_pose(
                grid.prob, grid.x0, grid.y0, self.params.resolution, pts, pose, pose, 1.0, 1.0, 1.0,
                self.params.p_unknown, 20,
            )  # fmt: skip
            sm = self.submaps[s]
            T_a_n = pose2.compose(
                pose2.between(self.node_local[sm.anchor_node], sm.T_local_submap), refined
            )
            out.append(LoopConstraint(j, s, refined, float(sc2), sm.anchor_node, T_a_n))
        return out, time.perf_counter() - t0, time.thread_time() - c0

    def _constraint(
        self, j: int, s: int, pts: FloatArray, pose: FloatArray, peak: int
    ) -> LoopConstraint:
        """The lattice pose ``pose`` of node ``j`` in submap ``s`` refined, as a loop constraint."""
        grid = self.submaps[s].grid
        refined, sc2 = refine_pose(
            grid.prob, grid.x0, grid.y0, self.params.resolution, pts, pose, pose, 1.0, 1.0, 1.0,
            self.params.p_unknown, 20,
        )  # fmt: skip
        sm = self.submaps[s]
        T_a_n = pose2.compose(
            pose2.between(self.node_local[sm.anchor_node], sm.T_local_submap), refined
        )
        return LoopConstraint(j, s, refined, float(sc2), sm.anchor_node, T_a_n, peak)

    def _peak_candidates(
        self, j: int, s: int, pts: FloatArray, T_s_n: FloatArray
    ) -> list[LoopConstraint]:
        """The best few peaks of node ``j`` in submap ``s`` (no distinct one), each refined."""
        cfg = self.cfg.loop
        idx = self.submaps[s].index
        assert idx is not None
        peaks = bnb_match_peaks(
            idx, pts, T_s_n, cfg.linear_window, np.deg2rad(cfg.angular_window_deg), cfg.min_score,
            cfg.step_range, cfg.peak_radius, np.deg2rad(cfg.peak_angle_deg), cfg.peaks_per_match,
        )  # fmt: skip
        return [self._constraint(j, s, pts, p, k + 1) for k, (p, _) in enumerate(peaks)]

    def _implied(self, c: LoopConstraint, at: int) -> FloatArray:
        """The global pose of node ``at`` that candidate ``c`` implies (its node's pose from the match,
        then the local SLAM's relative pose from its node to ``at``)."""
        g = pose2.compose(self.node_global[c.anchor], c.T_anchor_node)
        return pose2.compose(g, pose2.between(self.node_local[c.node], self.node_local[at]))

    def vet_peaks(self, final: bool) -> None:
        """Consistency over time (``cfg.loop.peaks_per_match`` > 0): a node's peak in a submap becomes a
        constraint when, among the ``temporal_window`` nodes around it searched against that submap
        (decided once they all have been), a majority (more than half of the window, and of the nodes
        searched there) have a peak that implies the same pose of it, within ``temporal_tol_m`` and
        ``temporal_tol_deg``; its best such peak is taken. Distinct matches vote but are decided by
        ``vet_candidates``."""
        cfg = self.cfg.loop
        t0 = time.perf_counter()
        K = cfg.temporal_window
        tol_r = np.deg2rad(cfg.temporal_tol_deg)
        for s, n in sorted(self._peaks_open):
            by_node = self._peaks[s]
            cands = by_node[n]
            searched = self._searched_against.get(s, [])
            i = bisect.bisect_left(searched, n)
            lo = max(0, min(i - K // 2, len(searched) - K))
            window = searched[lo : lo + K]
            if not final and (
                len(window) < K or i + K // 2 >= len(searched) or window[-1] > self._searched_upto
            ):
                continue
            self._peaks_open.discard((s, n))
            need = max(K // 2 + 1, len(window) // 2 + 1)
            a = self.submaps[s].anchor_node
            steps = np.diff(np.array(self.node_local[a : n + 1])[:, :2], axis=0)
            path = float(np.sum(np.hypot(steps[:, 0], steps[:, 1]))) if len(steps) else 0.0
            for c in cands:
                g = self._implied(c, n)
                corr = pose2.between(self.node_global[n], g)
                if float(np.hypot(corr[0], corr[1])) > (
                    cfg.temporal_tol_m + cfg.temporal_drift * path
                ) or abs(pose2.wrap(corr[2])) > np.deg2rad(
                    cfg.temporal_tol_deg + cfg.temporal_drift_deg_per_m * path
                ):
                    continue
                votes = 1
                for m in window:
                    if m == n:
                        continue
                    for o in by_node.get(int(m), []):
                        d = pose2.between(g, self._implied(o, n))
                        if (
                            np.hypot(d[0], d[1]) <= cfg.temporal_tol_m
                            and abs(pose2.wrap(d[2])) <= tol_r
                        ):
                            votes += 1
                            break
                if votes >= need:
                    self.loops.append(c)
                    self._loops_since_opt += 1
                    self.loop_stats["temporal"] += 1
                    break
        self.main_loop_time += time.perf_counter() - t0

    def _local_noises(self, L: FloatArray) -> list[Any]:
        """Per local edge i -> i + 1: a Gaussian noise model of node i + 1's match covariance (inverse
        information) in node i's frame, scaled so the median translation sigma is ``local_sigma_m``,
        each sigma capped at 25x the fixed ones; None where the node has no match."""
        import gtsam

        cfg = self.cfg.loop
        covs: list[FloatArray | None] = []
        for i in range(len(L) - 1):
            info = self.node_info[i + 1]
            if info is None or not np.all(np.isfinite(info)):
                covs.append(None)
                continue
            c, s = np.cos(L[i, 2]), np.sin(L[i, 2])
            R = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # local frame -> node i's
            cov = R @ np.linalg.inv(info + 1e-9 * np.eye(3)) @ R.T
            covs.append(0.5 * (cov + cov.T))
        sig = [np.sqrt(0.5 * (c[0, 0] + c[1, 1])) for c in covs if c is not None]
        if not sig:
            return [None] * len(covs)
        scale = (cfg.local_sigma_m / float(np.median(sig))) ** 2
        cap = np.array([25 * cfg.local_sigma_m] * 2 + [25 * cfg.local_sigma_rad])
        out: list[Any] = []
        for cov in covs:
            if cov is None:
                out.append(None)
                continue
            cv = cov * scale
            # cap: shrink the covariance where a sigma exceeds 25x the fixed one
            d = np.sqrt(np.diag(cv))
            f = np.minimum(1.0, cap / np.maximum(d, 1e-12))
            out.append(gtsam.noiseModel.Gaussian.Covariance(cv * np.outer(f, f)))
        return out

    def optimise(self) -> None:
        """Levenberg-Marquardt on the pose graph (gtsam), warm-started from the current estimate."""
        import gtsam

        t0 = time.perf_counter()
        cfg = self.cfg.loop
        n = len(self.node_local)
        graph = gtsam.NonlinearFactorGraph()
        init = gtsam.Values()
        local_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.local_sigma_m, cfg.local_sigma_m, cfg.local_sigma_rad])
        )
        loop_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(cfg.huber_k),
            gtsam.noiseModel.Diagonal.Sigmas(
                np.array([cfg.loop_sigma_m, cfg.loop_sigma_m, cfg.loop_sigma_rad])
            ),
        )
        graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*self.node_global[0]),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-6))))  # fmt: skip
        L = np.array(self.node_local)
        rel = pose2.between(L[:-1], L[1:])
        noises = self._local_noises(L) if cfg.local_edges == "information" else None
        for i in range(n - 1):
            noise = local_noise if noises is None or noises[i] is None else noises[i]
            graph.add(gtsam.BetweenFactorPose2(i, i + 1, gtsam.Pose2(*rel[i]), noise))
        for c in self.loops:
            graph.add(
                gtsam.BetweenFactorPose2(
                    c.anchor, c.node, gtsam.Pose2(*c.T_anchor_node), loop_noise
                )
            )
        for i, g in enumerate(self.node_global):
            init.insert(i, gtsam.Pose2(*g))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(50)
        params.setRelativeErrorTol(1e-6)
        try:
            res = gtsam.LevenbergMarquardtOptimizer(graph, init, params).optimize()
        except RuntimeError as exc:  # gtsam reports an indeterminant system this way
            raise EstimatorError(f"pose graph of {n} nodes: optimisation failed ({exc})") from None
        out = np.array(
            [[res.atPose2(i).x(), res.atPose2(i).y(), res.atPose2(i).theta()] for i in range(n)]
        )
        if not np.isfinite(out).all():
            raise EstimatorError(f"pose graph of {n} nodes: non-finite result")
        self.node_global = list(out)
        self._nodes_since_opt = 0
        self._loops_since_opt = 0
        self.timing["optimise"] += time.perf_counter() - t0


def run_slam2d(
    log_: LaserLog, cfg: Slam2dConfig | None = None, progress: Callable[[int], None] | None = None
) -> Slam2dResult:
    """Run the 2D SLAM over every scan of ``log_``; ``progress(k)`` is called after each scan."""
    cfg = cfg or Slam2dConfig()
    slam = Slam2d(cfg)
    try:
        return _run_slam2d(log_, cfg, slam, progress)
    finally:
        slam.close()


def _wide_search_scans(log_: LaserLog, cfg: Slam2dConfig, odometry: bool) -> NDArray[np.bool_]:
    """(N,) True at the scans whose wide search gets the full angular window (``MatcherConfig.recovery_when``)."""
    n = len(log_)
    m = cfg.matcher
    if m.recovery_when == "always" or not odometry:
        return np.ones(n, bool)
    start = np.zeros(n, bool)
    if log_.odom_jumped is not None:
        start |= log_.odom_jumped
    gap = np.diff(log_.t_ns).astype(float) * 1e-9 >= m.recovery_gap_s
    start[1:] |= gap
    # each suspect scan opens a window of recovery_suspect_scans scans (itself included)
    opened = np.cumsum(start)
    closed = np.concatenate(
        [np.zeros(m.recovery_suspect_scans, np.int64), opened[: -m.recovery_suspect_scans]]
    )
    return (opened - closed[:n]) > 0


def _run_slam2d(
    log_: LaserLog, cfg: Slam2dConfig, slam: Slam2d, progress: Callable[[int], None] | None
) -> Slam2dResult:
    n = len(log_)
    pts_all = scan_points(log_, cfg, with_time=True)
    deskew = log_.time_increment > 0
    odo = log_.odom_xy_yaw if (cfg.use_odometry and log_.odom_xy_yaw is not None) else None
    imu = imu_yaw_and_tilt(log_) if cfg.use_imu else None
    t_s = (log_.t_ns - log_.t_ns[0]).astype(float) * 1e-9
    slam.sensor_b = log_.T_b_l[None, :2].copy()
    local = np.zeros((n, 3))
    node_of_scan = np.zeros(n, np.int64)
    match_score = np.full(n, np.nan)
    recovered = 0
    poor_scans = 0
    recent: list[float] = []  # the last scores, for the running median
    rejected_tilt = 0
    empty = 0
    pose = np.zeros(3)
    vel = np.zeros(3)  # last local step (constant-velocity model without odometry)
    wide_ok = _wide_search_scans(log_, cfg, odo is not None)
    t0 = time.perf_counter()
    for k in range(n):
        if k > 0:
            step = pose2.between(odo[k - 1], odo[k]) if odo is not None else vel.copy()
            if imu is not None:
                step[2] = pose2.wrap(imu[0][k] - imu[0][k - 1])
            prior = pose2.compose(local[k - 1], step)
        else:
            prior = pose.copy()
        pts = pts_all[k][:, :2]
        if deskew and k > 0:
            # motion during the scan (Cartographer unwarps with its pose extrapolator): constant velocity
            # of the predicted step, each point moved to the pose at its firing time
            dt = max(float(log_.t_ns[k] - log_.t_ns[k - 1]) * 1e-9, 1e-3)
            f = pts_all[k][:, 2] / dt
            step_k = pose2.between(local[k - 1], prior)
            pts = pose2.act_each(step_k[None] * f[:, None], pts)
        tilted = imu is not None and imu[1][k] > cfg.max_tilt_deg
        poor = False
        if len(pts) < 3:
            empty += 1
            est = prior
        elif tilted:
            rejected_tilt += 1
            est = prior
        else:
            est, score = slam.match(pts, prior)
            if k > 0 and slam.active and len(recent) >= 20:
                med = float(np.median(recent))
                if score < cfg.matcher.recovery_score_ratio * med:
                    found = slam.relocalise(pts, prior, score, med, full_window=bool(wide_ok[k]))
                    if found is not None:
                        est, score = found
                        recovered += 1
                    else:
                        # still far below the run: not inserted, so it cannot spoil the submap
                        poor = True
                        poor_scans += 1
            if k > 0 and slam.active:
                recent.append(score)
                if len(recent) > 100:
                    recent.pop(0)
                slam.scores.append(score)
                match_score[k] = score
        if not np.isfinite(est).all():
            raise EstimatorError(
                f"{log_.source}: scan {k}: the scan matcher returned a non-finite pose"
            )
        local[k] = est
        if k > 0:
            vel = pose2.between(local[k - 1], est)
        if not tilted and not poor and len(pts) >= 3 and slam.wants_node(est, t_s[k]):
            slam.add_node(k, est, pts, t_s[k])
        node_of_scan[k] = max(len(slam.node_local) - 1, 0)
        if progress is not None:
            progress(k)
    total_local = time.perf_counter() - t0
    if not slam.node_local:
        raise EstimatorError(f"{log_.source}: no scan had enough valid readings to map")
    t_wait = time.perf_counter()
    slam.collect_loops(wait=True)
    slam.timing["loop_wait"] = time.perf_counter() - t_wait
    if cfg.loop.enabled:
        slam.vet_candidates(final=True)
        if cfg.loop.peaks_per_match > 0:
            slam.vet_peaks(final=True)
    if cfg.loop.enabled and slam.loops:
        slam.optimise()
    # loop_search: the matching's own time (on the worker thread when in the background)
    slam.timing["local"] = total_local - slam.main_loop_time - slam.timing["optimise"]
    if not slam.in_background:
        slam.timing["local"] -= slam.timing["loop_search"]
    NL = np.array(slam.node_local)
    NG = np.array(slam.node_global)
    # every scan: the optimised pose of its node times the local motion since that node
    j = node_of_scan
    glob = pose2.compose(NG[j], pose2.between(NL[j], local))
    first_node_scan = slam.node_scan[0]
    glob[:first_node_scan] = local[:first_node_scan]
    warnings = dict(log_.warnings)
    if empty:
        warnings["scans with fewer than 3 valid readings (pose from the prior)"] = empty
    if recovered:
        warnings["scans re-localised by the wide search (the prior was off)"] = recovered
    if poor_scans:
        warnings["scans far below the run's match score, not inserted"] = poor_scans
    if rejected_tilt:
        warnings["scans rejected by the IMU tilt (pose from the prior)"] = rejected_tilt
    return Slam2dResult(
        log_.t_ns.copy(), glob, local, None if log_.odom_xy_yaw is None else log_.odom_xy_yaw.copy(),
        np.array(slam.node_scan), len(slam.submaps), slam.loops, slam.loops_searched, dict(slam.timing),
        warnings, float(np.mean(slam.scores)) if slam.scores else 0.0, cfg, log_.source, rejected_tilt,
        match_score=match_score,
        extra={f"loop_{k}": float(v) for k, v in slam.loop_stats.items()},
    )  # fmt: skip


def render_map(
    log_: LaserLog, poses_xy_yaw: FloatArray, cfg: Slam2dConfig, stride: int = 1
) -> ProbabilityGrid:
    """All scans (every ``stride``-th) inserted at the given poses into one probability grid (scans
    unwarped with the motion between consecutive poses when the log gives beam times)."""
    P = np.asarray(poses_xy_yaw)
    pts_all = scan_points(log_, cfg, with_time=True)
    for k in range(len(P)):
        q = pts_all[k]
        if log_.time_increment > 0 and k > 0:
            dt = max(float(log_.t_ns[k] - log_.t_ns[k - 1]) * 1e-9, 1e-3)
            step_k = pose2.between(P[k - 1], P[k])
            pts_all[k] = pose2.act_each(step_k[None] * (q[:, 2] / dt)[:, None], q[:, :2])
        else:
            pts_all[k] = q[:, :2]
    grid = ProbabilityGrid(GridParams(resolution=cfg.map_resolution), P[0, :2], 10.0)
    allp = np.concatenate(
        [pose2.act(P[k], pts_all[k]) for k in range(0, len(P), stride)] or [P[:1, :2]]
    )
    grid.ensure_contains(
        np.minimum(allp.min(axis=0), P[:, :2].min(axis=0)),
        np.maximum(allp.max(axis=0), P[:, :2].max(axis=0)),
    )
    for k in range(0, len(P), stride):
        if len(pts_all[k]):
            grid.insert(pose2.act(P[k], log_.T_b_l[None, :2])[0], pose2.act(P[k], pts_all[k]))
    return grid
