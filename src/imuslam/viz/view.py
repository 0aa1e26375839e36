"""Results folders in one recording (``imuslam view``): for each folder ``<name>``, what it holds of
trajectory.tum (``world/<name>/trajectory`` static, ``world/<name>/body`` per pose on the
``sensor_time`` timeline), map.ply or map.pcd (``world/<name>/map``), map.yaml + map.pgm
(``world/<name>/grid``) and metrics.json (``metrics/<name>``, a text document), each folder in its own
colour, so two runs (raw against calibrated) are seen together."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from imuslam.errors import InputError

#: The files a results folder may hold that the viewer shows.
SHOWN = ("trajectory.tum", "map.ply", "map.pcd", "map.yaml", "metrics.json")
COLOURS = [(255, 140, 0), (30, 120, 230), (40, 170, 60), (200, 40, 160), (120, 90, 40)]


def run_names(folders: list[Path]) -> list[str]:
    """One entity name per folder: its name, made unique with its parent's where two share one."""
    names = [f.resolve().name or "run" for f in folders]
    out = []
    for f, n in zip(folders, names, strict=True):
        out.append(f"{f.resolve().parent.name}_{n}" if names.count(n) > 1 else n)
    return [f"{n}_{i}" if out.count(n) > 1 else n for i, n in enumerate(out)]


def check_folders(folders: list[Path]) -> None:
    """Each a folder holding at least one of :data:`SHOWN`, else an InputError naming it."""
    for f in folders:
        if not f.is_dir():
            raise InputError(f"{f}: not a folder; expected an imuslam results folder")
        if not any((f / n).is_file() for n in SHOWN):
            raise InputError(
                f"{f}: holds none of {', '.join(SHOWN)}; expected an imuslam results folder"
            )


def log_folder(rec: Any, folder: Path, name: str, colour: tuple[int, int, int]) -> list[str]:
    """Log what ``folder`` holds under ``world/<name>`` and ``metrics/<name>``; returns the files shown."""
    import rerun as rr

    from imuslam.viz.recording import time_column

    part = rr.escape_entity_path_part(name)
    base, shown = f"world/{part}", []
    tum = folder / "trajectory.tum"
    if tum.is_file():
        from imuslam.io.trajectory import read_trajectory

        tr = read_trajectory(tum, "tum")
        rec.log(f"{base}/trajectory", rr.LineStrips3D([tr.p_w], colors=[colour]), static=True)
        rec.send_columns(
            f"{base}/body",
            indexes=[time_column(rr, tr.t_ns), rr.TimeColumn("pose", sequence=np.arange(len(tr)))],
            columns=rr.Transform3D.columns(translation=tr.p_w, mat3x3=tr.R_w_b),
        )
        rec.log(f"{base}/body", rr.TransformAxes3D(0.3), static=True)
        shown.append(tum.name)
    cloud = next((folder / n for n in ("map.ply", "map.pcd") if (folder / n).is_file()), None)
    if cloud is not None:
        from imuslam.io.pointcloud import pcd_points, read_ply

        pts = read_ply(cloud) if cloud.suffix == ".ply" else pcd_points(cloud)
        grey = np.array(colour) // 2 + 64
        rec.log(f"{base}/map", rr.Points3D(pts, radii=0.03, colors=[grey]), static=True)
        shown.append(cloud.name)
    if (folder / "map.yaml").is_file():
        from imuslam.io.mapfiles import read_map_server
        from imuslam.viz.slam2d import log_grid, occupancy_from_pgm

        img, res, (x0, y0) = read_map_server(folder / "map.yaml")
        log_grid(rr, rec, f"{base}/grid", occupancy_from_pgm(img), res, x0, y0, static=True)
        shown.append("map.yaml")
    if (folder / "metrics.json").is_file():
        try:
            text = json.dumps(json.loads((folder / "metrics.json").read_text()), indent=2)
        except json.JSONDecodeError as exc:
            raise InputError(
                f"{folder / 'metrics.json'}: not JSON ({exc.msg}, line {exc.lineno})"
            ) from None
        rec.log(f"metrics/{part}", rr.TextDocument(text), static=True)
        shown.append("metrics.json")
    return shown


def log_folders(rec: Any, folders: list[Path]) -> dict[str, list[str]]:
    """Every folder in its colour; returns the files shown per entity name."""
    import rerun as rr

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    names = run_names(folders)
    return {n: log_folder(rec, f, n, COLOURS[i % len(COLOURS)])
            for i, (f, n) in enumerate(zip(folders, names, strict=True))}  # fmt: skip
