"""The ``imuslam`` command line: thin typer commands over library functions.

Each command lives in its own module of this package and is registered here.
"""

from __future__ import annotations

import logging

import typer

app = typer.Typer(
    name="imuslam",
    help="IMU calibration without external equipment, INS alignment and IMU-aided SLAM.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log debug messages."),
) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )


# Command registrations (one line per command module).
from imuslam.cli import align as _align  # noqa: E402
from imuslam.cli import allan as _allan  # noqa: E402
from imuslam.cli import calibrate as _calibrate  # noqa: E402
from imuslam.cli import correct as _correct  # noqa: E402
from imuslam.cli import demo as _demo  # noqa: E402
from imuslam.cli import evaluate as _evaluate  # noqa: E402
from imuslam.cli import online as _online  # noqa: E402
from imuslam.cli import simulate as _simulate  # noqa: E402

for _m in (_calibrate, _correct, _allan, _align, _evaluate, _simulate, _online, _demo):
    _m.register(app)
__import__("imuslam.cli.score", fromlist=["register"]).register(app)
__import__("imuslam.cli.study", fromlist=["register"]).register(app)
__import__("imuslam.cli.vio", fromlist=["register"]).register(app)
__import__("imuslam.cli.map2d", fromlist=["register"]).register(app)
__import__("imuslam.cli.lio", fromlist=["register"]).register(app)


def main() -> None:
    """Console-script entry point."""
    app()
