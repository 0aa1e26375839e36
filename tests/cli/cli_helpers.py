"""What every bad input must give, and small valid inputs to spoil.

``assert_rejected`` is the README's promise as a test: exit code 2 (bad input) or 3 (an estimator
failed), no traceback, one message, naming what was wrong, and nothing left in the output's folder.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from click.testing import Result
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.interfaces.imu import ImuLog
from imuslam.io.rosbag import write_imu_bag

runner = CliRunner()
_BOX = re.compile(r"[\s│╭╮╰╯─]")


def run(args: Sequence[str | Path]) -> Result:
    return runner.invoke(app, [str(a) for a in args])


def compact(text: str) -> str:
    """The output without whitespace and rich's box characters (a long path may wrap in a panel)."""
    return _BOX.sub("", text)


def assert_rejected(
    r: Result,
    names: Sequence[str],
    out_dir: Path | None = None,
    codes: tuple[int, ...] = (2, 3),
) -> None:
    """Exit 2 or 3, no traceback, exactly one message naming one of ``names`` (a file, an option),
    and ``out_dir`` holds no output (nor a temporary sibling) afterwards."""
    out = r.output
    assert r.exit_code in codes, f"exit {r.exit_code}: {out!r} {r.exception!r}"
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in out
    n_msgs = out.count("error:") + out.count("Invalid value") + out.count("Missing ")
    assert n_msgs == 1, out
    c = compact(out)
    assert any(compact(n) in c for n in names), f"none of {names} in {out!r}"
    if out_dir is not None:
        left = [p.name for p in out_dir.iterdir() if p.name.startswith((".", "out"))]
        assert not left, f"left behind: {left}"


def imu_rows(n: int = 200, rate_hz: float = 100.0, seed: int = 0) -> np.ndarray:
    """(n, 7) ``t ax ay az gx gy gz`` of a still IMU, m/s^2 and rad/s, with white noise."""
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.arange(n) / rate_hz
    acc = rng.normal(0.0, 0.02, (n, 3)) + [0.0, 0.0, 9.81]
    gyr = rng.normal(0.0, 0.002, (n, 3))
    return np.column_stack([t, acc, gyr])


def imu_text(rows: np.ndarray) -> list[list[str]]:
    return [[f"{r[0]:.4f}"] + [f"{v:.6f}" for v in r[1:]] for r in rows]


def tum_rows(n: int = 50, seed: int = 0, still: bool = False) -> np.ndarray:
    """(n, 8) ``t x y z qx qy qz qw`` of a robot driving a curve (or standing, with ``still``)."""
    rng = np.random.default_rng(seed)
    t = 100.0 + 0.1 * np.arange(n)
    yaw = 0.02 * np.arange(n)
    p = np.column_stack([np.cumsum(np.cos(yaw)), np.cumsum(np.sin(yaw)), 0.01 * rng.normal(size=n)])
    if still:
        p[:] = p[0]
    q = np.column_stack([np.zeros(n), np.zeros(n), np.sin(yaw / 2), np.cos(yaw / 2)])
    return np.column_stack([t, p, q])


def write_rows(path: Path, rows: list[list[str]]) -> Path:
    path.write_text("".join(" ".join(r) + "\n" for r in rows))
    return path


def write_calibration(path: Path, accel_unit: str = "m/s^2", gyro_unit: str = "rad/s") -> Path:
    """A near-identity calibration (1 % scale, small biases) for logs in the given units."""
    ka = 1.01 * (9.80665 / 2048 if accel_unit == "counts" else 1.0)
    kg = 1.01 * (np.pi / 180 / 16.4 if gyro_unit == "counts" else 1.0)
    cal = ImuCalibration(
        TriadModel(np.eye(3), np.full(3, ka), np.full(3, 0.01)),
        TriadModel(np.eye(3), np.full(3, kg), np.full(3, 0.001)),
        accel_unit=accel_unit,
        gyro_unit=gyro_unit,
    )
    cal.save_yaml(path)
    return path


def write_bag(path: Path, rows: np.ndarray, topic: str = "/imu/data") -> Path:
    """``rows`` (N, 7) as sensor_msgs/Imu in a bag (the kind from the suffix); NaN is written as is."""
    log = ImuLog(np.round(rows[:, 0] * 1e9).astype(np.int64), rows[:, 1:4], rows[:, 4:7])
    write_imu_bag(log, path, topic=topic)
    return path
