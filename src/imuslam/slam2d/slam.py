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

This module is the estimator (``Slam2d``: ``add_scan`` per scan, then ``finish``); ``pipeline.py`` drives
it over a log, ``config.py`` holds its settings. Poses are [x, y, theta] of the body (odometry frame) in the map frame; the first scan is at the origin.
"""

from __future__ import annotations

import bisect
import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import EstimatorError
from imuslam.slam2d import pose2
from imuslam.slam2d.config import Slam2dConfig
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
from imuslam.slam2d.records import LoopConstraint

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)


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
        # per scan (add_scan): the local-SLAM pose, the node it belongs to, its match score (NaN where
        # not matched); the last scores for the running median; what happened to scans not mapped
        self.scan_local: list[FloatArray] = []
        self.scan_node: list[int] = []
        self.scan_score: list[float] = []
        self._recent: list[float] = []
        self._vel = np.zeros(3)  # last local step (the constant-velocity model without odometry)
        self.counts = {"empty": 0, "recovered": 0, "poor": 0, "tilt": 0}
        self._t_first_scan: float | None = None

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

    def add_scan(
        self,
        pts_t: FloatArray,
        t_s: float,
        step: FloatArray | None = None,
        dyaw: float | None = None,
        dt_s: float | None = None,
        tilted: bool = False,
        wide: bool = True,
    ) -> FloatArray:
        """Track one scan and insert it when it moved enough; returns its local-SLAM pose (3,).

        pts_t: (P, 3) hit points in the body frame with their firing time after the scan's stamp, s;
        t_s: the scan's time since the first, s; step: the body's motion since the last scan from the
        wheel odometry (None: the last local step, a constant velocity); dyaw: the IMU's yaw change
        since the last scan (replaces the step's rotation); dt_s: the time since the last scan, s, when
        the scan is unwarped (None: it is not); tilted: the IMU reports a tilt above ``max_tilt_deg`` (the
        scan is not matched); wide: a re-localisation gets the full angular window."""
        if self._t_first_scan is None:
            self._t_first_scan = time.perf_counter()
        k = len(self.scan_local)
        if k > 0:
            s = step.copy() if step is not None else self._vel.copy()
            if dyaw is not None:
                s[2] = dyaw
            prior = pose2.compose(self.scan_local[k - 1], s)
        else:
            prior = np.zeros(3)
        pts = pts_t[:, :2]
        if dt_s is not None and k > 0:
            # motion during the scan (Cartographer unwarps with its pose extrapolator): constant velocity
            # of the predicted step, each point moved to the pose at its firing time
            f = pts_t[:, 2] / dt_s
            step_k = pose2.between(self.scan_local[k - 1], prior)
            pts = pose2.act_each(step_k[None] * f[:, None], pts)
        poor = False
        score_k = float("nan")
        if len(pts) < 3:
            self.counts["empty"] += 1
            est = prior
        elif tilted:
            self.counts["tilt"] += 1
            est = prior
        else:
            est, score = self.match(pts, prior)
            recent = self._recent
            if k > 0 and self.active and len(recent) >= 20:
                med = float(np.median(recent))
                if score < self.cfg.matcher.recovery_score_ratio * med:
                    found = self.relocalise(pts, prior, score, med, full_window=wide)
                    if found is not None:
                        est, score = found
                        self.counts["recovered"] += 1
                    else:
                        # still far below the run: not inserted, so it cannot spoil the submap
                        poor = True
                        self.counts["poor"] += 1
            if k > 0 and self.active:
                recent.append(score)
                if len(recent) > 100:
                    recent.pop(0)
                self.scores.append(score)
                score_k = score
        if not np.isfinite(est).all():
            raise EstimatorError(f"scan {k}: the scan matcher returned a non-finite pose")
        if k > 0:
            self._vel = pose2.between(self.scan_local[k - 1], est)
        self.scan_local.append(est)
        self.scan_score.append(score_k)
        if not tilted and not poor and len(pts) >= 3 and self.wants_node(est, t_s):
            self.add_node(k, est, pts, t_s)
        self.scan_node.append(max(len(self.node_local) - 1, 0))
        return est

    def finish(self) -> None:
        """After the last scan: wait for the loop searches, decide their candidates, optimise once."""
        if not self.node_local:
            raise EstimatorError("no scan had enough valid readings to map")
        total_local = time.perf_counter() - (self._t_first_scan or time.perf_counter())
        cfg = self.cfg
        t_wait = time.perf_counter()
        self.collect_loops(wait=True)
        self.timing["loop_wait"] = time.perf_counter() - t_wait
        if cfg.loop.enabled:
            self.vet_candidates(final=True)
            if cfg.loop.peaks_per_match > 0:
                self.vet_peaks(final=True)
        if cfg.loop.enabled and self.loops:
            self.optimise()
        # loop_search: the matching's own time (on the worker thread when in the background)
        self.timing["local"] = total_local - self.main_loop_time - self.timing["optimise"]
        if not self.in_background:
            self.timing["local"] -= self.timing["loop_search"]

    def scan_poses(self) -> FloatArray:
        """(N, 3) every scan's map-frame pose: the optimised pose of its node times the local motion
        since that node (scans before the first node keep their local pose)."""
        NL = np.array(self.node_local)
        NG = np.array(self.node_global)
        local = np.array(self.scan_local)
        j = np.array(self.scan_node, np.int64)
        glob = pose2.compose(NG[j], pose2.between(NL[j], local))
        first_node_scan = self.node_scan[0]
        glob[:first_node_scan] = local[:first_node_scan]
        return glob

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
