"""The ``imuslam`` command line: thin typer commands over library functions.

Each command lives in its own module of this package (a ``register(app)`` function) and is loaded only
when it runs: ``imuslam --help`` lists the commands from :data:`COMMANDS` without importing any of them,
so neither numba, scipy, matplotlib nor rosbags is loaded to print the help. A new command is one line
in :data:`COMMANDS` (``tests/cli/test_startup.py`` checks that its help line matches the command's).
"""

from __future__ import annotations

import importlib
import logging
from typing import Any

import typer
from typer.core import TyperCommand, TyperGroup

# name -> (module in imuslam.cli, one-line help as the command's docstring starts), in the help's order.
COMMANDS: dict[str, tuple[str, str]] = {
    "calibrate": (
        "calibrate",
        "Calibrate accelerometer and gyroscope from a log of static poses: a joint fit of both "
        "(default) or imu_tk's two steps (--method tedaldi, Tedaldi 2014).",
    ),
    "correct": (
        "correct",
        "Write the corrected IMU (m/s^2, rad/s, body frame); a bag keeps every other message untouched.",
    ),
    "allan": (
        "allan",
        "Overlapped Allan deviation per axis: noise density, bias instability, random walk, Kalibr yaml.",
    ),
    "align": (
        "align",
        "Estimate attitude and the IMU's remaining biases; write them, plots and the corrected IMU.",
    ),
    "eval": (
        "evaluate",
        "APE and RPE with SE(3)/Sim(3)/yaw-only alignment; metrics.json, plots, aligned TUM.",
    ),
    "simulate": (
        "simulate",
        "Simulate a robot (room, street, corridor, handheld, gimbal) with every sensor and the truth.",
    ),
    "online": (
        "online",
        "Calibrate with the gimbal, publish, watch for drift in still moments, recalibrate.",
    ),
    "demo": (
        "demo",
        "A simulated robot IMU with seed 000's errors, turned through gimbal poses and calibrated.",
    ),
    "score": (
        "score",
        "Score calibrations on a log: gravity-norm error per static pose, gyro-predicted gravity-direction "
        "error per pair of poses (RMS and worst), on poses found without any calibration.",
    ),
    "study": (
        "study",
        "Run a study: cells on Dask, results.parquet/.csv, report.html per claim; or a study of "
        "recorded logs (a YAML with 'logs'): the estimator once per calibration, maps and "
        "trajectories compared.",
    ),
    "vio": (
        "vio",
        "Stereo VO + IMU EKF: trajectory.tum (fused), vo.tum, imu.tum, metrics.json, plots.",
    ),
    "map2d": (
        "map2d",
        "Map a 2D laser log: trajectory.tum, map.pgm/map.yaml (map_server), map.png, config.yaml.",
    ),
    "lio": (
        "lio",
        "LiDAR-inertial odometry (iterated ESKF) with a voxel map; LiDAR-only without an IMU.",
    ),
    "calibrate-lidar": (
        "calibrate_lidar",
        "Calibrate the LiDAR pose on the IMU and the clock offset without a target (LI-Init's method).",
    ),
    "view": (
        "view",
        "Show results folders in the rerun viewer: trajectory, map, occupancy grid and metrics.",
    ),
}


def load_command(name: str) -> Any:
    """Import the module of command ``name`` and return its click command (built once per call)."""
    module = importlib.import_module(f"imuslam.cli.{COMMANDS[name][0]}")
    sub = typer.Typer(add_completion=False)
    module.register(sub)
    return typer.main.get_command(sub)


class _LazyGroup(TyperGroup):
    """A typer group whose commands are imported when one is run or asked for its own help.

    Listing (``imuslam --help``) sees placeholders carrying the name and the help line; resolving a
    command on the command line swaps in the real one.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._loaded: dict[str, Any] = {}

    def list_commands(self, ctx: Any) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name in self._loaded:
            return self._loaded[cmd_name]
        if cmd_name not in COMMANDS:
            return None
        return TyperCommand(cmd_name, help=COMMANDS[cmd_name][1])

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        name, cmd, rest = super().resolve_command(ctx, args)
        if name is not None and name not in self._loaded:
            self._loaded[name] = load_command(name)
        return name, (self._loaded[name] if name is not None else cmd), rest


app = typer.Typer(
    name="imuslam",
    help="IMU calibration without external equipment, INS alignment and IMU-aided SLAM.",
    no_args_is_help=True,
    add_completion=False,
    cls=_LazyGroup,
)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log debug messages."),
) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )


class _Deferred(type):
    """A stand-in for a rich class that imports its module when first used (called, or an attribute
    read: ``Traceback.from_exception``)."""

    _where: tuple[str, str]

    def _real(cls) -> Any:
        return getattr(importlib.import_module(cls._where[0]), cls._where[1])

    def __getattr__(cls, attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        return getattr(cls._real(), attr)

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        return cls._real()(*args, **kwargs)


def _import_typer_help_lightly() -> None:
    """Import typer's help renderer without the two rich modules it names at its top and a help
    does not use: ``rich.markdown`` (markdown_it, pygments; for the markdown markup mode, not ours)
    and ``rich.traceback`` (rich.pretty, attrs; for a crash's pretty traceback). Together they are
    about a third of a ``--help``'s start-up. The renderer gets stand-ins that import the real class
    when it is first used; the real modules stay importable as before. Anything unexpected (another
    typer's renderer naming other names) falls back to the plain import."""
    import sys
    import types

    if "typer.rich_utils" in sys.modules:
        return
    stand_ins = {
        mod: name
        for mod, name in (("rich.markdown", "Markdown"), ("rich.traceback", "Traceback"))
        if mod not in sys.modules
    }
    for mod, name in stand_ins.items():
        shim = types.ModuleType(mod)
        setattr(shim, name, _Deferred(name, (), {"_where": (mod, name)}))
        sys.modules[mod] = shim
    try:
        importlib.import_module("typer.rich_utils")
    except Exception:
        sys.modules.pop("typer.rich_utils", None)
    finally:
        for mod in stand_ins:
            sys.modules.pop(mod, None)


def main() -> None:
    """Console-script entry point."""
    import sys

    from imuslam.threads import configure_process

    configure_process()  # before any command imports numpy or numba
    from imuslam.cli.common import install_signal_handlers

    install_signal_handlers()
    if len(sys.argv) < 2 or "--help" in sys.argv:
        _import_typer_help_lightly()
    app()
