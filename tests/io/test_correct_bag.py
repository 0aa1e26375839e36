"""``imuslam correct`` on a real bz2-compressed ROS 1 bag: the topic it replaced named, the bag's
compression kept (a bz2 bag in, a bz2 bag out of about its size), every other message copied."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.imu.model import ImuCalibration, TriadModel

BAG = "robot_localization_husky/test1.bag"


def _chunk_compressions(path: Path) -> set[str]:
    from rosbags.rosbag1 import Reader

    with Reader(path) as r:
        return {c.decompressor.__module__.split(".")[0] for c in r.chunks.values()}


def test_correct_names_the_topic_and_keeps_bz2(shared_data: Path, tmp_path: Path) -> None:
    src = shared_data / BAG
    assert _chunk_compressions(src) == {"bz2"}
    cal = ImuCalibration(
        TriadModel(K=np.full(3, 1.01), b=np.array([0.05, -0.02, 0.1])), TriadModel()
    )
    cal.save_yaml(tmp_path / "cal.yaml")
    out = tmp_path / "corrected.bag"
    r = CliRunner().invoke(
        app, ["correct", str(src), "--calib", str(tmp_path / "cal.yaml"), "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    text = " ".join(r.output.split())
    assert "of /imu/data (sensor_msgs/Imu;" in text
    assert _chunk_compressions(out) == {"bz2"}
    # about the input's size (uncompressed it was 5 times larger)
    assert out.stat().st_size < 1.5 * src.stat().st_size
    from imuslam.io.bag import Bag

    with Bag(src) as a, Bag(out) as b:
        assert a.topics() == b.topics()
        raw, cor = a.imu("/imu/data"), b.imu("/imu/data")
    assert np.array_equal(raw.t_ns, cor.t_ns)
    assert np.allclose(cor.accel, 1.01 * (raw.accel + [0.05, -0.02, 0.1]), atol=1e-9)
