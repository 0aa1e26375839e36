"""MATLAB v7.3 logs (``accelBuffer`` / ``gyroBuffer``) read from the command line, told by their header
whatever their name (imu_tk's text logs are named .mat too)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.errors import InputError
from imuslam.io.load import detect_format, load_imu

HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Fri Nov 27 2026 HDF5 schema 1.00 ."


def _mat(path: Path, key: str, buf: np.ndarray) -> Path:
    import h5py

    with h5py.File(path, "w", userblock_size=512) as h:
        h[key] = buf.T  # MATLAB stores 4 x N as N x 4 in HDF5's order
    with open(path, "r+b") as f:
        f.write(HEADER.ljust(116))
    return path


def _static(tmp_path: Path) -> tuple[Path, Path]:
    """A still MPU6050-like log in g and deg/s: 100 Hz, 300 s, white noise 0.002 g and 0.05 deg/s per
    sample (densities 2e-4 g/sqrt(Hz), 5e-3 deg/s/sqrt(Hz))."""
    rng = np.random.default_rng(7)
    n = 30_000
    t = np.arange(n) * 0.01
    acc = rng.normal(size=(n, 3)) * 0.002 + [0.0, 0.0, 1.0]
    gyr = rng.normal(size=(n, 3)) * 0.05
    a = _mat(tmp_path / "acc.mat", "accelBuffer", np.vstack([t, acc.T]))
    g = _mat(tmp_path / "gyro.mat", "gyroBuffer", np.vstack([t, gyr.T]))
    return a, g


def test_a_v73_file_is_told_by_its_header_and_read_in_the_buffers_units(tmp_path: Path) -> None:
    a, g = _static(tmp_path)
    assert detect_format(a) == "matlab"
    log_ = load_imu(a, g)
    assert (log_.accel_unit, log_.gyro_unit) == ("g", "deg/s")
    assert len(log_) == 30_000
    assert any("deg/s, the MATLAB buffers' convention" in w for w in log_.warnings)


def test_allan_reads_a_v73_log_from_the_command_line(tmp_path: Path) -> None:
    a, g = _static(tmp_path)
    out = tmp_path / "allan"
    r = CliRunner().invoke(app, ["allan", str(a), str(g), "--out", str(out)])
    assert r.exit_code == 0, r.output
    terms = json.loads((out / "metrics.json").read_text())["terms"]
    white = {t["sensor"]: t["white"] for t in terms}
    # densities in SI: 2e-4 g/sqrt(Hz) = 1.96e-3 m/s^2/sqrt(Hz); 5e-3 deg/s/sqrt(Hz) = 8.7e-5 rad/s/sqrt(Hz)
    # (the estimate of 30000 samples is good to about 1 %)
    assert white["accel"] == pytest.approx(2e-4 * 9.80665, rel=0.05)
    assert white["gyro"] == pytest.approx(np.deg2rad(5e-3), rel=0.05)


def test_a_v5_file_is_named_with_what_to_do(tmp_path: Path) -> None:
    p = tmp_path / "old.mat"
    p.write_bytes(b"MATLAB 5.0 MAT-file, Platform: PCWIN".ljust(128) + b"\x00" * 64)
    with pytest.raises(InputError, match=r"MATLAB v5 \.mat file; imuslam reads v7\.3"):
        detect_format(p)
