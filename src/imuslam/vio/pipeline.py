"""Stereo VO + IMU fusion over a dataset: VO per frame pair, a VO rate and a VO velocity update at each
pair's mid-time (the velocity conditioned on the rate: one motion fit gives both, with strongly correlated
errors), and the non-holonomic pseudo-measurements at ``nhc_rate_hz``; beside it, VO alone (relative
poses chained) and the IMU alone (the core's strapdown from the same initial state) for comparison.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.geometry.se3 import exp as se3_exp
from imuslam.ins.coarse import level_rotation
from imuslam.ins.core import (
    ErrorLayout,
    InsState,
    integrate_nominal,
)
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.sources import StereoSource
from imuslam.io.trajectory import Trajectory
from imuslam.vio.config import VioConfig
from imuslam.vio.covcal import apply_vo_cov_correction
from imuslam.vio.filter import GateStats, VioFilter, VoFrame
from imuslam.vio.frontend import StereoVO, VoConfig, VoMeasurement, VoStats
from imuslam.vio.measurements import (
    twist_velocity,
)

FloatArray = NDArray[np.float64]
U8Image = NDArray[np.uint8]
log_ = logging.getLogger(__name__)


@dataclass
class VioResult:
    """Fused, VO-only and IMU-only trajectories (body poses), statistics and the per-update records."""

    fused: Trajectory
    vo: Trajectory
    imu: Trajectory
    gating: dict[str, GateStats]
    vo_stats: VoStats
    frames: dict[str, int]
    outliers: dict[str, int]
    bias_t_s: FloatArray
    bias: FloatArray
    bias_std: FloatArray
    config: VioConfig
    vo_measurements: list[VoMeasurement] = field(default_factory=list, repr=False)
    corrupted: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool), repr=False)
    vel_accepted: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool), repr=False)
    vo_scale: FloatArray = field(default_factory=lambda: np.ones(2), repr=False)
    """the online VO covariance scales [rate, velocity] at the end (``VioConfig.vo_cov_adapt_n``)"""
    t_ref_ns: int = 0
    """the filter's time origin: ``bias_t_s`` counts seconds from it"""

    def summary(self) -> dict[str, Any]:
        out = {
            "frames": self.frames,
            "vo": {
                "measurements": self.vo_stats.measurements,
                "skipped_few_features": self.vo_stats.skipped_few_features,
                "skipped_few_inliers": self.vo_stats.skipped_few_inliers,
                "mean_tracked": float(np.mean(self.vo_stats.tracked))
                if self.vo_stats.tracked
                else 0.0,
                "mean_inliers": float(np.mean(self.vo_stats.inliers))
                if self.vo_stats.inliers
                else 0.0,
                # where the front end's time went, per frame (VO runs pickled before the timing
                # existed have none)
                "ms_per_frame": {
                    k: 1e3 * v / max(self.vo_stats.frames, 1)
                    for k, v in getattr(self.vo_stats, "seconds", {}).items()
                },
            },
            "gating": {k: v.summary() for k, v in self.gating.items()},
            "outliers": self.outliers,
            "final_bias": {
                "accel": self.bias[-1, :3].tolist() if len(self.bias) else None,
                "gyro": self.bias[-1, 3:].tolist() if len(self.bias) else None,
            },
        }
        if self.config.vo_cov_adapt_n:
            out["vo_cov_adapted_scale"] = {
                "rate": float(self.vo_scale[0]),
                "velocity": float(self.vo_scale[1]),
            }
        return out


def vo_cov(m: VoMeasurement, cfg: VioConfig, M: FloatArray | None = None) -> FloatArray:
    """The (6, 6) covariance of ``[omega_b, vel_b]`` the filter uses for a VO measurement (see
    ``VioConfig.vo_cov_model``), reshaped by the correction ``M`` (6, 6) (``L M L^T``, see
    :mod:`imuslam.vio.covcal`), its rate and velocity blocks scaled by ``vo_rate_cov_scale`` and
    ``vo_cov_scale``."""
    if cfg.vo_cov_model == "residual" and m.cov_fit is not None:
        cov = m.cov_fit * m.var_factor
    else:
        cov = m.cov
    if M is not None:
        cov = apply_vo_cov_correction(cov, M)
    if cfg.vo_rate_cov_scale == 1.0 and cfg.vo_cov_scale == 1.0:
        return cov
    s = np.sqrt(np.r_[[cfg.vo_rate_cov_scale] * 3, [cfg.vo_cov_scale] * 3])
    return np.asarray(cov * np.outer(s, s), dtype=np.float64)


def _correction(cfg: VioConfig) -> FloatArray | None:
    """``cfg.vo_cov_correction`` as a (6, 6) array, checked symmetric positive definite."""
    if cfg.vo_cov_correction is None:
        return None
    M = np.asarray(cfg.vo_cov_correction, dtype=float)
    if M.shape != (6, 6) or not np.all(np.isfinite(M)) or not np.allclose(M, M.T, atol=1e-9):
        raise InputError(
            f"config: vo_cov_correction has shape {M.shape}; expected a finite symmetric 6x6 matrix"
        )
    if np.linalg.eigvalsh(M).min() <= 0:
        raise InputError("config: vo_cov_correction is not positive definite")
    return M


def _check_imu_span(imu: ImuLog, t_first: int, t_last: int, source: str) -> None:
    if len(imu) < 2 or imu.t_ns[-1] <= t_first or imu.t_ns[0] >= t_last:
        raise InputError(
            f"{source}: no IMU samples in the image time span "
            f"({t_first * 1e-9:.3f}-{t_last * 1e-9:.3f} s; IMU "
            f"{imu.t_ns[0] * 1e-9 if len(imu) else float('nan'):.3f}-"
            f"{imu.t_ns[-1] * 1e-9 if len(imu) else float('nan'):.3f} s)"
        )


@dataclass
class VioFrame:
    """What an observer of the front end receives per readable stereo pair: its stamp (ns), the
    rectified left image, the tracks (``StereoVO.last_tracks``: previous features, where they were
    found, the inliers; None on a first frame) and the measurement (None: first or skipped frame)."""

    t_ns: int
    left: NDArray[np.uint8]
    tracks: tuple[FloatArray, FloatArray, NDArray[np.int64]] | None
    measurement: VoMeasurement | None


@dataclass
class VoRun:
    """The front end's output over a run, reusable by several filter configurations: per used frame its
    time and the measurement since the previous one (None: first frame or skipped), and the counts."""

    frames: list[tuple[int, VoMeasurement | None]]
    stats: VoStats
    seen: int
    unreadable: int


def compute_vo(
    data: StereoSource,
    cfg: VoConfig,
    progress: Callable[[int], None] | None = None,
    observer: Callable[[VioFrame], None] | None = None,
) -> VoRun:
    """The whole front end at once (see :class:`VoRun`); ``observer`` sees each pair's :class:`VioFrame`."""
    rect = data.rectification()
    vo = StereoVO(rect, cfg)
    frames: list[tuple[int, VoMeasurement | None]] = []
    seen = unreadable = 0
    for t_ns, left, right in data.frames():
        seen += 1
        if progress is not None:
            progress(1)
        if left is None or right is None:
            unreadable += 1
            continue
        lr, rr = rect.rectify(left, right)
        frames.append((t_ns, vo.process(t_ns, lr, rr)))
        if observer is not None:
            observer(VioFrame(t_ns, lr, vo.last_tracks, frames[-1][1]))
    return VoRun(frames, vo.stats, seen, unreadable)


def _corrupt(
    m: VoMeasurement, cfg: VioConfig, rng: np.random.Generator
) -> tuple[VoMeasurement, bool]:
    """With probability ``cfg.outlier_fraction``, ``m`` with a gross error: a rate error of a random
    direction and a norm drawn from ``cfg.outlier_rate`` (rad/s), a velocity error likewise from
    ``cfg.outlier_vel`` (m/s), and the relative pose moved by the same errors over the pair's interval
    (``T_b0_b1 exp([dw dt, dv dt])``), so that every reader of the measurement sees one failure."""
    if not rng.uniform() < cfg.outlier_fraction:
        return m, False
    dv = rng.normal(size=3)
    dw = rng.normal(size=3)
    dw = dw / np.linalg.norm(dw) * rng.uniform(*cfg.outlier_rate)
    dv = dv / np.linalg.norm(dv) * rng.uniform(*cfg.outlier_vel)
    T = m.T_b0_b1 @ se3_exp(np.concatenate([dw, dv]) * m.dt)
    return replace(m, omega_b=m.omega_b + dw, vel_b=m.vel_b + dv, T_b0_b1=T), True


def run_vio(
    data: StereoSource,
    cfg: VioConfig | None = None,
    progress: Callable[[int], None] | None = None,
    vo_run: VoRun | None = None,
    observer: Callable[[VioFrame], None] | None = None,
    imu: ImuLog | None = None,
) -> VioResult:
    """VO on every stereo pair (or the given ``vo_run``) and the EKF over the IMU (``imu``, e.g. after
    calibration, else the dataset's); ``progress(n)`` is called per frame, ``observer`` sees each pair
    the front end reads (:class:`VioFrame`)."""
    cfg = cfg or VioConfig()
    imu = (imu if imu is not None else data.imu()).to_si()
    if vo_run is None:
        vo_run = compute_vo(data, cfg.vo, progress, observer)
    rng = np.random.default_rng(cfg.outlier_seed)
    M_cov = _correction(cfg)

    filt: VioFilter | None = None
    t_ref = 0
    imu_track: Trajectory | None = None
    T_vo = np.eye(4)
    vo_t: list[int] = []
    vo_T: list[FloatArray] = []
    meas_all: list[VoMeasurement] = []
    corrupted: list[bool] = []
    batch: list[VoFrame] = []
    frames_seen = vo_run.seen
    unreadable = vo_run.unreadable
    if vo_run.frames:
        _check_imu_span(imu, vo_run.frames[0][0], vo_run.frames[-1][0], data.source)
    T_prev_rel = np.eye(4)

    for t_ns, m in vo_run.frames:
        # corrupt a share of the measurements after the first (simulation studies of the gate): VO alone
        # chains the same corrupted motion the filter reads
        bad = False
        if m is not None and filt is not None and cfg.outlier_fraction > 0:
            m, bad = _corrupt(m, cfg, rng)
        # VO alone: chain the relative poses (a skipped pair keeps the last motion)
        if m is not None:
            T_prev_rel = m.T_b0_b1
        if vo_t:
            T_vo = T_vo @ T_prev_rel
        vo_t.append(t_ns)
        vo_T.append(T_vo.copy())
        if m is None:
            continue
        if cfg.vo_bias is not None:  # the learnt steady VO error, before any use of the measurement
            b = np.asarray(cfg.vo_bias, dtype=float)
            m = replace(m, omega_b=m.omega_b - b[:3], vel_b=m.vel_b - b[3:])
        if filt is None:
            # initial state at the first pair's mid-time: roll and pitch from the mean specific force,
            # yaw zero, velocity from the first VO velocity, the gyro bias from the first VO rate
            # against the mean gyro over the pair (a MEMS gyro's bias can be several deg/s, far outside
            # any gate around zero), the accelerometer bias zero
            t_ref = m.t0_ns
            t_imu = (imu.t_ns - t_ref) * 1e-9
            t_mid = (m.t_mid_ns - t_ref) * 1e-9
            win = (t_imu >= t_mid - cfg.level_window_s / 2) & (
                t_imu <= t_mid + cfg.level_window_s / 2
            )
            if win.sum() < 2:
                _check_imu_span(imu, m.t0_ns, m.t1_ns, data.source)
                win = np.abs(t_imu - t_mid) == np.min(np.abs(t_imu - t_mid))
            R0 = level_rotation(imu.accel[win])
            v0 = R0 @ m.vel_b
            i0, i1 = np.searchsorted(imu.t_ns, [m.t0_ns, m.t1_ns])
            bg0 = (imu.gyro[i0:i1].mean(axis=0) - m.omega_b) if i1 > i0 else np.zeros(3)
            x0 = InsState(np.zeros(3), v0, R0, np.zeros(3), bg0, np.array([0.0, 0.0, -cfg.g]))
            lay = ErrorLayout.full()
            P0 = np.zeros((lay.dim, lay.dim))
            P0[lay.TH, lay.TH] = np.diag([cfg.init_std_theta**2] * 2 + [cfg.init_std_yaw**2])
            P0[lay.P, lay.P] = np.eye(3) * 1e-8
            P0[lay.V, lay.V] = R0 @ m.cov[3:, 3:] @ R0.T + np.eye(3) * 1e-4
            P0[lay.BA, lay.BA] = np.eye(3) * cfg.init_std_ba**2
            P0[lay.BG, lay.BG] = m.cov[:3, :3] + np.eye(3) * (
                cfg.init_std_bg**2 + cfg.noise.gyro**2 / max(m.dt, 1e-3)
            )
            filt = VioFilter(imu, t_ref, x0, P0, t_mid, cfg)
            filt.mark()
            # the IMU alone from the same state
            sel = (t_imu > t_mid) & (imu.t_ns <= vo_run.frames[-1][0] + 50_000_000)
            a0, g0 = filt.sample_at(t_mid)
            ts = np.concatenate([[t_mid], t_imu[sel]])
            acc = np.concatenate([a0[None], imu.accel[sel]])
            gyr = np.concatenate([g0[None], imu.gyro[sel]])
            Pi, _, Ri = integrate_nominal(
                acc, gyr, np.diff(ts), x0.p_n, x0.v_n, R0, np.zeros(3), bg0, x0.g_n, np.zeros(3)
            )
            imu_track = Trajectory(t_ref + np.round(ts * 1e9).astype(np.int64), Pi, Ri, "IMU only")
            continue
        cov = vo_cov(m, cfg, M_cov)
        vel_b = m.vel_b
        if cfg.vo_model == "rate" and cfg.vo_velocity_model == "twist":
            vel_b, cov = twist_velocity(m.omega_b, m.vel_b, cov, m.dt)
        batch.append(VoFrame(
            (m.t_mid_ns - t_ref) * 1e-9,
            vel_b if cfg.vo_velocity else None, cov[3:, 3:],
            m.omega_b if cfg.vo_rate else None, cov[:3, :3],
            (m.t0_ns - t_ref) * 1e-9, (m.t1_ns - t_ref) * 1e-9,
            cov[:3, 3:] if cfg.vo_joint else None,
        ))  # fmt: skip
        meas_all.append(m)
        corrupted.append(bad)

    if filt is None or imu_track is None:
        raise InputError(
            f"{data.source}: no VO measurement from {frames_seen} frames "
            f"({unreadable} unreadable, {vo_run.stats.skipped_few_features} with too few features); "
            "nothing to fuse"
        )
    vel_acc = filt.frames(batch).tolist()  # the whole run in one compiled call
    # to the last frame
    filt.frame(VoFrame((vo_t[-1] - t_ref) * 1e-9))
    fused = filt.trajectory("fused")
    # VO alone, expressed from the same initial state as the others (pose of the first mid-time)
    vo_arr = np.asarray(vo_T)
    vo_traj = Trajectory(np.asarray(vo_t), vo_arr[:, :3, 3] @ fused.R_w_b[0].T, fused.R_w_b[0] @ vo_arr[:, :3, :3],
                         "VO only")  # fmt: skip
    imu_end = imu_track.t_ns <= vo_t[-1]
    imu_track = imu_track.subset(np.flatnonzero(imu_end))
    cor = np.asarray(corrupted, bool)
    va = np.asarray(vel_acc, bool)
    skipped = data.skipped_frames()
    bt, b, bs = filt.biases()
    return VioResult(
        fused, vo_traj, imu_track, filt.gate_stats(), vo_run.stats,
        {"listed_or_rendered": frames_seen + skipped.get("missing", 0), "missing": skipped.get("missing", 0),
         "unreadable": unreadable, "used": frames_seen - unreadable},
        {"corrupted": int(cor.sum()), "corrupted_rejected": int((cor & ~va).sum()),
         "good": int((~cor).sum()), "good_rejected": int((~cor & ~va).sum())},
        bt, b, bs, cfg, meas_all, cor, va, filt.vo_scale.copy(), t_ref,
    )  # fmt: skip


class VioPipeline:
    """Drives the filter over a stereo + IMU dataset (``run``), scores its tracks against a reference
    (``evaluate``) and writes the results folder (``save``): trajectory.tum (fused), vo.tum, imu.tum,
    config.yaml, metrics.json (the run's summary: frames, VO, gating, biases; and the errors against
    the reference when one is given) and the plots (tracks.png, nis.png, biases.png)."""

    def __init__(
        self, data: StereoSource, cfg: VioConfig | None = None, imu: ImuLog | None = None
    ) -> None:
        """``imu`` overrides the dataset's IMU (e.g. after calibration)."""
        self.data = data
        self.cfg = cfg or VioConfig()
        self.imu = imu

    def run(
        self,
        progress: Callable[[int], None] | None = None,
        observer: Callable[[VioFrame], None] | None = None,
    ) -> VioResult:
        """VO on every stereo pair and the filter over the IMU; ``progress(n)`` per frame,
        ``observer`` per pair the front end reads (:class:`VioFrame`)."""
        return run_vio(self.data, self.cfg, progress, observer=observer, imu=self.imu)

    @staticmethod
    def tracks(result: VioResult) -> dict[str, Trajectory]:
        return {"fused": result.fused, "vo": result.vo, "imu": result.imu}

    def evaluate(
        self,
        result: VioResult,
        truth: Trajectory,
        times_ns: NDArray[np.int64] | None = None,
        align: str = "se3",
    ) -> dict[str, Any]:
        """ATE / RPE of the fused, VO and IMU tracks against ``truth`` at ``times_ns`` (default: the VO
        times), ``align``-aligned: ``{track: EvalResult}``."""
        from imuslam.eval.vio_compare import compare_tracks

        tt = np.asarray(times_ns) if times_ns is not None else result.vo.t_ns
        return compare_tracks(truth, self.tracks(result), tt, align=align)

    def save(
        self,
        result: VioResult,
        out: str | Path,
        truth: Trajectory | None = None,
        evaluation: dict[str, Any] | None = None,
    ) -> Path:
        """The results folder through the one writer (:func:`imuslam.io.results.write_results`)."""
        from imuslam.eval.vio_compare import plot_vio
        from imuslam.io.results import write_results

        metrics = result.summary()
        if evaluation is not None:
            metrics["against_truth"] = {k: v.to_dict() for k, v in evaluation.items()}
        nis = {
            k: (np.asarray(v.nis), np.asarray(v.accepted_mask, bool), v.dof)
            for k, v in result.gating.items()
        }
        bias = (result.bias_t_s, result.bias, result.bias_std)
        tracks = self.tracks(result)
        return write_results(
            out, config=self.cfg, metrics=metrics,
            trajectories={"trajectory": result.fused, "vo": result.vo, "imu": result.imu},
            extra=lambda d: plot_vio(truth, tracks, nis, bias, str(d), self.cfg.gate_prob),
        )  # fmt: skip
