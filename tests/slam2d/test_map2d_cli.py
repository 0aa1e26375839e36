"""``imuslam map2d``: the results folder on a simulated room, bad logs as one line, counted warnings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from slam2d_helpers import _flaser


@pytest.mark.slow
def test_map2d_cli_on_simulated_room(tmp_path: Path) -> None:
    """imuslam simulate room -> imuslam map2d --gt: every output file, the trajectory one pose per scan with
    the log's stamps, ATE below one grid cell; a bad --config is one line with exit 2 and no folder."""
    from typer.testing import CliRunner

    from imuslam.cli import app

    runner = CliRunner()
    sim = tmp_path / "sim"
    r = runner.invoke(app, ["simulate", "room", "--duration", "20", "--out", str(sim)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "map"
    r = runner.invoke(
        app,
        [
            "map2d",
            str(sim),
            "--out",
            str(out),
            "--gt",
            str(sim / "ground_truth.tum"),
            "--no-progress",
        ],
    )
    assert r.exit_code == 0, r.output
    for f in ("trajectory.tum", "map.pgm", "map.yaml", "map.png", "config.yaml", "metrics.json"):
        assert (out / f).is_file(), f
    import json

    s = json.loads((out / "metrics.json").read_text())
    assert s["scans"] == 200
    # every match above the minimum score is a constraint or counted as rejected
    assert s["loop_candidates"] == s["loop_constraints"] + s["loop_inconsistent"]
    assert s["loop_ambiguous"] >= 0
    rows = np.loadtxt(out / "trajectory.tum")
    stamps = np.load(sim / "sim.npz")["scan_t_ns"]
    assert rows.shape == (200, 8)
    assert np.allclose(rows[:, 0], stamps * 1e-9, atol=1e-6)
    assert s["metrics"]["slam"]["ate_rmse_m"] < 0.05
    bad = tmp_path / "bad.yaml"
    bad.write_text("resolution: -1\n")
    r = runner.invoke(app, ["map2d", str(sim), "--out", str(tmp_path / "no"), "--config", str(bad)])
    assert r.exit_code == 2
    assert "resolution" in r.output
    assert not (tmp_path / "no").exists()


@pytest.mark.parametrize(
    ("case", "text", "expected"),
    [
        ("no scans", "ODOM 0 0 0 0 0 0 1.0 host 1.0\n", "no laser scans"),
        ("malformed", "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.0 h 1.0\nFLASER 3 1.0 x\n", "log.clf:2"),
        (
            "unsorted",
            "".join(_flaser(10.0 - k, ["1.0"] * 3, (0, 0, 0)) for k in range(10)),
            "not in time order",
        ),
    ],
)
def test_map2d_cli_bad_log_is_one_line_and_no_output(
    tmp_path: Path, case: str, text: str, expected: str
) -> None:
    """Each bad CARMEN log: exit 2, one line naming the file and what is wrong, no results folder."""
    from typer.testing import CliRunner

    from imuslam.cli import app

    f = tmp_path / "log.clf"
    f.write_text(text)
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["map2d", str(f), "--out", str(out), "--no-progress"])
    assert r.exit_code == 2, (case, r.output)
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1, (case, r.output)
    assert expected in lines[0] and "log.clf" in lines[0], (case, lines[0])
    assert "Traceback" not in r.output
    assert not out.exists()


def test_map2d_cli_counts_bad_readings_and_odometry_jumps(tmp_path: Path) -> None:
    """A log of a robot standing 3 m from a round wall with 4 bad readings (inf, NaN, 90 m beyond the
    30 m range, a negative one) and one odometry jump (5 m in 0.1 s): the map is made, each counted once in
    metrics.json and the printed table, the jump replaced by no motion (the pose stays at the start)."""
    import json

    from typer.testing import CliRunner

    from imuslam.cli import app

    rng = np.random.default_rng(0)
    lines = []
    for k in range(40):
        r = [f"{3.0 + 0.01 * rng.standard_normal():.3f}" for _ in range(180)]
        if k == 5:
            r[10], r[20] = "inf", "nan"
        if k == 7:
            r[30], r[40] = "90.0", "-1.0"
        odom = (5.0, 0.0, 0.0) if k >= 20 else (0.0, 0.0, 0.0)  # the jump between scans 19 and 20
        lines.append(_flaser(100.0 + 0.1 * k, r, odom))
    f = tmp_path / "log.clf"
    f.write_text("".join(lines))
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["map2d", str(f), "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    s = json.loads((out / "metrics.json").read_text())
    assert s["warnings"]["readings dropped (inf/NaN/out of range)"] == 4
    assert s["warnings"]["odometry jumps (step replaced by no motion)"] == 1
    assert "odometry jumps" in res.output
    traj = np.loadtxt(out / "trajectory.tum")
    # the scans all see the same wall from the same place: every pose within a cell of the first
    assert np.abs(traj[:, 1:3] - traj[0, 1:3]).max() < 0.05
