"""``AlignPipeline(dataset, config).run() -> AlignOutput``: INS alignment of an IMU log, and its results
folder through the one writer (``io.results.write_results``), as ``eval.pipeline.EvalPipeline`` does.

The dataset holds records only (the IMU log in SI units, an optional aiding trajectory, an optional
ground-truth state, an optional noise model read from a Kalibr file); reading files is the caller's.
The initial state is chosen here: coarse levelling on a still start (with gyrocompassing when a latitude
is given, or a heading from another source), or the aiding trajectory's pose at the first sample.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from imuslam.errors import InputError
from imuslam.geometry.euler import euler_to_matrix, matrix_to_euler
from imuslam.geometry.interp import interpolate_linear, interpolate_poses
from imuslam.geometry.so3 import log as so3_log
from imuslam.ins.align import Aiding, AlignmentResult, run_alignment
from imuslam.ins.coarse import CoarseAlignment, coarse_align
from imuslam.ins.kf import KfNoise
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.nav import NavState
from imuslam.interfaces.trajectory import Trajectory
from imuslam.io.trajectory import StateTruth

FloatArray = NDArray[np.float64]
AlignMethodName = Literal["coarse", "kf", "stkf", "rwnn"]
ALIGN_METHODS: tuple[str, ...] = ("coarse", "kf", "stkf", "rwnn")


class AlignConfig(BaseModel):
    """The settings of an alignment (the options of ``imuslam align``)."""

    model_config = ConfigDict(extra="forbid")

    method: AlignMethodName = "kf"
    aiding_std: float = Field(
        0.01, gt=0, description="m/s for zero-velocity updates, m for positions"
    )
    init: Literal["auto", "coarse", "aiding"] = "auto"
    noise: str = Field(
        "auto", description="auto (from the log), datasheet, or the Kalibr file used"
    )
    g: float = Field(9.80665, gt=0)
    t_still_s: float = Field(5.0, gt=0, description="still start used for levelling, s")
    lat_deg: float | None = Field(None, ge=-90, le=90)
    heading_deg: float | None = Field(None, ge=-360, le=360)
    zupt_period_s: float = Field(0.1, gt=0, description="spacing of the zero-velocity updates, s")


@dataclass
class AlignDataset:
    """imu: the log in m/s^2 and rad/s; aiding: positions of the IMU frame (None: it stands still);
    truth: a ground-truth state to score against; noise: a white-noise model (None: from the config)."""

    imu: ImuLog
    aiding: Trajectory | None = None
    truth: StateTruth | None = None
    noise: KfNoise | None = None


@dataclass
class AlignOutput:
    """What an alignment found. ``alignment`` is None for the coarse method (``coarse`` only); the
    truth arrays (at the estimate times) are None without a truth."""

    method: str
    reason: str
    coarse: CoarseAlignment | None
    alignment: AlignmentResult | None
    imu: ImuLog  # the log the filter ran on (cut to the aiding's start)
    noise: KfNoise | None = None
    noise_source: str = ""
    aiding_kind: str = "zupt"
    truth_accel_bias: FloatArray | None = None
    truth_gyro_bias: FloatArray | None = None
    truth_R_n_b: FloatArray | None = None
    attitude_error_deg: FloatArray | None = None  # (M, 3) rotation vector of R_est R_true^T, deg
    metrics: dict[str, Any] = field(default_factory=dict)

    def trajectory(self) -> Trajectory | None:
        """The filter's pose at each estimate time (absolute stamps), or None (coarse)."""
        a = self.alignment
        if a is None:
            return None
        t_ns = self.imu.t_ns[0] + np.round(a.t_s * 1e9).astype(np.int64)
        return Trajectory(t_ns, a.p_n, a.R_n_b, source=f"imuslam align ({self.method})")


def pose_at(tr: Trajectory, t_ns: int) -> NavState:
    """The trajectory's pose at ``t_ns`` (linear / slerp) and its velocity by central difference."""
    t = (tr.t_ns - tr.t_ns[0]) * 1e-9
    tq = (t_ns - tr.t_ns[0]) * 1e-9
    pq, Rq = interpolate_poses(
        tr.t_ns, tr.p_w, tr.R_w_b, np.array([min(max(t_ns, tr.t_ns[0]), tr.t_ns[-1])])
    )
    i = int(np.clip(np.searchsorted(t, tq), 1, len(t) - 2))
    v = (tr.p_w[i + 1] - tr.p_w[i - 1]) / (t[i + 1] - t[i - 1])
    return NavState(pq[0], v, Rq[0])


def truth_at(
    truth: StateTruth, t_ns: NDArray[np.int64]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Truth accelerometer and gyro biases (M, 3) and attitude (M, 3, 3) at ``t_ns`` (inside its span)."""
    tt = truth.traj.t_ns
    if t_ns[0] < tt[0] or t_ns[-1] > tt[-1]:
        raise InputError(
            f"{truth.traj.source}: the truth covers {tt[0]}..{tt[-1]} ns, the estimates "
            f"{t_ns[0]}..{t_ns[-1]} ns: it must cover the whole alignment"
        )
    ba = interpolate_linear(tt, truth.accel_bias, t_ns)
    bg = interpolate_linear(tt, truth.gyro_bias, t_ns)
    _, R = interpolate_poses(tt, truth.traj.p_w, truth.traj.R_w_b, t_ns)
    return ba, bg, R


class AlignPipeline:
    """Choose the initial state and the aiding, run the alignment, score it against a truth."""

    def __init__(self, dataset: AlignDataset, config: AlignConfig | None = None) -> None:
        self.dataset = dataset
        self.config = config or AlignConfig()

    def _coarse(self, log: ImuLog) -> CoarseAlignment:
        c = self.config
        k_still = max(int(np.searchsorted(log.t_s, c.t_still_s)), 10)
        return coarse_align(
            log.accel[:k_still],
            log.gyro[:k_still],
            log.rate_hz,
            None if c.lat_deg is None else np.deg2rad(c.lat_deg),
            heading_rad=None if c.heading_deg is None else np.deg2rad(c.heading_deg),
        )

    def _noise(self, log: ImuLog) -> tuple[KfNoise, str]:
        if self.dataset.noise is not None:
            return self.dataset.noise, self.config.noise
        if self.config.noise == "datasheet":
            return KfNoise(), "defaults (a consumer MEMS at rest)"
        return KfNoise.from_log(log.accel, log.gyro, log.rate_hz, floor=KfNoise()), "from the log"

    def run(self) -> AlignOutput:
        c, ds = self.config, self.dataset
        log = ds.imu
        tr = ds.aiding
        if c.init == "aiding" and tr is None:
            raise InputError("--init aiding needs a trajectory as --aiding")
        if c.method == "coarse":
            ca = self._coarse(log)
            yaw = None if ca.yaw is None else float(ca.yaw)
            metrics = {"method": "coarse", **{k: v for k, v in ca.__dict__.items() if k != "R_n_b"},
                       "yaw": yaw, "R_n_b": ca.R_n_b.tolist()}  # fmt: skip
            return AlignOutput("coarse", ca.reason, ca, None, log, metrics=metrics)
        if tr is None:
            ca = self._coarse(log)
            ta = np.arange(c.zupt_period_s, log.t_s[-1], c.zupt_period_s)
            aid = Aiding(ta, "zupt", np.zeros((len(ta), 3)), c.aiding_std)
            start = NavState(np.zeros(3), np.zeros(3), ca.R_n_b)
            reason = ca.reason
        else:
            src = tr.source or "the aiding trajectory"
            if len(tr) < 3:
                raise InputError(f"{src}: fewer than 3 poses")
            if tr.t_ns[0] > log.t_ns[-1] or tr.t_ns[-1] < log.t_ns[0]:
                raise InputError(
                    f"{src}: its time span does not overlap the IMU log's ({log.source})"
                )
            k0 = int(np.searchsorted(log.t_ns, tr.t_ns[0]))  # start the log at the first pose
            log = log.slice(k0, len(log))
            ta = (tr.t_ns - log.t_ns[0]) * 1e-9
            keep = (ta > 0) & (ta < log.t_s[-1])
            if keep.sum() < 3:
                raise InputError(f"{src}: fewer than 3 positions inside the IMU log's time span")
            aid = Aiding(ta[keep], "position", tr.p_w[keep], c.aiding_std)
            if (
                c.init == "coarse"
            ):  # level from a still start; heading as given, else the trajectory's
                ca = self._coarse(log)
                R0, reason = ca.R_n_b, ca.reason
                if ca.yaw is None:
                    yaw = float(matrix_to_euler(pose_at(tr, int(log.t_ns[0])).R_n_b)[2])
                    R0 = euler_to_matrix([ca.roll, ca.pitch, yaw])
                    reason += f"; heading {np.rad2deg(yaw):.1f} deg from {src}"
                start = NavState(tr.p_w[keep][0], np.zeros(3), R0)
            else:
                start = pose_at(tr, int(log.t_ns[0]))
                reason = f"initial attitude, position and velocity from {src}"
        noise, noise_src = self._noise(log)
        res = run_alignment(log, aid, start, c.method, noise, g=c.g)
        out = AlignOutput(c.method, reason, None, res, log, noise, noise_src, str(aid.kind))
        m: dict[str, Any] = {
            "method": c.method, "aiding": str(aid.kind), "accel_bias": res.accel_bias[-1].tolist(),
            "accel_bias_std": res.accel_bias_std[-1].tolist(), "gyro_bias": res.gyro_bias[-1].tolist(),
            "gyro_bias_std": res.gyro_bias_std[-1].tolist(), "init": reason,
            "noise": {"accel": noise.accel, "gyro": noise.gyro, "accel_bias_rw": noise.accel_bias_rw,
                      "gyro_bias_rw": noise.gyro_bias_rw, "source": noise_src},
        }  # fmt: skip
        if ds.truth is not None:
            t_abs = log.t_ns[0] + np.round(res.t_s * 1e9).astype(np.int64)
            tb, tbg, Rt = truth_at(ds.truth, t_abs)
            att = np.rad2deg(so3_log(res.R_n_b @ np.transpose(Rt, (0, 2, 1))))
            out.truth_accel_bias, out.truth_gyro_bias, out.truth_R_n_b = tb, tbg, Rt
            out.attitude_error_deg = att
            m.update(truth_accel_bias=tb[-1].tolist(), truth_gyro_bias=tbg[-1].tolist(),
                     accel_bias_error_sigmas=((res.accel_bias[-1] - tb[-1]) / res.accel_bias_std[-1]).tolist(),
                     gyro_bias_error_sigmas=((res.gyro_bias[-1] - tbg[-1]) / res.gyro_bias_std[-1]).tolist(),
                     attitude_error_deg=att[-1].tolist())  # fmt: skip
        out.metrics = m
        return out

    def save(
        self,
        result: AlignOutput,
        out: str | Path,
        plots: bool = True,
        extra: Callable[[Path], list[str]] | None = None,
        **inputs: Any,
    ) -> list[str]:
        """The results folder, all or nothing: ``config.yaml`` (``inputs`` and the config),
        ``metrics.json`` (``*_error_sigmas``: the final bias error in its 1-sigma), ``trajectory.tum`` (the filter's
        poses), ``estimates.csv`` (bias, 1-sigma and attitude over time), the plots, then ``extra(folder)``
        (the corrected IMU, written by the caller, which knows the input's format). Returns the files."""
        from imuslam.io.results import write_results

        files = ["config.yaml", "metrics.json"]
        traj = result.trajectory()

        def more(folder: Path) -> None:
            if result.alignment is None:
                return
            write_estimates(folder / "estimates.csv", result.alignment)
            files.extend(["trajectory.tum", "estimates.csv"])
            if plots:
                files.extend(plot_alignment(result, folder))
            if extra is not None:
                files.extend(extra(folder))

        write_results(
            out,
            config={**inputs, **self.config.model_dump(mode="json")},
            metrics=result.metrics,
            trajectories={} if traj is None else {"trajectory": traj},
            extra=more,
        )
        return files


def write_estimates(path: Path, res: AlignmentResult) -> None:
    """``t_s, bias, 1-sigma, roll/pitch/yaw`` (deg, Z-Y-X) per estimate, CSV with a header."""
    from imuslam.io.atomic import write_atomic

    rpy = np.rad2deg(matrix_to_euler(res.R_n_b))
    head = (
        "t_s,ba_x,ba_y,ba_z,sa_x,sa_y,sa_z,bg_x,bg_y,bg_z,sg_x,sg_y,sg_z,roll_deg,pitch_deg,yaw_deg"
    )
    rows = np.column_stack(
        [res.t_s, res.accel_bias, res.accel_bias_std, res.gyro_bias, res.gyro_bias_std, rpy]
    )
    lines = [head] + [",".join(f"{x:.9g}" for x in r) for r in rows]
    write_atomic(path, "\n".join(lines) + "\n")


def plot_alignment(result: AlignOutput, folder: Path) -> list[str]:
    """biases.png (estimate +- 1 sigma, truth dashed) and, with a truth, attitude_error.png."""
    from matplotlib.figure import Figure

    from imuslam.io.figures import save_figure

    res = result.alignment
    assert res is not None
    tt = res.t_s
    tb, tbg = result.truth_accel_bias, result.truth_gyro_bias
    fig = Figure(figsize=(10, 6))
    axes = fig.subplots(2, 1, sharex=True)
    for ax, b, s_, tru, name in ((axes[0], res.accel_bias, res.accel_bias_std, tb, "accel bias [m/s^2]"),
                                 (axes[1], res.gyro_bias, res.gyro_bias_std, tbg, "gyro bias [rad/s]")):  # fmt: skip
        for j in range(3):
            ax.plot(tt, b[:, j], color=f"C{j}", label=f"{'xyz'[j]} estimate")
            if np.all(np.isfinite(s_[:, j])):
                ax.fill_between(
                    tt, b[:, j] - s_[:, j], b[:, j] + s_[:, j], color=f"C{j}", alpha=0.2
                )
            if tru is not None:
                ax.plot(tt, tru[:, j], color=f"C{j}", ls="--", label=f"{'xyz'[j]} truth")
        ax.set_ylabel(name)
        ax.legend(ncol=2, fontsize="small")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(
        f"{result.method}: estimate +- 1 sigma" + (" against truth" if tb is not None else "")
    )
    save_figure(fig, folder / "biases.png")
    files = ["biases.png"]
    if result.attitude_error_deg is not None:
        fig = Figure(figsize=(10, 4))
        ax = fig.subplots()
        for j, lab in enumerate(("x (roll)", "y (pitch)", "z (heading)")):
            ax.plot(tt, result.attitude_error_deg[:, j], label=lab)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("attitude error in n [deg]")
        ax.legend()
        save_figure(fig, folder / "attitude_error.png")
        files.append("attitude_error.png")
    return files
