"""``imuslam online --sim --rrd``: the recording read back with rerun's reader holds every event of
metrics.json at its time, each published calibration's bias terms as the history stores them, and the
drift alarm's figures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app

pytest.importorskip("rerun")
from imuslam.viz.readback import load  # noqa: E402


@pytest.mark.slow  # an hour of robot time: about 10 s of CPU
def test_online_recording(tmp_path: Path) -> None:
    from imuslam.imu.history import CalibrationHistory

    out, rrd = tmp_path / "o", tmp_path / "online.rrd"
    r = CliRunner().invoke(
        app, ["online", "--sim", "--duration-h", "1", "--out", str(out), "--rrd", str(rrd)]
    )
    assert r.exit_code == 0, r.output
    rec = load(rrd)
    events = json.loads((out / "metrics.json").read_text())["events"]
    log = rec["/online/events"]
    assert log.rows == len(events)
    np.testing.assert_allclose(log.times_ns() * 1e-9, [e["t_s"] for e in events], atol=1e-6)
    texts = [t[0] if isinstance(t, list) else t for t in log.columns["TextLog:text"]]
    assert [t.split(":")[0] for t in texts] == [e["kind"] for e in events]
    hist = CalibrationHistory(out / "history")
    cals = [e for e in events if e["kind"] == "calibrated"]
    assert len(cals) == len(hist.versions()) >= 2  # the start, then after the drift alarm
    ab = rec["/online/calibration/accel_bias"].array("Scalars:scalars")
    for row, e in zip(ab, cals, strict=True):
        np.testing.assert_allclose(row, hist.load(e["detail"]["version"]).accel.b, rtol=1e-12)
    drift = [e for e in events if e["kind"] == "drift"]
    assert drift  # the 1 h run with the default bias drift raises one
    got = rec["/online/drift/norm_error"].array("Scalars:scalars")
    np.testing.assert_allclose(got, [e["detail"]["norm_error"] for e in drift], rtol=1e-12)
