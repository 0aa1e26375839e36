"""``imuslam simulate``: a simulated robot with ground truth, written as an MCAP bag, TUM and .npz."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import typer

from imuslam.cli import validate
from imuslam.cli.common import console, friendly_errors, progress_option, show_progress


class Scenario(StrEnum):
    """``imuslam.sim.scenario.SCENARIOS`` (tests/cli/test_startup.py checks they agree)."""

    room = "room"
    street = "street"
    corridor = "corridor"
    handheld = "handheld"
    gimbal = "gimbal"


#: An hour of simulated robot takes minutes to hours on 2 cores (60 s of a VLP-16: 20 s).
MAX_DURATION_S = 3600.0


def register(app: typer.Typer) -> None:
    @app.command("simulate")
    @friendly_errors
    def simulate_cmd(
        scenario: Scenario = typer.Argument(..., help=f"one of {', '.join(Scenario)}"),
        duration: float = typer.Option(
            60.0,
            "--duration",
            help=f"simulated time, s (at most {MAX_DURATION_S:g})",
            callback=validate.positive("s", hi=MAX_DURATION_S),
        ),
        out: Path = typer.Option(
            Path("sim_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
        seed: int = typer.Option(0, help="random seed (>= 0)", callback=validate.integer(lo=0)),
        rotating_platform: bool = typer.Option(
            False, help="street: IMU on a 10 Hz rotating platform"
        ),
        progress: bool = progress_option(),
    ) -> None:
        """Simulate a robot (room, street, corridor, handheld, gimbal) with every sensor and the truth."""
        from imuslam.io.results import results_folder
        from imuslam.sim.scenario import run_scenario

        with results_folder(out) as tmp:
            res = run_scenario(
                scenario.value, duration, tmp, seed, rotating_platform, show_progress(progress)
            )
        names = ", ".join(str(out / Path(f).relative_to(tmp)) for f in res.files)
        console.print(f"wrote {res.counts.get('messages', 0)} messages: {names}")
