"""``open_recording``: the file appears only when the block ends without error, and a viewer that goes
away costs a warning, never the results or the file."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")
from imuslam.viz import recording  # noqa: E402
from imuslam.viz.readback import load  # noqa: E402


def _log(rec: object, n: int) -> None:
    import rerun as rr

    for k in range(n):
        recording.set_time(rec, 1_000_000_000 + k, k)
        rec.log("x", rr.Points3D(np.full((4, 3), float(k))))  # type: ignore[attr-defined]


def test_an_error_in_the_block_leaves_no_file(tmp_path: Path) -> None:
    with (
        pytest.raises(ZeroDivisionError),
        recording.open_recording("t", tmp_path / "a.rrd", False) as rec,
    ):
        _log(rec, 3)
        _ = 1 / 0
    assert list(tmp_path.iterdir()) == []


def test_a_viewer_that_went_away_keeps_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    monkeypatch.setattr(
        recording, "spawn_viewer", lambda rr, rec: None
    )  # nobody listens on the port
    with (
        caplog.at_level(logging.WARNING),
        recording.open_recording("t", tmp_path / "a.rrd", True) as rec,
    ):
        _log(rec, 5)
    assert "could not be reached" in caplog.text
    x = load(tmp_path / "a.rrd")["/x"]
    assert x.rows == 5
    np.testing.assert_array_equal(x.times_ns(), 1_000_000_000 + np.arange(5))
