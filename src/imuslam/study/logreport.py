"""The report of a log study: per log, a table of its runs (map sharpness without ground truth, the
trajectory against the reference run and against the truth), the maps side by side and the
trajectories; written as report.md, report.html (figures inline), results.csv, study.yaml and each
run's trajectory (``<log>/<run>.tum``), like the report of a study over the simulator."""

from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from imuslam.interfaces import Trajectory
from imuslam.io.atomic import write_atomic
from imuslam.study.logconfig import LogSpec, LogStudyConfig
from imuslam.study.report import fmt_number, md_table_html


@dataclass
class RunResult:
    """One run: its trajectory, its metrics, and for map2d the map (probability grid) and the hits."""

    log: str
    run: str
    imu: str
    trajectory: Trajectory
    metrics: dict[str, float]
    grid: Any = None
    wall_s: float = 0.0
    imu_track: Trajectory | None = None  # vio: the IMU alone from the filter's first state


@dataclass
class LogStudyRun:
    """Every run of every log, in the study's order."""

    runs: list[RunResult] = field(default_factory=list)


#: The report's columns: (metric key, header with its unit).
COLUMNS = (
    ("wall_spread_cm", "wall spread [cm]"),
    ("map_entropy", "map entropy [nats]"),
    ("occupied_cells", "occupied cells"),
    ("ref_ate_m", "ATE vs reference [m]"),
    ("ref_ate_rot_deg", "rot. vs reference [deg]"),
    ("ref_rpe_m", "RPE/frame vs reference [m]"),
    ("gt_ate_m", "ATE vs truth [m]"),
    ("gt_ate_rot_deg", "rot. vs truth [deg]"),
    ("gt_rpe_m", "RPE/frame vs truth [m]"),
    ("gt_imu_ate_m", "IMU alone: ATE vs truth [m]"),
    ("gt_imu_ate_rot_deg", "IMU alone: rot. vs truth [deg]"),
    ("path_length_m", "path [m]"),
)


def _num(x: float) -> str:
    """A figure; a difference below 1e-12 (a run against itself, round-off) as 0."""
    return "0" if np.isfinite(x) and abs(x) < 1e-12 else fmt_number(x)


#: The terminal's shorter table leaves these out (they are in report.md and results.csv).
LONG_ONLY = ("ref_rpe_m", "gt_rpe_m", "gt_imu_ate_rot_deg", "path_length_m")


def table_rows(
    spec: LogSpec, runs: list[RunResult], imu: bool = True
) -> tuple[list[str], list[list[str]]]:
    """Header and rows of one log's table (the columns some run has). ``imu``: the whole table, with
    the column that says what IMU each run got; else the terminal's (without :data:`LONG_ONLY`)."""
    cols = [(k, h) for k, h in COLUMNS if any(k in r.metrics for r in runs)]
    if not imu:
        cols = [(k, h) for k, h in cols if k not in LONG_ONLY]
    head = ["run", *(["IMU"] if imu else []), *[h for _, h in cols]]
    rows = [[r.run, *([r.imu] if imu else []), *[_num(r.metrics.get(k, float("nan"))) for k, _ in cols]]
            for r in runs]  # fmt: skip
    return head, rows


def markdown(spec: LogSpec, runs: list[RunResult]) -> str:
    head, rows = table_rows(spec, runs)
    lines = [f"#### {spec.name}: {spec.estimator} on {Path(spec.path).name}", "",
             f"Reference run: {spec.reference_run}; trajectories {spec.align}-aligned."
             + (f" Truth: {Path(spec.gt).name}." if spec.gt else " No ground truth given."), "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]  # fmt: skip
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    if spec.estimator == "map2d":
        lines += ["", "Map sharpness without ground truth: the hits' RMS distance from their local wall and "
                  f"the mean map entropy within {spec.radius_m or 0.2:g} m, the output map's occupied cells; "
                  "lower is crisper."]  # fmt: skip
    elif spec.estimator == "lio":
        lines += ["", "Map sharpness without ground truth: the map points' RMS distance from their local "
                  f"plane (the square root of the mean plane variance) and the mean map entropy within "
                  f"{spec.radius_m or 0.3:g} m; lower is crisper."]  # fmt: skip
    else:
        lines += ["", "VIO keeps no map: its runs are compared by trajectory; 'IMU alone' integrates the "
                  "run's IMU from the filter's first state."]  # fmt: skip
    return "\n".join(lines) + "\n"


def figure_png(spec: LogSpec, runs: list[RunResult]) -> bytes:
    """The runs' maps side by side (map2d), and their trajectories in the plane."""
    from matplotlib.figure import Figure

    maps = [r for r in runs if r.grid is not None]
    n = len(maps) + 1
    fig = Figure(figsize=(min(4.0 * n, 20), 4.4))
    for i, r in enumerate(maps):
        ax = fig.add_subplot(1, n, i + 1)
        pr, known, x0, y0 = r.grid.cropped_known()
        img = np.where(known, 1.0 - pr, 0.5)
        res = r.grid.params.resolution
        ax.imshow(img, cmap="gray", origin="lower", vmin=0, vmax=1,
                  extent=(x0, x0 + img.shape[1] * res, y0, y0 + img.shape[0] * res))  # fmt: skip
        ax.plot(r.trajectory.p_w[:, 0], r.trajectory.p_w[:, 1], "-", color="C1", lw=0.8)
        c = r.trajectory.p_w[:, :2].mean(
            axis=0
        )  # the walls near the path, where the scans are dense
        ax.set_xlim(c[0] - 6, c[0] + 6)
        ax.set_ylim(c[1] - 6, c[1] + 6)
        ax.set_title(
            f"{r.run}: {fmt_number(r.metrics.get('wall_spread_cm', float('nan')))} cm", fontsize=9
        )
        ax.set_aspect("equal")
    ax = fig.add_subplot(1, n, n)
    for r in runs:
        ax.plot(r.trajectory.p_w[:, 0], r.trajectory.p_w[:, 1], "-", lw=1, label=r.run)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=8)
    ax.set_title("trajectories (each run's own frame)", fontsize=9)
    fig.suptitle(spec.name, fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()


def frame(res: LogStudyRun) -> pd.DataFrame:
    return pd.DataFrame(
        [
            {"log": r.log, "run": r.run, "imu": r.imu, **r.metrics, "wall_s": r.wall_s}
            for r in res.runs
        ]
    )


def write_log_outputs(study: LogStudyConfig, res: LogStudyRun, out: Path) -> None:
    """report.md, report.html, results.csv, study.yaml and ``<log>/<run>.tum`` in ``out``."""
    from imuslam.io.trajectory import write_tum

    mds, parts = [], [f"<h1>Study {html.escape(study.name)}</h1>"]
    for spec in study.logs:
        runs = [r for r in res.runs if r.log == spec.name]
        md = markdown(spec, runs)
        mds.append(md)
        png = base64.b64encode(figure_png(spec, runs)).decode()
        parts += [
            md_table_html(md),
            f'<img alt="{html.escape(spec.name)}" src="data:image/png;base64,{png}">',
        ]
        (out / spec.name).mkdir(exist_ok=True)
        for r in runs:
            write_tum(r.trajectory, out / spec.name / f"{r.run}.tum")
    dump = yaml.safe_dump(study.model_dump(mode="json"), sort_keys=False)
    write_atomic(out / "report.md", "\n".join(mds))
    write_atomic(out / "results.csv", frame(res).to_csv(index=False))
    write_atomic(out / "study.yaml", dump)
    parts.append("<h2>Study</h2><pre>" + html.escape(dump) + "</pre>")
    style = ("body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse;margin:8px 0}"
             "td,th{border:1px solid #ccc;padding:2px 6px;font-size:13px}img{max-width:100%}")  # fmt: skip
    write_atomic(out / "report.html", f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(study.name)}"
                 f"</title><style>{style}</style></head><body>{''.join(parts)}</body></html>\n")  # fmt: skip
