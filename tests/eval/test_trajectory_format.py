"""``eval --format auto``: TUM, KITTI and EuRoC csv told apart by content; a file read in the wrong
format names the --format that reads it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.errors import InputError
from imuslam.io.trajectory import detect_trajectory_format, read_trajectory

runner = CliRunner()


@pytest.mark.parametrize(
    "name, kind",
    [("V102_groundtruth.csv", "euroc"), ("V102.txt", "tum"), ("fr2_desk_ORB.txt", "tum"),
     ("georeferenced.tum", "tum"), ("KITTI_00_gt.txt", "kitti"), ("ROS_example.bag", "bag")],
)  # fmt: skip
def test_the_format_is_told_by_content(shared_data: Path, name: str, kind: str) -> None:
    assert detect_trajectory_format(shared_data / "evo_testdata" / name) == kind


def test_a_renamed_file_is_still_told_by_content(tmp_path: Path, shared_data: Path) -> None:
    src = shared_data / "evo_testdata" / "V102_groundtruth.csv"
    dst = tmp_path / "groundtruth.txt"  # no .csv to go by
    dst.write_bytes(src.read_bytes())
    assert detect_trajectory_format(dst) == "euroc"
    bad = tmp_path / "seven.txt"
    bad.write_text("# t x y z qx qy qz\n1 0 0 0 0 0 0\n")
    with pytest.raises(InputError, match=r"line 2 has 7 columns; expected TUM \(8"):
        detect_trajectory_format(bad)


def test_eval_auto_reads_euroc_against_tum_as_the_explicit_formats(
    shared_data: Path, tmp_path: Path
) -> None:
    d = shared_data / "evo_testdata"
    gt, est = str(d / "V102_groundtruth.csv"), str(d / "V102.txt")
    base = ["eval", gt, est, "--no-plots"]
    r1 = runner.invoke(app, [*base, "--out", str(tmp_path / "auto")])
    r2 = runner.invoke(
        app, [*base, "--format", "euroc", "--est-format", "tum", "--out", str(tmp_path / "set")]
    )
    assert r1.exit_code == 0 and r2.exit_code == 0, r1.output + r2.output
    m1 = json.loads((tmp_path / "auto" / "metrics.json").read_text())
    m2 = json.loads((tmp_path / "set" / "metrics.json").read_text())
    assert m1["ape_trans"] == m2["ape_trans"] and m1["n_pairs"] == m2["n_pairs"] > 700


def test_a_wrong_format_names_the_right_one(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / "evo_testdata"
    with pytest.raises(InputError, match=r"looks like EuRoC csv: give --format euroc"):
        read_trajectory(d / "V102_groundtruth.csv", "tum")
    r = runner.invoke(
        app,
        ["eval", str(d / "V102_groundtruth.csv"), str(d / "V102.txt"), "--format", "tum",
         "--out", str(tmp_path / "o")],
    )  # fmt: skip
    assert r.exit_code == 2
    assert "give --format euroc" in " ".join(r.output.split())
    assert not (tmp_path / "o").exists()


def test_a_mounted_frame_is_the_body_pose_times_the_mount() -> None:
    """``Trajectory.of_mounted_frame``: each pose T_w_f equals T_w_b T_b_f, as 4 x 4 products."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from imuslam.interfaces import Trajectory

    rng = np.random.default_rng(3)
    R = Rotation.random(5, random_state=4).as_matrix()
    tr = Trajectory(np.arange(5, dtype=np.int64) * 10**8, rng.normal(size=(5, 3)), R, "body")
    T_b_f = np.eye(4)
    T_b_f[:3, :3] = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    T_b_f[:3, 3] = [0.1, -0.05, 0.15]
    f = tr.of_mounted_frame(T_b_f)
    for k in range(5):
        T_w_b = np.eye(4)
        T_w_b[:3, :3], T_w_b[:3, 3] = R[k], tr.p_w[k]
        T_w_f = T_w_b @ T_b_f
        assert np.allclose(f.R_w_b[k], T_w_f[:3, :3], atol=1e-12)
        assert np.allclose(f.p_w[k], T_w_f[:3, 3], atol=1e-12)
    assert np.array_equal(f.t_ns, tr.t_ns)
