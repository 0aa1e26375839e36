"""``imuslam align --rrd`` on a simulated hand-held bag aided by its ground-truth poses: the recording
read back with rerun's reader holds the bias estimates and their 1-sigma of estimates.csv on the IMU's
clock, the filter's poses of trajectory.tum, and the IMU raw and corrected by the final biases."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app

pytest.importorskip("rerun")
from imuslam.viz.readback import load  # noqa: E402

RUNNER = CliRunner()


def tum_stamps_ns(path: Path) -> np.ndarray:
    """The TUM file's stamps as written (9 decimals), exact to the nanosecond."""
    from decimal import Decimal

    rows = [ln.split()[0] for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    return np.array([int(Decimal(r) * 10**9) for r in rows], dtype=np.int64)


def test_align_recording(tmp_path: Path) -> None:
    from imuslam.io.trajectory import read_trajectory
    from imuslam.sim.scenario import run_scenario

    run_scenario("handheld", 6.0, tmp_path / "sim", seed=1, progress=False)
    bag, out, rrd = tmp_path / "sim" / "bag", tmp_path / "a", tmp_path / "align.rrd"
    r = RUNNER.invoke(app, ["align", str(bag), "--topic", "/imu/data", "--aiding", str(bag), "--aiding-topic",
                            "/ground_truth", "--aiding-std", "0.005", "--out", str(out), "--rrd", str(rrd)])  # fmt: skip
    assert r.exit_code == 0, r.output
    rec = load(rrd)
    est = np.loadtxt(out / "estimates.csv", delimiter=",", skiprows=1)
    tum = read_trajectory(out / "trajectory.tum", "tum")
    b = rec["/align/bias/accel"]
    assert b.rows == len(est) == len(tum)
    np.testing.assert_array_equal(b.times_ns(), tum_stamps_ns(out / "trajectory.tum"))
    np.testing.assert_allclose(b.array("Scalars:scalars"), est[:, 1:4], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(rec["/align/bias/accel_1sigma"].array("Scalars:scalars"), est[:, 4:7],
                               rtol=1e-8)  # fmt: skip
    np.testing.assert_allclose(rec["/align/bias/gyro"].array("Scalars:scalars"), est[:, 7:10],
                               rtol=1e-8, atol=1e-12)  # fmt: skip
    np.testing.assert_allclose(
        rec["/world/body"].array("Transform3D:translation"), tum.p_w, atol=2e-5
    )
    m = json.loads((out / "metrics.json").read_text())
    raw = rec["/imu/raw/gyro"].array("Scalars:scalars")
    cor = rec["/imu/corrected/gyro"].array("Scalars:scalars")
    assert raw.shape == cor.shape
    np.testing.assert_allclose(raw - cor, np.broadcast_to(m["gyro_bias"], raw.shape), atol=1e-12)
