"""K-fold cross-validation of a calibration over the static poses of its log.

The poses are those of the score (``imu/score.py``: fixed detector settings, independent of the
calibration). Pose ``i`` falls in fold ``i mod k``, so each fold's held-out poses are spread over the
session. For each fold the calibration is refitted without the held-out poses: every static interval of
the fit that overlaps a held-out pose is dropped, with the rotations to and from it. The refitted
calibration then scores the held-out poses (gravity-norm error) and every pair of consecutive poses with
a held-out end (gyro-predicted gravity-direction error). A pair is scored once per held-out end, so by
two different refits. The result says how well the method predicts poses it did not see, where the fit
residual only says how well it explains those it did.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.imu.model import ImuCalibration
from imuslam.imu.score import detect_poses, pose_errors, rms, worst
from imuslam.interfaces.imu import ImuLog, InputError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class CrossValidation:
    """Held-out errors of a k-fold cross-validation.

    poses: (K, 2) the score's static poses; fold: (K,) fold of each pose.
    norm_error: (K,) held-out gravity-norm error per pose, m/s^2.
    direction_error_deg: (M,) held-out gravity-direction error per (pair, held-out end), deg.
    pair: (M,) index of the pair (poses pair, pair + 1) of each direction error.
    """

    method: str
    k_folds: int
    poses: IntArray
    fold: IntArray
    norm_error: FloatArray
    direction_error_deg: FloatArray
    pair: IntArray
    fit_norm_rms: float = float("nan")  # the full calibration on the same poses (in-sample), m/s^2
    fit_direction_rms_deg: float = float("nan")
    # (K,) held-out gravity-norm error with each fold's accelerometer bias drift (when its fit kept one)
    # applied at the pose's time: the in-session prediction of a drift-aware fit. Equal to norm_error
    # where no drift was kept. A calibration file keeps only the bias at the reference time, so this is
    # not what the calibration delivers on a later log.
    norm_error_in_session: FloatArray | None = None
    # each fold's refitted calibration (fold f's at index f)
    fold_calibrations: list[ImuCalibration] = field(default_factory=list)

    @property
    def norm_rms_in_session(self) -> float:
        return rms(
            self.norm_error if self.norm_error_in_session is None else self.norm_error_in_session
        )

    @property
    def norm_rms(self) -> float:
        return rms(self.norm_error)

    @property
    def norm_worst(self) -> float:
        return worst(self.norm_error)

    @property
    def direction_rms_deg(self) -> float:
        return rms(self.direction_error_deg)

    @property
    def direction_worst_deg(self) -> float:
        return worst(self.direction_error_deg)


def _overlaps(iv: IntArray, held: IntArray) -> NDArray[np.bool_]:
    """(len(iv),) whether each interval [s, e) overlaps any held-out pose [s, e)."""
    if len(held) == 0:
        return np.zeros(len(iv), dtype=bool)
    return np.any(
        (iv[:, 0][:, None] < held[:, 1][None, :]) & (iv[:, 1][:, None] > held[:, 0][None, :]),
        axis=1,
    )


def cross_validate(
    log: ImuLog,
    config: CalibrationConfig,
    intervals: IntArray,
    k_folds: int = 5,
    calibration: ImuCalibration | None = None,
) -> CrossValidation:
    """K-fold cross-validation of ``config``'s method on ``log``.

    intervals: (L, 2) the static intervals the full calibration used (its threshold sweep's choice);
        each fold refits on those that do not overlap its held-out poses.
    calibration: the calibration fitted on all poses, whose in-sample score is recorded beside.
    """
    if k_folds < 2:
        raise InputError(f"cross-validation needs at least 2 folds, got {k_folds}")
    poses = detect_poses(log, config.t_init_s)
    K = len(poses)
    if K < 2 * k_folds:
        raise InputError(
            f"{log.source}: {K} static poses are too few for {k_folds}-fold cross-validation"
        )
    fold = np.arange(K) % k_folds
    norm = np.full(K, np.nan)
    norm_sess = np.full(K, np.nan)
    t_pose = log.t_s[(poses[:, 0] + poses[:, 1]) // 2]
    dirs: list[FloatArray] = []
    pair_ids: list[IntArray] = []
    fold_cals: list[ImuCalibration] = []
    iv = np.asarray(intervals, dtype=np.int64)
    for f in range(k_folds):
        out = _overlaps(iv, poses[fold == f])
        kept = np.flatnonzero(~out)
        pair_ok = np.diff(kept) == 1  # consecutive in the full set: no held-out pose between them
        res = calibrate(log, config, intervals=iv[kept], pair_ok=pair_ok)
        fold_cals.append(res.calibration)
        pe = pose_errors(log, res.calibration, poses, config.g)
        norm[fold == f] = pe.norm_error[fold == f]
        norm_sess[fold == f] = pe.norm_error[fold == f]
        rate = res.calibration.notes.get("accel_bias_drift_per_s")
        if rate is not None:
            held = np.flatnonzero(fold == f)
            sign = 1.0 if res.calibration.accel.bias_sign == "plus" else -1.0
            t_ref = float(res.calibration.notes["accel_bias_drift_t_ref_s"])
            raw = np.stack([log.accel[s:e].mean(axis=0) for s, e in poses[held]])
            # the fit's model: a_O = T K (a_S + sign (b + rate (t - t_ref)))
            raw = raw + sign * np.outer(t_pose[held] - t_ref, np.asarray(rate))
            norm_sess[held] = np.linalg.norm(res.calibration.correct_accel(raw), axis=1) - config.g
        touched = np.flatnonzero((fold[:-1] == f) | (fold[1:] == f))
        dirs.append(pe.direction_error_deg[touched])
        pair_ids.append(touched)
    fit = None if calibration is None else pose_errors(log, calibration, poses, config.g)
    return CrossValidation(
        config.method,
        k_folds,
        poses,
        fold,
        norm,
        np.concatenate(dirs),
        np.concatenate(pair_ids).astype(np.int64),
        rms(fit.norm_error) if fit is not None else float("nan"),
        rms(fit.direction_error_deg) if fit is not None else float("nan"),
        norm_sess,
        fold_cals,
    )
