"""What the 2D SLAM returns: the result of a run and its loop constraints."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.slam2d.config import Slam2dConfig

FloatArray = NDArray[np.float64]


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
