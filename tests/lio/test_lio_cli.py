"""``imuslam lio`` on a simulated bag: the results folder, and bad input as one-line errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.sim import export
from imuslam.sim.drive import simulate_lidar_drive

RUNNER = CliRunner()


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = simulate_lidar_drive("street", 3.0, seed=5)
    root = tmp_path_factory.mktemp("liobags")

    def write(name: str, scans: list) -> Path:  # type: ignore[type-arg]
        pc = [(s.t_ns, "/points", export.pointcloud_message(s)[1]) for s in scans]
        export.write_bag(root / name, [export.imu_messages(d.imu), iter(pc)])
        return root / name

    micro = [replace(s, t_offset_s=(s.t_offset_s * 1e6).astype(np.float32)) for s in d.scans]
    (root / "cfg.yaml").write_text("extrinsic:\n  p_i_l: [0.0, 0.0, 0.2]\n")
    return {
        "good": write("good", d.scans),
        "micro": write("micro", micro),
        "cfg": root / "cfg.yaml",
    }


def test_lio_command_writes_the_results_folder(bags: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = RUNNER.invoke(app, ["lio", str(bags["good"]), "--imu-topic", "/imu/data", "--points-topic", "/points",
                            "--config", str(bags["cfg"]), "--mode", "direct", "--out", str(out)])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert {p.name for p in out.iterdir()} >= {"trajectory.tum", "map.ply", "map.pcd", "config.yaml", "scans.csv",
                                               "trajectory.png"}  # fmt: skip
    rows = (out / "trajectory.tum").read_text().splitlines()
    assert len(rows) == 31  # header + one pose per scan end
    assert "scans/s" in r.output
    cfg = (out / "config.yaml").read_text()
    assert "p_i_l:\n  - 0.0\n  - 0.0\n  - 0.2" in cfg and "mode: direct" in cfg


def test_missing_topic_lists_the_topics(bags: dict[str, Path], tmp_path: Path) -> None:
    r = RUNNER.invoke(app, ["lio", str(bags["good"]), "--points-topic", "/velodyne_points", "--out",
                            str(tmp_path / "o")])  # fmt: skip
    assert r.exit_code == 2
    assert "/velodyne_points" in r.output and "/points" in r.output and "/imu/data" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "o").exists()


def test_point_time_in_an_unknown_unit_is_named(bags: dict[str, Path], tmp_path: Path) -> None:
    r = RUNNER.invoke(app, ["lio", str(bags["micro"]), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert "scan 0" in r.output and "unknown unit" in r.output
    assert not (tmp_path / "o").exists()


def test_bad_option_value(bags: dict[str, Path], tmp_path: Path) -> None:
    r = RUNNER.invoke(
        app, ["lio", str(bags["good"]), "--state", "huge", "--out", str(tmp_path / "o")]
    )
    assert r.exit_code == 2 and "--state" in r.output
