"""``imuslam eval``: ATE / RPE of an estimate against a reference, as evo computes them."""

from __future__ import annotations

from pathlib import Path

import typer

from imuslam.cli import validate
from imuslam.cli.common import console, friendly_errors, table, write_json
from imuslam.errors import InputError
from imuslam.eval.align import ALIGN_METHODS
from imuslam.io.trajectory import TRAJ_FORMATS


def register(app: typer.Typer) -> None:
    @app.command("eval")
    @friendly_errors
    def eval_cmd(
        gt: Path = typer.Argument(..., help="reference trajectory"),
        est: Path = typer.Argument(..., help="estimated trajectory"),
        fmt: str = typer.Option(
            "tum",
            "--format",
            help="tum, kitti, euroc or bag (both files)",
            callback=validate.choice(TRAJ_FORMATS),
        ),
        est_format: str | None = typer.Option(
            None,
            help="format of the estimate if it differs",
            callback=validate.choice(TRAJ_FORMATS),
        ),
        align: str = typer.Option(
            "se3",
            "--align",
            help="se3, sim3, yaw (4-DoF), first or none",
            callback=validate.choice(ALIGN_METHODS),
        ),
        rpe_delta: float = typer.Option(1.0, help="RPE pair spacing", callback=validate.positive()),
        rpe_unit: str = typer.Option(
            "frames", help="frames or m", callback=validate.choice(("frames", "m"))
        ),
        max_diff: float = typer.Option(
            0.01, help="association: max time difference, s", callback=validate.positive("s")
        ),
        kitti: bool = typer.Option(False, help="also KITTI drift over 100..800 m segments"),
        topic: str | None = typer.Option(None, help="pose topic of a bag"),
        gt_times: Path | None = typer.Option(None, help="KITTI times file of the reference"),
        out: Path = typer.Option(
            Path("eval_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
    ) -> None:
        """APE and RPE with SE(3)/Sim(3)/yaw-only alignment; metrics.json, plots, aligned TUM."""
        from imuslam.eval.metrics import KITTI_LENGTHS, evaluate
        from imuslam.eval.plots import plot_evaluation
        from imuslam.io.results import results_folder
        from imuslam.io.trajectory import read_trajectory, write_tum

        if align not in ALIGN_METHODS:
            raise InputError(f"--align: '{align}'; expected one of {', '.join(ALIGN_METHODS)}")
        ef = est_format or fmt
        ref = read_trajectory(gt, fmt, topic, gt_times)
        e = read_trajectory(est, ef, topic)
        by_index = fmt == "kitti" and ef == "kitti" and gt_times is None
        res, r, ea = evaluate(
            ref, e, align, rpe_delta, rpe_unit, max_diff,  # type: ignore[arg-type]
            KITTI_LENGTHS if kitti else None, by_index=by_index,
        )  # fmt: skip
        rows = []
        for name, st, unit in (
            ("APE translation", res.ape_trans, "m"),
            ("APE rotation", res.ape_rot_deg, "deg"),
            (f"RPE translation ({res.rpe_delta:g} {res.rpe_unit})", res.rpe_trans, "m"),
            (f"RPE rotation ({res.rpe_delta:g} {res.rpe_unit})", res.rpe_rot_deg, "deg"),
        ):
            rows.append([name, f"{st.rmse:.6g}", f"{st.mean:.6g}", f"{st.median:.6g}", f"{st.std:.6g}",
                         f"{st.max:.6g}", unit])  # fmt: skip
        for L, (tp, _rd, n) in res.kitti.items():
            rows.append([f"KITTI drift {L:g} m ({n} segments)", f"{tp:.4g}", "", "", "", "", "%"])
        console.print(table(f"{est} vs {gt}: {res.n_pairs} pairs, {res.align} (scale {res.scale:.6g})",
                            ["quantity", "rmse", "mean", "median", "std", "max", "unit"], rows))  # fmt: skip
        with results_folder(out) as tmp:
            write_json(tmp / "metrics.json", res.to_dict())
            write_json(tmp / "config.json", {"gt": str(gt), "est": str(est), "format": fmt, "est_format": ef,
                                             "align": align, "rpe_delta": rpe_delta, "rpe_unit": rpe_unit,
                                             "max_diff_s": max_diff, "kitti": kitti})  # fmt: skip
            write_tum(ea, tmp / "estimate_aligned.tum")
            plot_evaluation(res, r, ea, tmp)
        console.print(f"wrote {out}/metrics.json, trajectories.png, ape.png, estimate_aligned.tum")
