"""A 2D SLAM run scored against a reference: a CARMEN log of corrected poses (Kümmerle 2009 relations
between consecutive corrected scans, scans associated by their readings) or a trajectory file (ATE/RPE as
evo computes them). The raw wheel odometry is scored the same way as the baseline."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.eval.mapquality import align_se2, transform
from imuslam.eval.metrics import evaluate
from imuslam.eval.relations import (
    associate_by_ranges,
    consecutive_relations,
    loop_relations,
    relation_error,
    separation_relations,
)
from imuslam.io.laserlog import LaserLog
from imuslam.io.trajectory import Trajectory, read_trajectory

FloatArray = NDArray[np.float64]


def planar_trajectory(t_ns: NDArray[np.int64], xy_yaw: FloatArray, source: str) -> Trajectory:
    c, s = np.cos(xy_yaw[:, 2]), np.sin(xy_yaw[:, 2])
    R = np.zeros((len(xy_yaw), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    p = np.column_stack([xy_yaw[:, :2], np.zeros(len(xy_yaw))])
    return Trajectory(t_ns, p, R, source)


def is_carmen(path: Path) -> bool:
    n = path.name.lower()
    return any(
        n.endswith(e) for e in (".clf", ".log", ".clf.gz", ".log.gz", ".clf.bz2", ".log.bz2")
    )


# relation sets at several scales (Kümmerle 2009's metric holds for any set of relations), chosen before
# any result was seen: by separation along the reference path (1 m is the consecutive corrected scans)
# and loop relations (poses within 2 m of each other, more than 60 s apart)
SEPARATIONS_M = (10.0, 50.0)
LOOP_RADIUS_M = 2.0
LOOP_MIN_DT_S = 60.0


def relations_against_corrected(
    gt: str | Path, log_: LaserLog, estimates: dict[str, FloatArray], relation_sets: bool = False
) -> dict[str, Any]:
    """Kümmerle 2009 relation errors of each estimate (N, 3) against a corrected CARMEN log, and its
    global consistency: the ATE (RMSE and largest, m) of the associated poses after the SE(2) alignment
    that fits them best (a loop left open shows here, not in the local relations). With
    ``relation_sets``: ``out["sets"][set][estimate]``, the relation errors of the sets ``"10m"``,
    ``"50m"`` (:data:`SEPARATIONS_M` along the reference path) and ``"loop"`` (within
    :data:`LOOP_RADIUS_M`, more than :data:`LOOP_MIN_DT_S` apart); a set with no relation is left out."""
    from imuslam.io.carmen import read_carmen

    ref = read_carmen(gt)
    ri, ei = associate_by_ranges(ref.laser.ranges, log_.ranges)
    if len(ri) < 2:
        raise InputError(
            f"{gt}: fewer than 2 of its scans have the readings of a scan of {log_.source}"
        )
    i, j = consecutive_relations(len(ri))
    refp = ref.laser_pose_xy_yaw[ri]
    out: dict[str, Any] = {
        "reference": str(gt),
        "associated_scans": len(ri),
        "reference_scans": len(ref.laser),
    }
    for name, est in estimates.items():
        out[name] = asdict(relation_error(est[ei], refp, i, j))
        T = align_se2(est[ei, :2], refp[:, :2])
        d = np.hypot(*(transform(T, est[ei])[:, :2] - refp[:, :2]).T)
        out[name]["ate_rmse_m"] = float(np.sqrt(np.mean(d**2)))
        out[name]["ate_max_m"] = float(d.max())
    if relation_sets:
        sets: dict[str, tuple[NDArray[np.int64], NDArray[np.int64]]] = {
            f"{d:.0f}m": separation_relations(refp, d) for d in SEPARATIONS_M
        }
        t_s = (log_.t_ns[ei] - log_.t_ns[0]) * 1e-9
        sets["loop"] = loop_relations(refp, t_s, LOOP_RADIUS_M, LOOP_MIN_DT_S)
        out["sets"] = {
            k: {
                name: asdict(relation_error(est[ei], refp, a, b)) for name, est in estimates.items()
            }
            for k, (a, b) in sets.items()
            if len(a)
        }
    return out


def ate_rpe(
    gt: str | Path, t_ns: NDArray[np.int64], estimates: dict[str, FloatArray], fmt: str = "tum"
) -> dict[str, Any]:
    """APE (SE(3)-aligned) and RPE per metre of each planar estimate against a trajectory file."""
    ref = read_trajectory(gt, fmt)
    out: dict[str, Any] = {"reference": str(gt)}
    for name, est in estimates.items():
        res = evaluate(ref, planar_trajectory(t_ns, est, name), "se3", 1.0, "m", max_diff_s=0.02)
        out[name] = {"ate_rmse_m": res.ape_trans.rmse, "ate_max_m": res.ape_trans.max,
                     "rpe_trans_rmse_m_per_m": res.rpe_trans.rmse, "rpe_rot_rmse_deg_per_m": res.rpe_rot_deg.rmse,
                     "poses": res.n_pairs}  # fmt: skip
    return out


def score_run(
    gt: str | Path, log_: LaserLog, t_ns: NDArray[np.int64], slam_xy_yaw: FloatArray
) -> dict[str, Any]:
    """Metrics of the SLAM estimate and of the raw odometry (if any) against ``gt``."""
    est = {"slam": slam_xy_yaw}
    if log_.odom_xy_yaw is not None:
        est["odometry"] = log_.odom_xy_yaw
    p = Path(gt)
    if is_carmen(p):
        return {
            "kind": "kuemmerle2009_relations",
            **relations_against_corrected(p, log_, est, relation_sets=True),
        }
    return {"kind": "ate_rpe", **ate_rpe(p, t_ns, est)}


def reference_in_map(
    gt: str | Path, log_: LaserLog, t_ns: NDArray[np.int64], slam_xy_yaw: FloatArray
) -> FloatArray:
    """The reference's positions (M, 2) in the SLAM map's frame, for drawing: the poses associated with
    the run's scans (by readings for a corrected CARMEN log, by stamps within 0.02 s for a trajectory)
    moved by the SE(2) alignment that fits them onto the SLAM poses best (Umeyama 1991, no scale)."""
    from imuslam.eval.associate import match_stamps

    p = Path(gt)
    if is_carmen(p):
        from imuslam.io.carmen import read_carmen

        carmen = read_carmen(p)
        ri, ei = associate_by_ranges(carmen.laser.ranges, log_.ranges)
        refp = carmen.laser_pose_xy_yaw[ri]
    else:
        ref = read_trajectory(p, "tum")
        ei, ri = match_stamps(
            t_ns.astype(np.float64) * 1e-9, ref.t_ns.astype(np.float64) * 1e-9, 0.02
        )
        yaw = np.arctan2(ref.R_w_b[ri, 1, 0], ref.R_w_b[ri, 0, 0])
        refp = np.column_stack([ref.p_w[ri, :2], yaw])
    if len(ri) < 2:
        return np.zeros((0, 2))
    T = align_se2(refp[:, :2], slam_xy_yaw[ei, :2])
    return transform(T, refp)[:, :2]
