"""``imuslam eval``: ATE / RPE of an estimate against a reference, as evo computes them."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer

from imuslam.cli import validate
from imuslam.cli.common import console, friendly_errors, table


class TrajFormat(StrEnum):
    auto = "auto"
    tum = "tum"
    kitti = "kitti"
    euroc = "euroc"
    bag = "bag"


class Align(StrEnum):
    se3 = "se3"
    sim3 = "sim3"
    yaw = "yaw"
    first = "first"
    none = "none"


class RpeUnit(StrEnum):
    frames = "frames"
    m = "m"


def register(app: typer.Typer) -> None:
    @app.command("eval")
    @friendly_errors
    def eval_cmd(
        gt: Path = typer.Argument(..., help="reference trajectory"),
        est: Path = typer.Argument(..., help="estimated trajectory"),
        fmt: TrajFormat = typer.Option(
            TrajFormat.auto,
            "--format",
            help="auto (TUM, KITTI or EuRoC csv by content, a bag by name), tum, kitti, euroc or bag "
            "(both files)",
        ),
        est_format: TrajFormat | None = typer.Option(
            None, help="format of the estimate if it differs"
        ),
        align: Align = typer.Option(
            Align.se3, "--align", help="se3, sim3, yaw (4-DoF), first or none"
        ),
        rpe_delta: float = typer.Option(1.0, help="RPE pair spacing", callback=validate.positive()),
        rpe_unit: RpeUnit = typer.Option(RpeUnit.frames, help="frames or m"),
        max_diff: float = typer.Option(
            0.01, help="association: max time difference, s", callback=validate.positive("s")
        ),
        kitti: bool = typer.Option(False, help="also KITTI drift over 100..800 m segments"),
        topic: str | None = typer.Option(None, help="pose topic of a bag"),
        gt_times: Path | None = typer.Option(None, help="KITTI times file of the reference"),
        out: Path = typer.Option(
            Path("eval_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
        plots: bool = typer.Option(
            True, "--plots/--no-plots", help="write trajectories.png and ape.png"
        ),
    ) -> None:
        """APE and RPE with SE(3)/Sim(3)/yaw-only alignment; metrics.json, plots, aligned TUM."""
        from imuslam.eval.pipeline import EvalConfig, EvalPipeline
        from imuslam.io.trajectory import detect_trajectory_format, read_trajectory

        gf = detect_trajectory_format(gt) if fmt == TrajFormat.auto and gt.exists() else fmt.value
        ef = (est_format or fmt).value
        ef = detect_trajectory_format(est) if ef == "auto" and est.exists() else ef
        ref = read_trajectory(gt, gf, topic, gt_times)
        e = read_trajectory(est, ef, topic)
        cfg = EvalConfig(
            align=align.value,
            rpe_delta=rpe_delta,
            rpe_unit=rpe_unit.value,
            max_diff_s=max_diff,
            kitti=kitti,
            by_index=gf == "kitti" and ef == "kitti" and gt_times is None,
        )
        pipeline = EvalPipeline(ref, e, cfg)
        res = pipeline.run()
        rows = []
        for name, st, unit in (
            ("APE translation", res.ape_trans, "m"),
            ("APE rotation", res.ape_rot_deg, "deg"),
            (f"RPE translation ({res.rpe_delta:g} {res.rpe_unit})", res.rpe_trans, "m"),
            (f"RPE rotation ({res.rpe_delta:g} {res.rpe_unit})", res.rpe_rot_deg, "deg"),
        ):
            rows.append([f"{name} [{unit}]", f"{st.rmse:.6g}", f"{st.mean:.6g}", f"{st.median:.6g}",
                         f"{st.std:.6g}", f"{st.max:.6g}"])  # fmt: skip
        for L, (tp, _rd, n) in res.kitti.items():
            rows.append([f"KITTI drift {L:g} m ({n} segments) [%]", f"{tp:.4g}", "", "", "", ""])
        console.print(table(f"{est} vs {gt}: {res.n_pairs} pairs, {res.align} (scale {res.scale:.6g})",
                            ["quantity [unit]", "rmse", "mean", "median", "std", "max"], rows))  # fmt: skip
        pipeline.save(res, out, plots, gt=str(gt), est=str(est), format=gf, est_format=ef)
        pngs = "trajectories.png, ape.png, " if plots else ""
        console.print(f"wrote {out}/metrics.json, config.yaml, {pngs}estimate_aligned.tum")
