"""``imuslam simulate``: a simulated robot with ground truth, written as an MCAP bag, TUM and .npz."""

from __future__ import annotations

from pathlib import Path

import typer

from imuslam.cli.common import console, friendly_errors
from imuslam.sim.scenario import SCENARIOS, run_scenario


def register(app: typer.Typer) -> None:
    @app.command("simulate")
    @friendly_errors
    def simulate_cmd(
        scenario: str = typer.Argument(..., help=f"one of {', '.join(SCENARIOS)}"),
        duration: float = typer.Option(60.0, "--duration", help="simulated time, s"),
        out: Path = typer.Option(Path("sim_out"), "--out", help="results folder"),
        seed: int = typer.Option(0, help="random seed"),
        rotating_platform: bool = typer.Option(
            False, help="street: IMU on a 10 Hz rotating platform"
        ),
    ) -> None:
        """Simulate a robot (room, street, corridor, handheld, gimbal) with every sensor and the truth."""
        res = run_scenario(scenario, duration, out, seed, rotating_platform)
        console.print(
            f"wrote {res.counts.get('messages', 0)} messages: {', '.join(str(f) for f in res.files)}"
        )
