"""``imuslam align``: INS alignment of an IMU log (coarse, Kalman, strong tracking or RWNN)."""

from __future__ import annotations

from pathlib import Path

import numpy as np  # noqa: E402
import typer  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from imuslam.cli import validate  # noqa: E402
from imuslam.cli.common import (  # noqa: E402
    ACCEL_UNITS,
    FORMAT_HELP,
    GYRO_UNITS,
    console,
    friendly_errors,
    load_log,
    table,
    write_json,
)
from imuslam.errors import InputError  # noqa: E402
from imuslam.geometry.interp import interpolate_linear, interpolate_poses  # noqa: E402
from imuslam.ins.align import Aiding, AlignmentResult, run_alignment  # noqa: E402
from imuslam.ins.coarse import coarse_align  # noqa: E402
from imuslam.ins.kf import KfNoise  # noqa: E402
from imuslam.interfaces.imu import ImuLog  # noqa: E402
from imuslam.interfaces.nav import NavState  # noqa: E402
from imuslam.interfaces.trajectory import Trajectory  # noqa: E402
from imuslam.io.atomic import write_atomic  # noqa: E402
from imuslam.io.figures import save_figure  # noqa: E402
from imuslam.io.load import FORMATS, detect_format, write_imu  # noqa: E402
from imuslam.io.results import results_folder  # noqa: E402
from imuslam.io.trajectory import (  # noqa: E402
    TRAJ_FORMATS,
    StateTruth,
    read_euroc_state,
    read_trajectory,
)

METHODS = ("coarse", "kf", "stkf", "rwnn")

FloatArray = NDArray[np.float64]


def _trajectory_format(path: Path, fmt: str) -> str:
    if fmt != "auto":
        return fmt
    if path.is_dir() or path.suffix in (".bag", ".mcap", ".db3"):
        return "bag"
    return "euroc" if path.suffix == ".csv" else "tum"


def _noise(spec: str, log: ImuLog) -> tuple[KfNoise, str]:
    if spec == "datasheet":
        return KfNoise(), "defaults (a consumer MEMS at rest)"
    if spec == "auto":
        return KfNoise.from_log(log.accel, log.gyro, log.rate_hz, floor=KfNoise()), "from the log"
    return KfNoise.from_kalibr_yaml(spec), spec


def _pose_at(tr: Trajectory, t_ns: int) -> NavState:
    """The trajectory's pose at ``t_ns`` (linear / slerp) and its velocity by central difference."""
    t = (tr.t_ns - tr.t_ns[0]) * 1e-9
    tq = (t_ns - tr.t_ns[0]) * 1e-9
    pq, Rq = interpolate_poses(
        tr.t_ns, tr.p_w, tr.R_w_b, np.array([min(max(t_ns, tr.t_ns[0]), tr.t_ns[-1])])
    )
    p, R = pq[0], Rq[0]
    i = int(np.clip(np.searchsorted(t, tq), 1, len(t) - 2))
    v = (tr.p_w[i + 1] - tr.p_w[i - 1]) / (t[i + 1] - t[i - 1])
    return NavState(p, v, R)


def _truth_at(
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


def _rpy_deg(R: FloatArray) -> FloatArray:
    """Roll, pitch, yaw (deg) of R_n_b (N, 3, 3), ZYX convention."""
    return np.rad2deg(Rotation.from_matrix(R).as_euler("ZYX")[:, ::-1])


def _write_estimates(path: Path, res: AlignmentResult) -> None:
    rpy = _rpy_deg(res.R_n_b)
    head = (
        "t_s,ba_x,ba_y,ba_z,sa_x,sa_y,sa_z,bg_x,bg_y,bg_z,sg_x,sg_y,sg_z,roll_deg,pitch_deg,yaw_deg"
    )
    rows = np.column_stack(
        [res.t_s, res.accel_bias, res.accel_bias_std, res.gyro_bias, res.gyro_bias_std, rpy]
    )
    lines = [head] + [",".join(f"{x:.9g}" for x in r) for r in rows]
    write_atomic(path, "\n".join(lines) + "\n")


def register(app: typer.Typer) -> None:
    @app.command("align")
    @friendly_errors
    def align_cmd(
        log_path: Path = typer.Argument(
            ..., metavar="LOG", help="IMU log (SI, g or deg/s; calibrated)"
        ),
        method: str = typer.Option(
            "kf", help="coarse, kf, stkf or rwnn", callback=validate.choice(METHODS)
        ),
        aiding: str = typer.Option(
            "zupt",
            help="'zupt' (the IMU stands still) or a trajectory of the IMU frame (TUM, EuRoC csv, bag) "
            "whose positions aid the filter",
        ),
        aiding_format: str = typer.Option(
            "auto",
            help="auto, tum, euroc, kitti or bag",
            callback=validate.choice(("auto", *TRAJ_FORMATS)),
        ),
        aiding_topic: str | None = typer.Option(None, help="pose topic of an aiding bag"),
        aiding_std: float = typer.Option(
            0.01, help="aiding 1-sigma: m/s for zupt, m for positions", callback=validate.positive()
        ),
        init: str = typer.Option(
            "auto",
            help="initial state: 'coarse' (levelling on a still start), 'aiding' (the trajectory's first "
            "pose) or 'auto' (coarse for zupt, aiding for a trajectory)",
            callback=validate.choice(("auto", "coarse", "aiding")),
        ),
        noise: str = typer.Option(
            "auto",
            help="IMU white noise: 'auto' (as the log shows it, vibration included), 'datasheet' "
            "(defaults) or a Kalibr imu.yaml (as `imuslam allan` writes)",
        ),
        g: float = typer.Option(
            9.80665, "--g", help="gravity magnitude, m/s^2", callback=validate.gravity()
        ),
        t_still: float = typer.Option(
            5.0, help="seconds of still start used for levelling", callback=validate.positive("s")
        ),
        lat_deg: float | None = typer.Option(
            None,
            help="latitude, for gyrocompassing (coarse)",
            callback=validate.number(-90, 90, unit="deg", what="a latitude"),
        ),
        heading_deg: float | None = typer.Option(
            None,
            help="initial yaw from another source (compass, a known pose): deg, counter-clockwise from east (ENU)",
            callback=validate.number(-360, 360, unit="deg", what="a heading"),
        ),
        truth: Path | None = typer.Option(
            None,
            help="ground-truth state (EuRoC state csv with biases): plotted and compared",
        ),
        fmt: str = typer.Option(
            "auto", "--format", help=FORMAT_HELP, callback=validate.choice(FORMATS)
        ),
        topic: str | None = typer.Option(None, help="IMU topic of a bag"),
        accel_unit: str | None = typer.Option(
            None, help="m/s^2 or g (guessed if absent)", callback=validate.choice(ACCEL_UNITS[:2])
        ),
        gyro_unit: str | None = typer.Option(
            None,
            help="rad/s or deg/s (guessed if absent)",
            callback=validate.choice(GYRO_UNITS[:2]),
        ),
        columns: str | None = typer.Option(
            None, help="CSV column mapping: t=..,ax=..,ay=..,az=..,gx=..,gy=..,gz=.."
        ),
        out: Path = typer.Option(
            Path("align_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
    ) -> None:
        """Estimate attitude and the IMU's remaining biases; write them, plots and the corrected IMU."""
        if init == "aiding" and aiding == "zupt":
            raise InputError("--init aiding needs a trajectory as --aiding")
        if aiding != "zupt" and not Path(aiding).exists():
            raise InputError(f"--aiding {aiding}: no such file; expected 'zupt' or a trajectory")
        if noise not in ("auto", "datasheet") and not Path(noise).is_file():
            raise InputError(
                f"--noise {noise}: no such file; expected auto, datasheet or a Kalibr imu.yaml"
            )
        log = load_log(log_path, None, fmt, topic, accel_unit, gyro_unit, columns).to_si()
        full = log
        if method == "coarse" or aiding == "zupt":
            k_still = max(int(np.searchsorted(log.t_s, t_still)), 10)
            ca = coarse_align(log.accel[:k_still], log.gyro[:k_still], log.rate_hz,
                              None if lat_deg is None else np.deg2rad(lat_deg),
                              heading_rad=None if heading_deg is None else np.deg2rad(heading_deg))  # fmt: skip
        if method == "coarse":
            rows = [["roll", f"{np.rad2deg(ca.roll):.3f}", f"{np.rad2deg(ca.roll_pitch_std):.2g}", "deg"],
                    ["pitch", f"{np.rad2deg(ca.pitch):.3f}", f"{np.rad2deg(ca.roll_pitch_std):.2g}", "deg"],
                    ["yaw", "unobservable" if ca.yaw is None else f"{np.rad2deg(ca.yaw):.2f}",
                     "-" if ca.yaw_std is None else f"{np.rad2deg(ca.yaw_std):.2g}", "deg"]]  # fmt: skip
            console.print(table("Coarse alignment", ["quantity", "value", "1-sigma", "unit"], rows))
            console.print(ca.reason)
            with results_folder(out) as tmp:
                write_json(tmp / "alignment.json", {"method": "coarse", **{k: v for k, v in ca.__dict__.items() if k != "R_n_b"},
                                                    "R_n_b": ca.R_n_b.tolist()})  # fmt: skip
            console.print(f"wrote {out}/alignment.json")
            return
        if aiding == "zupt":
            ta = np.arange(0.1, log.t_s[-1], 0.1)
            aid = Aiding(ta, "zupt", np.zeros((len(ta), 3)), aiding_std)
            start = NavState(np.zeros(3), np.zeros(3), ca.R_n_b)
            reason = ca.reason
        else:
            ap = Path(aiding)
            tr = read_trajectory(ap, _trajectory_format(ap, aiding_format), aiding_topic)
            if len(tr) < 3:
                raise InputError(f"{ap}: fewer than 3 poses")
            if tr.t_ns[0] > log.t_ns[-1] or tr.t_ns[-1] < log.t_ns[0]:
                raise InputError(
                    f"{ap}: its time span does not overlap the IMU log's ({log.source})"
                )
            k0 = int(np.searchsorted(log.t_ns, tr.t_ns[0]))  # start the log at the first pose
            log = log.slice(k0, len(log))
            ta = (tr.t_ns - log.t_ns[0]) * 1e-9
            keep = (ta > 0) & (ta < log.t_s[-1])
            if keep.sum() < 3:
                raise InputError(f"{ap}: fewer than 3 positions inside the IMU log's time span")
            aid = Aiding(ta[keep], "position", tr.p_w[keep], aiding_std)
            if (
                init == "coarse"
            ):  # level from a still start; heading as given, else from the trajectory
                k_still = max(int(np.searchsorted(log.t_s, t_still)), 10)
                ca = coarse_align(log.accel[:k_still], log.gyro[:k_still], log.rate_hz,
                                  None if lat_deg is None else np.deg2rad(lat_deg),
                                  heading_rad=None if heading_deg is None else np.deg2rad(heading_deg))  # fmt: skip
                R0 = ca.R_n_b
                reason = ca.reason
                if ca.yaw is None:
                    yaw = float(
                        Rotation.from_matrix(_pose_at(tr, int(log.t_ns[0])).R_n_b).as_euler("ZYX")[
                            0
                        ]
                    )
                    R0 = Rotation.from_euler("ZYX", [yaw, ca.pitch, ca.roll]).as_matrix()
                    reason += f"; heading {np.rad2deg(yaw):.1f} deg from {ap}"
                start = NavState(tr.p_w[keep][0], np.zeros(3), R0)
            else:
                start = _pose_at(tr, int(log.t_ns[0]))
                reason = f"initial attitude, position and velocity from {ap}"
        kf_noise, noise_src = _noise(noise, log)
        console.print(
            f"IMU white noise {kf_noise.accel:.3g} m/s^2/sqrt(Hz), {kf_noise.gyro:.3g} rad/s/sqrt(Hz) "
            f"({noise_src}); bias random walks {kf_noise.accel_bias_rw:.3g}, {kf_noise.gyro_bias_rw:.3g}"
        )
        res = run_alignment(log, aid, start, method, kf_noise, g=g)  # type: ignore[arg-type]
        tt, ba, bg, sa, sg = (
            res.t_s,
            res.accel_bias,
            res.gyro_bias,
            res.accel_bias_std,
            res.gyro_bias_std,
        )
        summary: dict[str, object] = {
            "method": method, "aiding": aid.kind, "accel_bias": ba[-1].tolist(), "accel_bias_std": sa[-1].tolist(),
            "gyro_bias": bg[-1].tolist(), "gyro_bias_std": sg[-1].tolist(), "init": reason,
            "config": {"log": str(log_path), "method": method, "aiding": aiding, "aiding_std": aiding_std,
                       "init": init, "noise": noise, "g": g, "truth": None if truth is None else str(truth)},
            "noise": {"accel": kf_noise.accel, "gyro": kf_noise.gyro, "accel_bias_rw": kf_noise.accel_bias_rw,
                      "gyro_bias_rw": kf_noise.gyro_bias_rw, "source": noise_src},
        }  # fmt: skip
        tb = tbg = Rt = None
        if truth is not None:
            st = read_euroc_state(truth)
            t_abs = log.t_ns[0] + np.round(tt * 1e9).astype(np.int64)
            tb, tbg, Rt = _truth_at(st, t_abs)
            att_err = np.rad2deg(
                Rotation.from_matrix(res.R_n_b @ np.transpose(Rt, (0, 2, 1))).as_rotvec()
            )
            za = (ba[-1] - tb[-1]) / sa[-1]
            zg = (bg[-1] - tbg[-1]) / sg[-1]
            summary.update(truth_accel_bias=tb[-1].tolist(), truth_gyro_bias=tbg[-1].tolist(), accel_bias_z=za.tolist(),
                           gyro_bias_z=zg.tolist(), attitude_error_deg=att_err[-1].tolist())  # fmt: skip
        cols = (
            ["quantity", "estimate", "1-sigma"]
            + (["truth", "|err|/sigma"] if tb is not None else [])
            + ["unit"]
        )
        rows = []
        for name, est, sd, tru, unit, f in (("accel bias", ba, sa, tb, "m/s^2", "{:+.5f}"),
                                            ("gyro bias", bg, sg, tbg, "rad/s", "{:+.6f}")):  # fmt: skip
            for j in range(3):
                row = [f"{name} {'xyz'[j]}", f.format(est[-1, j]), f"{sd[-1, j]:.2g}"]
                if tru is not None:
                    row += [f.format(tru[-1, j]), f"{abs(est[-1, j] - tru[-1, j]) / sd[-1, j]:.1f}"]
                rows.append(row + [unit])
        console.print(table(f"Alignment ({method}, {aid.kind} aiding)", cols, rows))
        from matplotlib.figure import Figure

        fig = Figure(figsize=(10, 6))
        axes = fig.subplots(2, 1, sharex=True)
        for ax, b, s_, tru, name in ((axes[0], ba, sa, tb, "accel bias [m/s^2]"),
                                     (axes[1], bg, sg, tbg, "gyro bias [rad/s]")):  # fmt: skip
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
            f"{method}: estimate +- 1 sigma" + (" against truth" if tb is not None else "")
        )
        with results_folder(out) as tmp:
            save_figure(fig, tmp / "biases.png")
            files = ["alignment.json", "estimates.csv", "biases.png"]
            if Rt is not None:
                fig = Figure(figsize=(10, 4))
                ax = fig.subplots()
                for j, lab in enumerate(("x (roll)", "y (pitch)", "z (heading)")):
                    ax.plot(tt, att_err[:, j], label=lab)
                ax.set_xlabel("time [s]")
                ax.set_ylabel("attitude error in n [deg]")
                ax.legend()
                save_figure(fig, tmp / "attitude_error.png")
                files.append("attitude_error.png")
            write_json(tmp / "alignment.json", summary)
            _write_estimates(tmp / "estimates.csv", res)
            if detect_format(log_path) == "bag" and fmt in ("auto", "bag"):
                # a bag stays a bag: a copy with the IMU topic replaced, every other message untouched
                dst = tmp / ("corrected_imu" + (log_path.suffix if log_path.is_file() else ""))
                t_topic = topic or full.source.rsplit(":", 1)[-1]
                write_imu(res.corrected(full), dst, "bag", template=log_path, topic=t_topic)
                files.append(f"{dst.name} (the input bag, {t_topic} corrected)")
            else:
                write_imu(res.corrected(full), tmp / "corrected_imu.csv", "euroc")
                files.append("corrected_imu.csv (EuRoC format)")
        console.print(f"wrote {out}/{', '.join(files)}")
