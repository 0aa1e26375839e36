"""The 2D SLAM's configuration (``imuslam map2d --config``; written beside every result as config.yaml):
local scan matching (Cartographer's names where they exist), loop closure and the pose graph."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class MatcherConfig(BaseModel):
    """Local scan matching (Cartographer's names where they exist)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    use_correlative: bool = True
    # the local search's windows are bounded: its cost grows with their area (1 km never ended)
    linear_window: float = Field(
        0.15, ge=0, le=1.0, description="correlative search half-window, m"
    )
    angular_window_deg: float = Field(
        10.0, ge=0, le=180.0, description="correlative search half-window, deg"
    )
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
    recovery_linear_window: float = Field(
        1.0, gt=0, le=5.0, description="wide search half-window, m"
    )
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

    @model_validator(mode="after")
    def _ranges(self) -> Slam2dConfig:
        if not self.min_range < self.max_range:
            raise ValueError(
                f"min_range {self.min_range:g} m must be below max_range {self.max_range:g} m "
                "(no reading would be used)"
            )
        return self
