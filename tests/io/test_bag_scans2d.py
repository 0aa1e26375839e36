"""Bag.scans2d reads ROS 1 LaserScan / MultiEchoLaserScan from the message bytes: the same scans as
rosbags' deserialiser and rosmsg.scan2d_from_msg (Bag.records), array for array."""

from __future__ import annotations

from itertools import islice
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1

from imuslam.interfaces.lidar import Scan2d
from imuslam.io import rosmsg
from imuslam.io.bag import Bag

T0 = 1_700_000_000_000_000_000


def _same(a: object, b: object) -> None:
    for k, va in vars(a).items():
        vb = getattr(b, k)
        if isinstance(va, np.ndarray):
            assert va.dtype == vb.dtype and va.tobytes() == vb.tobytes(), k
        else:
            assert type(va) is type(vb) and va == vb, k


def _multiecho(t_ns: int, rng: np.random.Generator, n: int) -> object:
    T = rosmsg.typestore("ros1").types
    echo = T["sensor_msgs/msg/LaserEcho"]

    def beams(scale: float) -> list[object]:
        counts = rng.integers(0, 4, n)  # beams of no, one and several echoes
        return [echo(echoes=(scale * rng.uniform(0, 1, c)).astype(np.float32)) for c in counts]

    return T[rosmsg.MULTIECHO_LASERSCAN](
        header=rosmsg.header(t_ns, "laser", "ros1"), angle_min=-1.0, angle_max=1.0,
        angle_increment=2.0 / (n - 1), time_increment=1e-4, scan_time=0.1, range_min=0.5,
        range_max=25.0, ranges=beams(30.0), intensities=beams(100.0),
    )  # fmt: skip


def test_scans2d_from_bytes_equal_rosbags(tmp_path: Path) -> None:
    rng = np.random.default_rng(6)
    ts = rosmsg.typestore("ros1")
    w = Writer1(tmp_path / "b.bag")
    w.open()
    c1 = w.add_connection("/scan", rosmsg.LASERSCAN, typestore=ts)
    c2 = w.add_connection("/echoes", rosmsg.MULTIECHO_LASERSCAN, typestore=ts)
    for k in range(4):
        r = rng.uniform(0.0, 30.0, 181).astype(np.float32)
        r[:5] = [np.nan, np.inf, 0.1, 26.0, 0.5]
        scan = Scan2d(T0 + k * 10**8, -1.5, 3.0 / 180, 1e-4, 0.1, 0.5, 25.0, r,
                             rng.uniform(0, 100, 181 if k else 3).astype(np.float32))  # fmt: skip
        w.write(c1, scan.t_ns, ts.serialize_ros1(rosmsg.laserscan_message(scan, dialect="ros1"),
                                                 rosmsg.LASERSCAN))  # fmt: skip
        m = _multiecho(T0 + k * 10**8 + 1, rng, 91)
        w.write(c2, T0 + k * 10**8 + 1, ts.serialize_ros1(m, rosmsg.MULTIECHO_LASERSCAN))
    w.close()
    with Bag(tmp_path / "b.bag") as bag:
        for topic in ("/scan", "/echoes"):
            got = list(bag.scans2d(topic))
            ref = [r for _, r in bag.records([topic])]
            assert len(got) == len(ref) == 4
            for a, b in zip(got, ref, strict=True):
                _same(a, b)


def test_scans2d_of_the_backpack_bag_equal_rosbags(shared_data: Path) -> None:
    path = shared_data / "cartographer_backpack_2d/b0-2014-07-21-12-42-53-short.bag"
    with Bag(path) as bag:
        got = list(islice(bag.scans2d("horizontal_laser_2d"), 40))
        ref = [r for _, r in islice(bag.records(["horizontal_laser_2d"]), 40)]
    for a, b in zip(got, ref, strict=True):
        _same(a, b)
