"""The runs the viewer's tests read back: a simulated street through ``lio --rrd`` and a simulated room
through ``map2d --rrd``, each once per session."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.interfaces import Trajectory
from imuslam.io.trajectory import write_tum
from imuslam.sim import export
from imuslam.sim.drive import simulate_lidar_drive

RUNNER = CliRunner()
TOPICS = ["--imu-topic", "/imu/data", "--points-topic", "/points"]


@pytest.fixture(scope="session")
def lio_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    d = simulate_lidar_drive("street", 3.0, seed=5)
    root = tmp_path_factory.mktemp("viz_lio")
    pc = [(s.t_ns, "/points", export.pointcloud_message(s)[1]) for s in d.scans]
    export.write_bag(root / "bag", [export.imu_messages(d.imu), iter(pc)])
    write_tum(Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth"), root / "gt.tum")
    (root / "cfg.yaml").write_text("extrinsic:\n  p_i_l: [0.0, 0.0, 0.2]\n")
    out, rrd = root / "out", root / "run.rrd"
    r = RUNNER.invoke(app, ["lio", str(root / "bag"), *TOPICS, "--config", str(root / "cfg.yaml"),
                            "--gt", str(root / "gt.tum"), "--out", str(out), "--rrd", str(rrd)])  # fmt: skip
    assert r.exit_code == 0, r.output
    from imuslam.viz.readback import load

    return {"root": root, "out": out, "rrd": rrd, "imu": d.imu, "rec": load(rrd)}


@pytest.fixture(scope="session")
def map2d_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("viz_map2d")
    r = RUNNER.invoke(app, ["simulate", "room", "--duration", "40", "--out", str(root / "sim")])
    assert r.exit_code == 0, r.output
    r = RUNNER.invoke(app, ["map2d", str(root / "sim"), "--out", str(root / "out"), "--no-progress",
                            "--rrd", str(root / "run.rrd")])  # fmt: skip
    assert r.exit_code == 0, r.output
    return {"sim": root / "sim", "out": root / "out", "rrd": root / "run.rrd"}
