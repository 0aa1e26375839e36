"""The laser log readers: CARMEN (FLASER, ROBOTLASER1, compressed), bags with LaserScan and
MultiEchoLaserScan, and their bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from slam2d_helpers import _flaser

from imuslam.errors import InputError
from imuslam.io.laserlog import LaserLog, check_beam_count


def test_beam_count_must_match_angles() -> None:
    check_beam_count(-np.pi, np.pi - 0.01, 0.01, 629, "scan 0")
    with pytest.raises(InputError, match="give .* beams but the scan has 600 ranges"):
        check_beam_count(-np.pi, np.pi, 0.01, 600, "/scan message 3")


def test_laserlog_rejects_empty_and_unsorted() -> None:
    from imuslam.io.laserlog import check_time_order

    with pytest.raises(InputError, match="no laser scans"):
        LaserLog(np.zeros(0, np.int64), np.zeros((0, 10)), -1.0, 0.1, 0.1, 10.0)
    w: dict[str, int] = {}
    with pytest.raises(InputError, match="not in time order"):
        check_time_order(np.array([5, 4, 3, 2, 1]), "log.clf", w)
    check_time_order(np.arange(100)[np.r_[0:50, 51, 50, 52:100]], "log.clf", w)
    assert sum(w.values()) == 1


def test_carmen_bad_input(tmp_path: Path) -> None:
    from imuslam.io.carmen import read_carmen

    f = tmp_path / "x.clf"
    f.write_text("ODOM 0 0 0 0 0 0 1.0 host 1.0\n")
    with pytest.raises(InputError, match="no laser scans"):
        read_carmen(f)
    f.write_text(
        "FLASER 3 1.0 2.0 nan 0 0 0 0 0 0 1.0 h 1.0\nFLASER 3 1.0 abc 1 0 0 0 0 0 0 2.0 h 2.0\n"
    )
    with pytest.raises(InputError, match=r"x.clf:2: 'abc' is not a number"):
        read_carmen(f)
    f.write_text(
        "FLASER 3 1.0 2.0 nan 0 0 0 0 0 0 1.0 h 1.0\nFLASER 3 1.0 90 inf 5 0 0 5 0 0 1.1 h 2.0\n"
    )
    log_ = read_carmen(f).laser
    assert log_.warnings["readings dropped (inf/NaN/out of range)"] == 3
    assert log_.warnings["odometry jumps (step replaced by no motion)"] == 1
    assert np.allclose(log_.odom_xy_yaw[1], [0, 0, 0])


def test_laserscan_angle_fields_must_match_ranges() -> None:
    import dataclasses

    from imuslam.interfaces.lidar import Scan2d
    from imuslam.io import rosmsg

    s = Scan2d(
        5, -1.0, 0.01, 0.0, 0.1, 0.1, 10.0, np.ones(201, np.float32), np.zeros(201, np.float32)
    )
    msg = rosmsg.laserscan_message(s)
    assert len(rosmsg.scan2d_from_msg(msg).ranges) == 201
    bad = dataclasses.replace(msg, angle_max=msg.angle_max + 0.5)
    with pytest.raises(InputError, match="give 251.0 beams but it has 201 ranges"):
        rosmsg.scan2d_from_msg(bad)


@pytest.mark.slow
def test_backpack_bag_reads_multiecho_scans_and_imu(shared_data: Path) -> None:
    """Cartographer's 2D backpack bag: 10 s of MultiEchoLaserScan (1079 beams, +-134.75 deg) and a 200 Hz
    IMU; with two laser topics the reader asks for one by name."""
    from imuslam.io.datasets import open_dataset

    bag = shared_data / "cartographer_backpack_2d" / "b0-2014-07-21-12-42-53-short.bag"
    with pytest.raises(InputError, match="several .* topics; name one"):
        open_dataset(bag, "laser")
    log_ = open_dataset(bag, "laser", scan_topic="horizontal_laser_2d")
    assert log_.n_beams == 1079
    assert np.rad2deg(log_.angle_min) == pytest.approx(-134.75, abs=0.05)
    assert 300 < len(log_) < 400  # ~35 Hz for 10 s
    assert (imu := log_.imu()) is not None and 1800 < len(imu) < 2100
    assert log_.odom_xy_yaw is None


def test_carmen_robotlaser1_and_compressed(tmp_path: Path) -> None:
    """ROBOTLASER1 lines (angles from the line's own fields) in a .gz file; a field of view that disagrees
    with the number of readings is an error naming the line."""
    import gzip

    from imuslam.io.carmen import read_carmen

    def line(n: int, t: float, x: float) -> str:
        r = " ".join(["2.5"] * n)
        return (f"ROBOTLASER1 0 -1.5708 3.14159 {3.14159 / (181 - 1):.7f} 81.9 0.01 0 {n} {r} 0 "
                f"{x + 0.1} 0 0 {x} 0 0 0 0 0 0 0 {t} host {t}\n")  # fmt: skip

    f = tmp_path / "r.log.gz"
    f.write_bytes(gzip.compress((line(181, 10.0, 0.0) + line(181, 10.2, 0.05)).encode()))
    c = read_carmen(f)
    assert len(c.laser) == 2 and c.laser.n_beams == 181
    assert c.laser.angle_increment == pytest.approx(np.pi / 180, rel=1e-5)
    assert np.allclose(c.laser.odom_xy_yaw[:, 0], [0.0, 0.05])
    assert np.allclose(c.laser_pose_xy_yaw[:, 0], [0.1, 0.15])
    assert c.laser.t_ns[1] - c.laser.t_ns[0] == pytest.approx(0.2e9, abs=1e3)
    f.write_bytes(gzip.compress(line(100, 10.0, 0.0).encode()))
    with pytest.raises(InputError, match=r"r.log.gz:1: field of view .* and 100 readings disagree"):
        read_carmen(f)


def test_reader_marks_the_odometry_jump_and_a_slice_keeps_it(tmp_path: Path) -> None:
    """The same 5 m jump in 0.1 s between scans 19 and 20 as above: the CARMEN reader marks scan 20 (and
    only it) in ``odom_jumped``, which ``slice`` keeps aligned with its scans; a mask of the wrong length
    is a clear error."""
    from imuslam.errors import InputError
    from imuslam.io.carmen import read_carmen
    from imuslam.io.laserlog import LaserLog

    lines = [_flaser(100.0 + 0.1 * k, ["3.000"] * 180, (5.0, 0.0, 0.0) if k >= 20 else (0.0, 0.0, 0.0))
             for k in range(40)]  # fmt: skip
    f = tmp_path / "log.clf"
    f.write_text("".join(lines))
    log_ = read_carmen(f).laser
    assert log_.odom_jumped is not None
    assert np.flatnonzero(log_.odom_jumped).tolist() == [20]
    part = log_.slice(15, 30)
    assert part.odom_jumped is not None
    assert np.flatnonzero(part.odom_jumped).tolist() == [5]
    with pytest.raises(InputError, match="odom_jumped"):
        LaserLog(log_.t_ns, log_.ranges, log_.angle_min, log_.angle_increment, log_.range_min,
                 log_.range_max, odom_jumped=np.zeros(3, bool))  # fmt: skip
