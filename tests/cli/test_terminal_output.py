"""What the commands print explains itself: units kept in table headers, nothing cut at 80 columns,
each warning once, progress bars only on a terminal and ``--no-progress`` wherever a bar is drawn."""

from __future__ import annotations

import io
import logging

import pytest
from rich.console import Console

from imuslam.cli import common


def _render(t: object, width: int = 80) -> str:
    c = Console(file=io.StringIO(), width=width, emoji=False)
    c.print(t)
    return c.file.getvalue()  # type: ignore[attr-defined]


def test_units_in_headers_survive_and_long_cells_wrap_uncut() -> None:
    path = "/work/shared/data/imu_tk_t265/calib_t265/calibration_of_the_t265_with_a_long_name.yaml"
    t = common.table("score", ["file", "ATE [m]", "norm RMS [m/s^2]"], [[path, "0.004358123", "1"]])
    text = _render(t)
    assert "ATE [m]" in text and "[m/s^2]" in "".join(text.split())
    assert "…" not in text  # nothing cut with an ellipsis
    assert "0.004358123" in text
    first = "".join(ln.split("│")[1].strip() for ln in text.splitlines() if ln.startswith("│"))
    assert first == path  # the whole path, folded over lines
    assert max(len(ln) for ln in text.splitlines()) <= 80


def test_each_warning_is_shown_once(monkeypatch: pytest.MonkeyPatch) -> None:
    buf = io.StringIO()
    handler = logging.StreamHandler(buf)
    root = logging.getLogger()
    root.addHandler(handler)
    out = io.StringIO()
    monkeypatch.setattr(common, "console", Console(file=out, width=200, emoji=False))
    try:
        common.show_warnings_once()
        log = logging.getLogger("imuslam.io.readers")
        log.warning("log.txt: gyro unit not given; guessed rad/s")  # a reader logs it ...
        log.warning("log.txt: gyro unit not given; guessed rad/s")  # ... twice
        # ... and returns it with the result, whose warnings the command prints
        common.print_warnings(["log.txt: gyro unit not given; guessed rad/s", "3 poses dropped"])
        common.print_warnings(["3 poses dropped"])
    finally:
        root.removeHandler(handler)
    shown = buf.getvalue() + out.getvalue()
    assert shown.count("gyro unit not given") == 1
    assert shown.count("3 poses dropped") == 1


def test_progress_only_on_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr("sys.stderr", io.StringIO())
    assert common.show_progress(True) is False  # a log file or a pipe: no bar
    monkeypatch.setattr("sys.stderr", Tty())
    assert common.show_progress(True) is True
    assert common.show_progress(False) is False


@pytest.mark.parametrize("command", ["vio", "map2d", "lio", "study", "simulate"])
def test_every_command_with_a_progress_bar_takes_no_progress(command: str) -> None:
    from typer.testing import CliRunner

    from imuslam.cli import app

    r = CliRunner().invoke(app, [command, "--help"], env={"COLUMNS": "200"})
    assert r.exit_code == 0
    assert "--no-progress" in r.output


def test_lio_says_which_configuration_ran_and_suggests_calibrating_a_raw_imu() -> None:
    from imuslam.cli.lio import describe_run
    from imuslam.lio.config import LioConfig

    cfg = LioConfig()
    raw = describe_run(cfg, has_imu=True, calibrated=False)
    assert raw[0] == (
        f"ran: LiDAR-inertial, IMU raw, state {cfg.filter.state} (18), start alignment "
        f"{cfg.align}, front end {cfg.frontend.mode}"
    )
    assert "--calib" in raw[1]
    calibrated = describe_run(cfg, has_imu=True, calibrated=True)
    assert len(calibrated) == 1 and "IMU calibrated (--calib)" in calibrated[0]
    lidar_only = describe_run(cfg.model_copy(update={"use_imu": False}), False, False)
    assert describe_run(cfg, has_imu=False, calibrated=False) == [
        f"ran: LiDAR-only (constant-velocity model, no IMU), front end {cfg.frontend.mode}"
    ]
    assert lidar_only == [
        f"ran: LiDAR-only (constant-velocity model, --no-imu), front end {cfg.frontend.mode}"
    ]


@pytest.mark.parametrize(
    "option, default", [("--state", "full"), ("--mode", "features"), ("--align", "none")]
)
def test_lio_help_names_the_defaults(option: str, default: str) -> None:
    import re

    from typer.testing import CliRunner

    from imuslam.cli import app

    r = CliRunner().invoke(app, ["lio", "--help"], env={"COLUMNS": "300"})
    line = next(ln for ln in r.output.splitlines() if option in ln)
    assert re.search(rf"default\W[^│]*\b{default}\b", line), line
