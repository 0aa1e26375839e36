"""``imuslam align``: INS alignment of an IMU log (coarse, Kalman, strong tracking or RWNN)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import typer  # noqa: E402

from imuslam.cli.common import FORMAT_HELP, console, friendly_errors, load_log, table, write_json  # noqa: E402
from imuslam.ins.align import Aiding, run_alignment  # noqa: E402
from imuslam.ins.coarse import coarse_align  # noqa: E402
from imuslam.ins.strapdown import NavState  # noqa: E402
from imuslam.io.figures import save_figure  # noqa: E402
from imuslam.io.imulog import InputError  # noqa: E402
from imuslam.io.load import write_imu  # noqa: E402
from imuslam.io.trajectory import read_tum  # noqa: E402


def register(app: typer.Typer) -> None:
    @app.command("align")
    @friendly_errors
    def align_cmd(
        log_path: Path = typer.Argument(
            ..., metavar="LOG", help="IMU log (SI, g or deg/s; calibrated)"
        ),
        method: str = typer.Option("kf", help="coarse, kf, stkf or rwnn"),
        aiding: str = typer.Option(
            "zupt", help="'zupt' (the IMU stands still) or a TUM file of positions"
        ),
        aiding_std: float = typer.Option(
            0.01, help="aiding 1-sigma: m/s for zupt, m for positions"
        ),
        t_still: float = typer.Option(5.0, help="seconds of still start used for levelling"),
        lat_deg: float | None = typer.Option(None, help="latitude, for gyrocompassing (coarse)"),
        fmt: str = typer.Option("auto", "--format", help=FORMAT_HELP),
        topic: str | None = typer.Option(None, help="IMU topic of a bag"),
        out: Path = typer.Option(Path("align_out"), "--out", help="results folder"),
    ) -> None:
        """Estimate attitude and the IMU's remaining biases; write them, plots and the corrected IMU."""
        log = load_log(log_path, None, fmt, topic, None, None, None).to_si()
        t = log.t_s
        k_still = max(int(np.searchsorted(t, t_still)), 10)
        ca = coarse_align(log.accel[:k_still], log.gyro[:k_still], log.rate_hz,
                          None if lat_deg is None else np.deg2rad(lat_deg))  # fmt: skip
        if method == "coarse":
            rows = [["roll", f"{np.rad2deg(ca.roll):.3f}", f"{np.rad2deg(ca.roll_pitch_std):.2g}", "deg"],
                    ["pitch", f"{np.rad2deg(ca.pitch):.3f}", f"{np.rad2deg(ca.roll_pitch_std):.2g}", "deg"],
                    ["yaw", "unobservable" if ca.yaw is None else f"{np.rad2deg(ca.yaw):.2f}",
                     "-" if ca.yaw_std is None else f"{np.rad2deg(ca.yaw_std):.2g}", "deg"]]  # fmt: skip
            console.print(table("Coarse alignment", ["quantity", "value", "1-sigma", "unit"], rows))
            console.print(ca.reason)
            write_json(out / "alignment.json", {"method": "coarse", **{k: v for k, v in ca.__dict__.items() if k != "R_n_b"},
                                                "R_n_b": ca.R_n_b.tolist()})  # fmt: skip
            return
        if aiding == "zupt":
            ta = np.arange(0.1, t[-1], 0.1)
            aid = Aiding(ta, "zupt", np.zeros((len(ta), 3)), aiding_std)
            p0 = np.zeros(3)
        else:
            tr = read_tum(aiding)
            ta = (tr.t_ns - log.t_ns[0]) * 1e-9
            keep = (ta > 0) & (ta < t[-1])
            if keep.sum() < 3:
                raise InputError(f"{aiding}: fewer than 3 positions inside the IMU log's time span")
            aid = Aiding(ta[keep], "position", tr.p_w[keep], aiding_std)
            p0 = tr.p_w[keep][0]
        init = NavState(p0, np.zeros(3), ca.R_n_b)
        if method not in ("kf", "stkf", "rwnn"):
            raise InputError(f"--method: '{method}'; expected coarse, kf, stkf or rwnn")
        res = run_alignment(log, aid, init, method)  # type: ignore[arg-type]
        tt, ba, bg, sa, sg = (
            res.t_s,
            res.accel_bias,
            res.gyro_bias,
            res.accel_bias_std,
            res.gyro_bias_std,
        )
        rows = [
            [f"accel bias {'xyz'[j]}", f"{ba[-1, j]:+.5f}", f"{sa[-1, j]:.2g}", "m/s^2"]
            for j in range(3)
        ]
        rows += [
            [f"gyro bias {'xyz'[j]}", f"{bg[-1, j]:+.6f}", f"{sg[-1, j]:.2g}", "rad/s"]
            for j in range(3)
        ]
        console.print(
            table(
                f"Alignment ({method}, {aid.kind} aiding)",
                ["quantity", "estimate", "1-sigma", "unit"],
                rows,
            )
        )
        fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
        for ax, b, s_, name in (
            (axes[0], ba, sa, "accel bias [m/s^2]"),
            (axes[1], bg, sg, "gyro bias [rad/s]"),
        ):
            for j in range(3):
                ax.plot(tt, b[:, j], color=f"C{j}", label="xyz"[j])
                if np.all(np.isfinite(s_[:, j])):
                    ax.fill_between(
                        tt, b[:, j] - s_[:, j], b[:, j] + s_[:, j], color=f"C{j}", alpha=0.2
                    )
            ax.set_ylabel(name)
            ax.legend()
        axes[1].set_xlabel("time [s]")
        save_figure(fig, out / "biases.png")
        write_json(out / "alignment.json", {"method": method, "aiding": aid.kind, "accel_bias": ba[-1].tolist(),
                                            "accel_bias_std": sa[-1].tolist(), "gyro_bias": bg[-1].tolist(),
                                            "gyro_bias_std": sg[-1].tolist(), "coarse_reason": ca.reason})  # fmt: skip
        corrected = log.slice(0, len(log))
        corrected.accel = corrected.accel - ba[-1]
        corrected.gyro = corrected.gyro - bg[-1]
        write_imu(corrected, out / "corrected_imu.csv", "euroc")
        console.print(f"wrote {out}/alignment.json, biases.png, corrected_imu.csv (EuRoC format)")
