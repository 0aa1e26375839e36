"""IMU log readers and writers: round trips of every format written, real files, and bad input."""

from pathlib import Path

import numpy as np
import pytest

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog
from imuslam.io.load import load_imu, write_imu
from imuslam.io.rosbag import list_topics, read_imu_bag


def _log(n: int = 200, seed: int = 0) -> ImuLog:
    rng = np.random.default_rng(seed)
    t = 1_403_715_273_262_142_976 + np.arange(n, dtype=np.int64) * 5_000_000
    return ImuLog(
        t, rng.normal(size=(n, 3)) + [0, 0, 9.81], rng.normal(size=(n, 3)) * 0.1, "m/s^2", "rad/s"
    )


@pytest.mark.parametrize("name", ["x.bag", "ros2_sqlite", "x.mcap"])
def test_bag_round_trip_and_replace(tmp_path: Path, name: str) -> None:
    log = _log()
    path = tmp_path / name
    kind = {"x.bag": "ros1", "ros2_sqlite": "ros2", "x.mcap": "mcap"}[name]
    write_imu(log, path, "bag", topic="/imu")
    back = load_imu(path)
    np.testing.assert_array_equal(back.t_ns, log.t_ns)
    np.testing.assert_array_equal(back.accel, log.accel)
    np.testing.assert_array_equal(back.gyro, log.gyro)
    corrected = ImuLog(log.t_ns, log.accel * 1.01, log.gyro - 0.02, "m/s^2", "rad/s")
    out = tmp_path / ("c_" + name)
    write_imu(corrected, out, "bag", template=path, topic="/imu")
    again = read_imu_bag(out, "/imu")
    np.testing.assert_array_equal(again.accel, corrected.accel)
    assert list_topics(out) == {"/imu": "sensor_msgs/msg/Imu"}
    # each container is what its name asks for: a ROS 1 bag file, a standalone MCAP file (x.mcap is a
    # file, as ROS 2 tools and Foxglove open it), or a ROS 2 bag folder (metadata.yaml) holding an
    # sqlite3 database (format magics: rosbag "#ROSBAG V2.0", MCAP "\x89MCAP0\r\n", SQLite
    # "SQLite format 3")
    for p in (path, out):
        if kind == "ros1":
            assert p.is_file() and p.read_bytes()[:13] == b"#ROSBAG V2.0\n"
        elif kind == "mcap":
            assert p.is_file() and p.read_bytes()[:8] == b"\x89MCAP0\r\n"
        else:
            assert p.is_dir() and (p / "metadata.yaml").is_file()
            (f,) = p.glob("*.db3")
            assert f.read_bytes()[:16] == b"SQLite format 3\x00"


def test_text_and_euroc_round_trip(tmp_path: Path) -> None:
    log = _log()
    write_imu(log, tmp_path / "one.txt", "imutk")
    write_imu(log, tmp_path / "two", "imutk", two_files=True)
    write_imu(log, tmp_path / "data.csv", "euroc")
    a = load_imu(tmp_path / "one.txt", accel_unit="m/s^2", gyro_unit="rad/s")
    b = load_imu(
        tmp_path / "two" / "acc.txt",
        tmp_path / "two" / "gyro.txt",
        accel_unit="m/s^2",
        gyro_unit="rad/s",
    )
    c = load_imu(tmp_path / "data.csv")
    for x in (a, b):
        np.testing.assert_allclose(x.accel, log.accel, rtol=1e-8)
        # seconds with 9 decimals: the stamps survive to the nanosecond
        assert (
            np.max(np.abs(x.t_ns - log.t_ns)) <= 512
        )  # 2 ulp of float64 epoch seconds (238 ns each)
    np.testing.assert_array_equal(c.t_ns, log.t_ns)
    np.testing.assert_array_equal(c.gyro, log.gyro)


def test_real_files(shared_data: Path) -> None:
    xs = load_imu(
        shared_data / "imu_tk_xsens" / "xsens_acc.mat",
        shared_data / "imu_tk_xsens" / "xsens_gyro.mat",
    )
    assert len(xs) == 51175 and xs.accel_unit == "counts"
    assert xs.rate_hz == pytest.approx(100.0, rel=1e-3)
    t265 = load_imu(
        shared_data / "imu_tk_t265" / "t265_acc.mat", shared_data / "imu_tk_t265" / "t265_gyr.mat"
    )
    # Stamps rounded to 0.01 s, re-timed at the fitted rate. The expectation comes from the raw stamps
    # read here with numpy: N samples over the raw span give the rate to within one quantum over the span
    # (0.01 s / 324 s, 6 mHz), and each re-timed stamp lies within one quantum of its raw one.
    raw_t = np.loadtxt(shared_data / "imu_tk_t265" / "t265_acc.mat", usecols=0)
    raw_span = raw_t[-1] - raw_t[0]
    assert any("quantised" in w for w in t265.warnings)
    assert np.all(np.diff(t265.t_ns) > 0)
    span = (t265.t_ns[-1] - t265.t_ns[0]) * 1e-9
    assert abs(span - raw_span) < 0.01
    assert t265.rate_hz == pytest.approx((len(raw_t) - 1) / raw_span, abs=0.01 / raw_span * 200.0)
    assert np.max(np.abs(t265.t_ns * 1e-9 - raw_t)) < 0.01
    eu = load_imu(shared_data / "euroc_V1_01_micro_kimera")
    assert eu.rate_hz == pytest.approx(200.0, rel=1e-6) and eu.accel_unit == "m/s^2"
    assert np.linalg.norm(eu.accel[:200].mean(axis=0)) == pytest.approx(9.81, abs=0.2)
    cols: dict[str, str | int] = dict(
        t="timestamp", ax="scaledAccelX", ay="scaledAccelY", az="scaledAccelZ",
        gx="scaledGyroX", gy="scaledGyroY", gz="scaledGyroZ",
    )  # fmt: skip
    ab = load_imu(
        shared_data / "airbrakes_microstrain_6pos" / "xplus.csv",
        fmt="csv",
        columns=cols,
        accel_unit="g",
        gyro_unit="rad/s",
    )
    assert any("skipped" in w for w in ab.warnings)
    # +x up at rest: about +1 g on x.
    assert ab.accel[:100, 0].mean() == pytest.approx(1.0, abs=0.05)


def test_bag_without_topic_lists_topics(shared_data: Path) -> None:
    bag = next((shared_data / "evo_testdata").glob("*.bag"))
    with pytest.raises(
        InputError, match=r"no sensor_msgs/msg/Imu topics.*geometry_msgs/msg/PoseStamped"
    ):
        load_imu(bag)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("", "no data rows"),
        ("0.0 1 2 3\n0.01 1 nan 3\n", "line 2: a value is NaN"),
        ("0.0 1 2 3\n0.01 1 2\n", "line 2: 3 columns; expected 4"),
        ("0.0 1 2 3\n0.02 1 2 3\n0.01 1 2 3\n", "time goes backwards at line 3"),
        ("0.0 1 2 3\n0.01 1 x 3\n", "line 2: 'x' is not a number"),
    ],
)
def test_bad_text_input(tmp_path: Path, content: str, match: str) -> None:
    acc = tmp_path / "acc.txt"
    acc.write_text(content)
    gyro = tmp_path / "gyro.txt"
    gyro.write_text("0.0 0 0 0\n0.01 0 0 0\n0.02 0 0 0\n")
    with pytest.raises(InputError, match=match) as err:
        load_imu(acc, gyro, accel_unit="m/s^2", gyro_unit="rad/s")
    assert str(acc) in str(err.value)


def test_unknown_format_and_missing_file(tmp_path: Path) -> None:
    p = tmp_path / "x.txt"
    p.write_text("0 1 2 3 4 5 6\n")
    with pytest.raises(InputError, match="unknown format"):
        load_imu(p, fmt="xml")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="no such file"):
        load_imu(tmp_path / "missing.txt")


def test_failed_write_leaves_nothing(tmp_path: Path) -> None:
    log = ImuLog(np.arange(3), np.zeros((3, 3)), np.zeros((3, 3)), "counts", "counts", "raw")
    with pytest.raises(InputError, match="m/s\\^2"):
        write_imu(log, tmp_path / "out.mcap", "bag")
    assert list(tmp_path.iterdir()) == []
