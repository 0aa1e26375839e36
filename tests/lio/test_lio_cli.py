"""``imuslam lio`` on a simulated bag: the results folder, and bad input as one-line errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.interfaces import ImuLog, Trajectory
from imuslam.io.trajectory import write_tum
from imuslam.sim import export
from imuslam.sim.drive import simulate_lidar_drive
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO

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
    # the calibration imuslam calibrate writes: seed 000's table-2 model with the simulator's parameters
    a, g = SEED000_ACCEL, SEED000_GYRO
    ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    ).save_yaml(root / "calibration.yaml")
    write_tum(Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth"), root / "gt.tum")
    # the IMU with a 0.3 s gap in the middle of the drive
    keep = (d.imu.t_s < 1.5) | (d.imu.t_s > 1.8)
    gap_imu = ImuLog(d.imu.t_ns[keep], d.imu.accel[keep], d.imu.gyro[keep], "m/s^2", "rad/s", "gap")
    export.write_bag(root / "gap", [export.imu_messages(gap_imu),
                                    iter([(s.t_ns, "/points", export.pointcloud_message(s)[1]) for s in d.scans])])  # fmt: skip
    # scan 15's header stamp before scan 14's (recorded in this order: the bag's log times increase)
    order = list(range(len(d.scans)))
    order[14], order[15] = 15, 14
    swapped = [
        (d.scans[i].t_ns, "/points", export.pointcloud_message(d.scans[j])[1])
        for i, j in enumerate(order)
    ]
    export.write_bag(root / "swapped", [export.imu_messages(d.imu), iter(swapped)])
    return {
        "good": write("good", d.scans),
        "micro": write("micro", micro),
        "swapped": root / "swapped",
        "gap": root / "gap",
        "cfg": root / "cfg.yaml",
        "calib": root / "calibration.yaml",
        "gt": root / "gt.tum",
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


def _run(bag: Path, out: Path, *extra: str) -> tuple[int, str]:
    r = RUNNER.invoke(app, ["lio", str(bag), "--imu-topic", "/imu/data", "--points-topic", "/points",
                            "--mode", "direct", "--out", str(out), *extra])  # fmt: skip
    return r.exit_code, r.output


def test_calib_option_corrects_the_raw_imu(bags: dict[str, Path], tmp_path: Path) -> None:
    """The simulated IMU carries seed 000's table-2 errors (gyro biases of 0.06 rad/s = 3.4 deg/s in
    norm, gyro axis misalignments of 3-9 %, accelerometer biases up to 0.14 m/s^2); in the reduced state
    (no bias states) they go straight into the motion prior: 0.34 deg of attitude per 0.1 s scan from the
    gyro bias alone, every scan, which the LiDAR update only partly removes. The calibration written in
    ``imuslam calibrate``'s format removes them, leaving the noise: its rotation error must be below
    half the raw one (translation is not compared: 24 m after an SE(3) alignment is too short)."""
    import json

    rot = {}
    for name, extra in (("raw", ()), ("cal", ("--calib", str(bags["calib"])))):
        code, output = _run(bags["good"], tmp_path / name, "--state", "reduced", "--gt", str(bags["gt"]),
                            *extra)  # fmt: skip
        assert code == 0, output
        m = json.loads((tmp_path / name / "metrics.json").read_text())
        rot[name] = (m["ape_rot_deg"]["rmse"], m["ape_trans"]["rmse"])
        assert (tmp_path / name / "config.yaml").exists()
    assert rot["cal"][0] < 0.5 * rot["raw"][0], rot


def test_calib_file_that_is_missing_is_named(bags: dict[str, Path], tmp_path: Path) -> None:
    code, output = _run(bags["good"], tmp_path / "o", "--calib", str(tmp_path / "nope.yaml"))
    assert code == 2 and "nope.yaml" in output and "Traceback" not in output
    assert not (tmp_path / "o").exists()


def test_imu_gap_is_a_counted_warning(bags: dict[str, Path], tmp_path: Path) -> None:
    code, output = _run(bags["gap"], tmp_path / "o")
    assert code == 0, output
    import re

    m = re.search(
        r"warning: 1 IMU gaps longer than 0.1 s \(longest ([\d.]+) s at t = ([\d.]+) s\)", output
    )
    assert m is not None, output
    assert abs(float(m[1]) - 0.3) <= 0.011 and abs(float(m[2]) - 1.5) <= 0.011  # 200 Hz samples


def test_scans_out_of_order_are_skipped_and_counted(bags: dict[str, Path], tmp_path: Path) -> None:
    code, output = _run(bags["swapped"], tmp_path / "o")
    assert code == 0, output
    assert "1 scans out of time order skipped" in output
    rows = (tmp_path / "o" / "trajectory.tum").read_text().splitlines()
    assert len(rows) == 30  # header + 29 of the 30 scans
