"""ATE and RPE with the definitions of evo (Grupp, "evo: Python package for the evaluation of odometry and
SLAM", 2017) and the KITTI odometry benchmark (Geiger et al., CVPR 2012), vectorised.

APE: ``E_i = P_ref,i^-1 P_est,i``; translation error ``|t(E_i)|`` = ``|p_est - p_ref|``, rotation error
the angle of ``R(E_i)``. RPE over pairs (i, j): ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``, Q the reference.
Pairs by frames: i = 0, d, 2d, ... consecutive; by distance: each pair spans ``delta`` metres of the
estimate's path (evo's rule). KITTI drift: for every start frame (step 10) and segment length, the
relative pose error over the first frame that lies that far along the reference path, in % of length.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, is_dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.eval.align import AlignMethod, align, apply
from imuslam.eval.associate import associate
from imuslam.geometry.quaternion import quat_from_matrix
from imuslam.interfaces.trajectory import Trajectory

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


@dataclass
class Stats:
    """Statistics of an error series (std is the population std, as evo)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    n: int

    @classmethod
    def of(cls, e: FloatArray) -> Stats:
        e = np.asarray(e, dtype=float)
        return cls(
            float(np.sqrt(np.mean(e**2))), float(np.mean(e)), float(np.median(e)), float(np.std(e)),
            float(np.min(e)), float(np.max(e)), float(np.sum(e**2)), int(e.size),
        )  # fmt: skip


def rotation_angle_deg(R: FloatArray) -> FloatArray:
    """Angle (N,) in degrees of rotation matrices (N, 3, 3), as evo computes it with scipy: the matrix goes
    to the nearest unit quaternion by Shepperd's method (which projects a matrix slightly off SO(3)), and
    the angle is ``2 atan2(|q_xyz|, |q_w|)``. Written with numpy so ``imuslam eval`` needs no scipy."""
    q = quat_from_matrix(R)
    return np.rad2deg(2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0])))


def ape(ref: Trajectory, est: Trajectory) -> tuple[FloatArray, FloatArray]:
    """Per-pose translation error (m) and rotation error (deg) of associated, aligned trajectories."""
    e_t = np.linalg.norm(est.p_w - ref.p_w, axis=1)
    e_r = rotation_angle_deg(np.swapaxes(ref.R_w_b, 1, 2) @ est.R_w_b)
    return e_t, e_r


def rpe_pairs(est: Trajectory, delta: float, unit: str) -> tuple[IntArray, IntArray]:
    """Index pairs (i, j) for the RPE: consecutive pairs ``delta`` frames or metres apart (evo's rule)."""
    if not (np.isfinite(delta) and delta > 0):
        raise ValueError(f"RPE delta {delta}; expected a positive number of {unit}")
    if unit == "frames":
        if delta != int(delta):
            raise InputError(f"RPE delta {delta} frames; expected a whole number of frames")
        ids = np.arange(0, len(est), int(delta), dtype=np.int64)
    elif unit == "m":
        from imuslam.eval.kernels import path_ids  # numba loads only for RPE in metres

        ids = path_ids(np.ascontiguousarray(est.p_w), float(delta))
    else:
        raise ValueError(f"RPE unit '{unit}'; expected frames or m")
    if len(ids) < 2:
        raise InputError(
            f"RPE with delta {delta} {unit} gives no pair in {len(est)} poses; use a smaller delta"
        )
    return ids[:-1], ids[1:]


def _relative(
    p: FloatArray, R: FloatArray, i: IntArray, j: IntArray
) -> tuple[FloatArray, FloatArray]:
    Ri_t = np.swapaxes(R[i], 1, 2)
    return Ri_t @ R[j], (Ri_t @ (p[j] - p[i])[:, :, None])[:, :, 0]


def rpe(
    ref: Trajectory, est: Trajectory, i: IntArray, j: IntArray
) -> tuple[FloatArray, FloatArray]:
    """Translation (m) and rotation (deg) of ``(Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` for each pair."""
    Rq, tq = _relative(ref.p_w, ref.R_w_b, i, j)
    Rp, tp = _relative(est.p_w, est.R_w_b, i, j)
    Rq_t = np.swapaxes(Rq, 1, 2)
    R_e = Rq_t @ Rp
    t_e = (Rq_t @ (tp - tq)[:, :, None])[:, :, 0]
    return np.linalg.norm(t_e, axis=1), rotation_angle_deg(R_e)


def kitti_drift(
    ref: Trajectory, est: Trajectory, lengths: tuple[float, ...] = KITTI_LENGTHS, step: int = 10
) -> dict[float, tuple[float, float, int]]:
    """KITTI segment errors: length -> (translation drift %, rotation drift deg/m, segments).

    As the KITTI odometry devkit (evaluate_odometry.cpp): distances along the reference; from every
    ``step``-th frame the segment ends at the first frame whose distance exceeds the start's by more than
    L (``lastFrameFromSegmentLength``: strictly greater); the error pose is (P_i^-1 P_j)^-1 (Q_i^-1 Q_j),
    its translation norm and rotation angle divided by L, averaged over the segments; reported as % and
    deg/m as the devkit's summary."""
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref.p_w, axis=0), axis=1))])
    starts = np.arange(0, len(ref), step)
    out: dict[float, tuple[float, float, int]] = {}
    for L in lengths:
        j = np.searchsorted(dist, dist[starts] + L, side="right")
        ok = j < len(ref)
        if not ok.any():
            continue
        i_, j_ = starts[ok].astype(np.int64), j[ok].astype(np.int64)
        et, er = rpe(ref, est, i_, j_)
        out[L] = (float(np.mean(et / L) * 100), float(np.mean(er / L)), int(ok.sum()))
    return out


@dataclass
class EvalResult:
    """Metrics of an estimate against a reference, with the trajectories they were computed on (as evo's
    ``Result``: stats, the error series and the associated reference / aligned estimate)."""

    align: str
    scale: float
    n_pairs: int
    path_length_m: float
    ape_trans: Stats
    ape_rot_deg: Stats
    rpe_delta: float
    rpe_unit: str
    rpe_trans: Stats
    rpe_rot_deg: Stats
    kitti: dict[float, tuple[float, float, int]] = field(default_factory=dict)
    ape_trans_series: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    t_s: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    reference: Trajectory | None = field(default=None, repr=False)
    estimate_aligned: Trajectory | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The metrics (no series, no trajectories), as metrics.json holds them."""
        skip = ("ape_trans_series", "t_s", "reference", "estimate_aligned")
        d = {
            f.name: asdict(v) if is_dataclass(v) and not isinstance(v, type) else v
            for f in fields(self)
            if f.name not in skip
            for v in (getattr(self, f.name),)
        }
        d["kitti"] = {
            f"{k:g}": {"trans_pct": v[0], "rot_deg_per_m": v[1], "segments": v[2]}
            for k, v in self.kitti.items()
        }
        if self.kitti:
            d["kitti_mean_trans_pct"] = float(np.mean([v[0] for v in self.kitti.values()]))
        return d


def evaluate(
    ref: Trajectory,
    est: Trajectory,
    align_method: AlignMethod = "se3",
    rpe_delta: float = 1.0,
    rpe_unit: str = "frames",
    max_diff_s: float = 0.01,
    kitti_lengths: tuple[float, ...] | None = None,
    by_index: bool = False,
) -> EvalResult:
    """Associate (or pair by index), align, and compute APE, RPE and, optionally, KITTI drift.

    Returns the result, which holds the associated reference and the aligned estimate.
    """
    if by_index:
        if len(ref) != len(est):
            raise InputError(
                f"{est.source}: {len(est)} poses against {len(ref)} in {ref.source}; no time stamps to associate"
            )
        r, e = ref, est
    else:
        r, e = associate(ref, est, max_diff_s)
    if len(r) < 3:
        raise InputError(f"{est.source}: {len(r)} associated poses; at least 3 are needed")
    s, R, t = align(r, e, align_method)
    ea = apply(e, s, R, t)
    et, er = ape(r, ea)
    i, j = rpe_pairs(ea, rpe_delta, rpe_unit)
    rt, rr = rpe(r, ea, i, j)
    kd = kitti_drift(r, ea, kitti_lengths) if kitti_lengths else {}
    res = EvalResult(
        align_method, s, len(r), r.path_length, Stats.of(et), Stats.of(er), rpe_delta, rpe_unit,
        Stats.of(rt), Stats.of(rr), kd, et, r.t_s - r.t_s[0], r, ea,
    )  # fmt: skip
    return res
