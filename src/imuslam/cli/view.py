"""``imuslam view``: results folders in the rerun viewer (spawned), or in a recording (``--rrd``)."""

from __future__ import annotations

from pathlib import Path

import typer

from imuslam.cli.common import console, friendly_errors


def register(app: typer.Typer) -> None:
    @app.command("view")
    @friendly_errors
    def view_cmd(
        folders: list[Path] = typer.Argument(
            ..., help="results folders (lio, map2d, vio, eval, ...); several are shown together"
        ),
        rrd: Path | None = typer.Option(
            None,
            "--rrd",
            help="write a recording to this new .rrd file instead of opening the viewer",
        ),
    ) -> None:
        """Show results folders in the rerun viewer: trajectory, map, occupancy grid and metrics."""
        from imuslam.viz.recording import open_recording
        from imuslam.viz.view import check_folders, log_folders

        check_folders(folders)
        title = "imuslam view " + " ".join(f.name for f in folders)
        with open_recording(title, rrd, viewer=rrd is None) as rec:
            shown = log_folders(rec, folders)
        for name, files in shown.items():
            console.print(f"{name}: {', '.join(files)}", markup=False, highlight=False)
        if rrd is not None:
            console.print(f"wrote {rrd} (open it with: rerun {rrd})", markup=False, highlight=False)
