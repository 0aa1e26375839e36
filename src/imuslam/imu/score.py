"""The score of a calibration on a log: how well it predicts static poses it is given, independently of
how it was made.

Static poses are found on the raw log by the detector of ``imu/static.py`` with fixed settings (1 s
window, threshold 6 x the variance norm of the initial still period, poses at least 1 s long), so the
poses do not depend on the calibration being scored and every calibration is scored on the same ones.
For each calibration:

- per pose, the gravity-norm error ``|mean of the calibrated accel| - g`` (m/s^2);
- per consecutive pair of poses, the gyro-predicted gravity-direction error: the calibrated gyro is
  integrated (RK4 on the quaternion, Tedaldi 2014 eq. 14) from the end of the first pose to the start of
  the second, the first pose's gravity direction is carried through that rotation and compared with the
  second's (Tedaldi 2014, eq. 13, as an angle in deg).

RMS and worst of both are the calibration's score. A calibration for other units than the log (counts
against m/s^2, or g) is refused with one line, as is a log without static poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from imuslam.imu.model import ImuCalibration
from imuslam.imu.rk4 import integrate_segments
from imuslam.imu.static import detect, init_variance_norm, window_half_size, windowed_variance_norm
from imuslam.interfaces.imu import ImuLog, InputError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

# Fixed detector settings of the score (not tuned per calibration or per log).
SCORE_WINDOW_S = 1.0
SCORE_K = 6.0
SCORE_MIN_POSE_S = 1.0
MIN_POSES = 3
# A calibrated gravity norm further than this from g means the calibration is for other units.
UNIT_TOLERANCE = 0.2


def detect_poses(log: ImuLog, t_init_s: float = 50.0) -> IntArray:
    """Static poses (K, 2) ``[start, end]`` sample indices of the raw log, by the fixed-setting detector.

    Raises InputError when the log has no initial still period or fewer than 3 static poses.
    """
    t = log.t_s
    n_init = int(np.searchsorted(t, t_init_s, side="right")) - 1
    if len(log) < 20 or n_init < 20 or t[-1] < 1.1 * t_init_s:
        raise InputError(
            f"{log.source}: the log lasts {t[-1] if len(log) else 0.0:.1f} s; the score needs its "
            f"initial still period of {t_init_s:g} s (--t-init) and static poses after it"
        )
    rate = log.rate_hz
    det = windowed_variance_norm(log.accel, window_half_size(SCORE_WINDOW_S, rate))
    n0 = init_variance_norm(log.accel, n_init)
    if not n0 > 0:
        raise InputError(f"{log.source}: the accelerometer is constant over the still period")
    poses = detect(log.accel, det, n0, SCORE_K, int(round(SCORE_MIN_POSE_S * rate))).valid
    if len(poses) < MIN_POSES:
        raise InputError(
            f"{log.source}: {len(poses)} static poses found (1 s window, threshold {SCORE_K:g} x the "
            f"variance of the first {t_init_s:g} s, poses >= {SCORE_MIN_POSE_S:g} s); the score needs "
            f"at least {MIN_POSES} static poses with rotations between them"
        )
    return poses


@dataclass
class PoseErrors:
    """Errors of one calibration on the poses of a log.

    norm_error: (K,) calibrated gravity norm minus g per pose, m/s^2.
    direction_error_deg: (K-1,) gyro-predicted gravity-direction error per consecutive pair, deg.
    """

    norm_error: FloatArray
    direction_error_deg: FloatArray


def pose_errors(log: ImuLog, cal: ImuCalibration, poses: IntArray, g: float) -> PoseErrors:
    """Gravity-norm error per pose and gravity-direction error per consecutive pair (see module doc)."""
    raw_means = np.stack([log.accel[s:e].mean(axis=0) for s, e in poses])
    means = cal.correct_accel(raw_means)
    norms = np.linalg.norm(means, axis=1)
    u = means / norms[:, None]
    segs = np.stack([poses[:-1, 1], poses[1:, 0]], axis=1)
    # The calibrated rate of every sample (with its g-sensitivity term if the calibration has one).
    w = cal.correct_gyro(log.gyro, log.accel)
    R = integrate_segments(w, log.t_s, segs, np.eye(3)[None])[0]
    pred = np.einsum("sji,sj->si", R, u[:-1])
    cos = np.clip(np.sum(pred * u[1:], axis=1), -1.0, 1.0)
    return PoseErrors(norms - g, np.rad2deg(np.arccos(cos)))


def check_units(log: ImuLog, cal: ImuCalibration, poses: IntArray, g: float, name: str) -> None:
    """InputError when ``cal`` is for other units than ``log`` (by the unit fields and by magnitude)."""
    if cal.accel_unit != log.accel_unit or cal.gyro_unit != log.gyro_unit:
        raise InputError(
            f"{name}: calibration for accel in {cal.accel_unit} and gyro in {cal.gyro_unit}, but "
            f"{log.source} has accel in {log.accel_unit} and gyro in {log.gyro_unit}"
        )
    raw_means = np.stack([log.accel[s:e].mean(axis=0) for s, e in poses])
    med = float(np.median(np.linalg.norm(cal.correct_accel(raw_means), axis=1)))
    if not abs(med - g) < UNIT_TOLERANCE * g:
        raise InputError(
            f"{name}: it turns the static poses of {log.source} into a gravity norm of {med:.4g} "
            f"m/s^2 instead of {g:g}: the calibration is for other units than the log "
            f"(log accel unit {log.accel_unit})"
        )


def rms(x: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def worst(x: FloatArray) -> float:
    return float(np.max(np.abs(x))) if x.size else float("nan")


@dataclass
class CalibrationScore:
    """Score of one calibration on one log."""

    name: str
    errors: PoseErrors

    @property
    def norm_rms(self) -> float:
        return rms(self.errors.norm_error)

    @property
    def norm_worst(self) -> float:
        return worst(self.errors.norm_error)

    @property
    def direction_rms_deg(self) -> float:
        return rms(self.errors.direction_error_deg)

    @property
    def direction_worst_deg(self) -> float:
        return worst(self.errors.direction_error_deg)

    def summary(self) -> dict[str, float | str]:
        return {
            "calibration": self.name,
            "norm_rms_mps2": self.norm_rms,
            "norm_worst_mps2": self.norm_worst,
            "direction_rms_deg": self.direction_rms_deg,
            "direction_worst_deg": self.direction_worst_deg,
        }


@dataclass
class ScoreResult:
    """Scores of several calibrations on the same poses of one log."""

    log_source: str
    g: float
    poses: IntArray  # (K, 2)
    t_s: FloatArray  # (K,) mid time of each pose, s
    scores: list[CalibrationScore]


def score_calibrations(
    log: ImuLog,
    calibrations: list[tuple[str, ImuCalibration]],
    g: float,
    t_init_s: float = 50.0,
) -> ScoreResult:
    """Score each ``(name, calibration)`` on the static poses of ``log`` (found without any calibration)."""
    if not calibrations:
        raise ValueError(
            "no calibration to score: give a calibration.yaml or an imu_tk .calib pair"
        )
    poses = detect_poses(log, t_init_s)
    scores = []
    for name, cal in calibrations:
        check_units(log, cal, poses, g, name)
        scores.append(CalibrationScore(name, pose_errors(log, cal, poses, g)))
    mid = (poses[:, 0] + poses[:, 1]) // 2
    return ScoreResult(log.source, g, poses, log.t_s[mid], scores)


def plot_scores(res: ScoreResult) -> Figure:
    """Gravity-norm error per pose and gravity-direction error per pair, one bar series per calibration."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 6.5))
    a1, a2 = fig.subplots(2, 1)
    n = len(res.scores)
    width = 0.8 / n
    for j, s in enumerate(res.scores):
        k = np.arange(s.errors.norm_error.size)
        a1.bar(k + (j - (n - 1) / 2) * width, s.errors.norm_error, width,
               label=f"{s.name} (RMS {s.norm_rms:.4f})")  # fmt: skip
        p = np.arange(s.errors.direction_error_deg.size)
        a2.bar(p + (j - (n - 1) / 2) * width, s.errors.direction_error_deg, width,
               label=f"{s.name} (RMS {s.direction_rms_deg:.3f})")  # fmt: skip
    a1.set_ylabel("|a| - g per pose [m/s^2]")
    a1.set_xlabel("static pose")
    a1.legend(fontsize=8)
    a2.set_ylabel("gravity direction error [deg]")
    a2.set_xlabel("pair of consecutive poses")
    a2.legend(fontsize=8)
    fig.suptitle(f"Score on {len(res.poses)} static poses of {res.log_source}", fontsize=10)
    fig.tight_layout()
    return fig


def load_calibrations(
    paths: list[Path], accel_unit: str, gyro_unit: str
) -> tuple[list[tuple[str, ImuCalibration]], float | None]:
    """Calibrations named by their files: ``.yaml``/``.yml`` (imuslam) or consecutive ``.calib`` pairs
    (imu_tk: accelerometer then gyroscope, taken in the given units). Returns them and the first YAML's g.
    """
    out: list[tuple[str, ImuCalibration]] = []
    g: float | None = None
    i = 0
    while i < len(paths):
        p = Path(paths[i])
        if p.suffix in (".yaml", ".yml"):
            cal = ImuCalibration.load_yaml(p)
            g = cal.g if g is None else g
            out.append((f"{p.parent.name}/{p.name}", cal))
            i += 1
        elif p.suffix == ".calib":
            if i + 1 >= len(paths) or Path(paths[i + 1]).suffix != ".calib":
                raise InputError(
                    f"{p}: an imu_tk .calib file must be followed by its gyroscope .calib file"
                )
            cal = ImuCalibration.import_imutk(p, paths[i + 1], accel_unit, gyro_unit)
            out.append((f"{p.parent.name}/{p.name}+{Path(paths[i + 1]).name}", cal))
            i += 2
        else:
            raise InputError(
                f"{p}: expected a calibration.yaml or an imu_tk .calib pair (acc, gyro)"
            )
    return out, g


def write_scores(res: ScoreResult, out_dir: str | Path) -> list[Path]:
    """scores.csv (one row per calibration), poses.csv, pairs.csv and score.png in ``out_dir``, all
    at once (:func:`imuslam.io.results.results_folder`: the folder's other files are kept)."""
    from imuslam.io.figures import save_figure
    from imuslam.io.results import results_folder

    names = ["scores.csv", "poses.csv", "pairs.csv", "score.png"]
    out = Path(out_dir)
    with results_folder(out) as tmp:
        summ = [s.summary() for s in res.scores]
        lines = [",".join(summ[0])] + [
            ",".join(f"{v:.6g}" if isinstance(v, float) else f'"{v}"' for v in row.values())
            for row in summ
        ]
        (tmp / "scores.csv").write_text("\n".join(lines) + "\n")
        head = "pose,start,end,t_s," + ",".join(f'"norm_error {s.name}"' for s in res.scores)
        rows = [
            f"{k},{s},{e},{t:.3f},"
            + ",".join(f"{sc.errors.norm_error[k]:.6g}" for sc in res.scores)
            for k, ((s, e), t) in enumerate(zip(res.poses, res.t_s, strict=True))
        ]
        (tmp / "poses.csv").write_text("\n".join([head, *rows]) + "\n")
        head = "pair,from_pose,to_pose," + ",".join(
            f'"direction_error_deg {s.name}"' for s in res.scores
        )
        rows = [
            f"{k},{k},{k + 1},"
            + ",".join(f"{sc.errors.direction_error_deg[k]:.6g}" for sc in res.scores)
            for k in range(len(res.poses) - 1)
        ]
        (tmp / "pairs.csv").write_text("\n".join([head, *rows]) + "\n")
        save_figure(plot_scores(res), tmp / "score.png")
    return [out / n for n in names]
