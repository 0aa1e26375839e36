"""The ROS message layer both ways, per-point time fields as drivers write them, and the bag reader on
ROS 1, ROS 2 (sqlite3) and a bare MCAP file."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2

from imuslam.errors import InputError
from imuslam.interfaces.lidar import Scan2d, Scan3d
from imuslam.io import rosmsg
from imuslam.io.bag import Bag

RNG = np.random.default_rng(11)
T0 = 1_700_000_000_123_456_789


def _scan(n: int = 500) -> Scan3d:
    return Scan3d(T0, RNG.normal(size=(n, 3)).astype(np.float32) * 10,
                  np.sort(RNG.uniform(0, 0.1, n)).astype(np.float32),
                  RNG.integers(0, 16, n).astype(np.uint16), RNG.uniform(0, 255, n).astype(np.float32))  # fmt: skip


def _serde(msg: object, msgtype: str, dialect: rosmsg.Dialect) -> object:
    ts = rosmsg.typestore(dialect)
    if dialect == "ros1":
        return ts.deserialize_ros1(ts.serialize_ros1(msg, msgtype), msgtype)
    return ts.deserialize_cdr(ts.serialize_cdr(msg, msgtype), msgtype)


@pytest.mark.parametrize("dialect", ["ros1", "ros2"])
def test_round_trips_through_serialised_messages(dialect: rosmsg.Dialect) -> None:
    a, w = RNG.normal(size=3), RNG.normal(size=3)
    t, a2, w2 = rosmsg.imu_sample(
        _serde(rosmsg.imu_message(T0, a, w, dialect=dialect), rosmsg.IMU, dialect)
    )
    assert t == T0 and np.array_equal(a, a2) and np.array_equal(w, w2)

    scan = _scan()
    back = rosmsg.scan3d_from_msg(
        _serde(rosmsg.pointcloud2_message(scan, dialect=dialect), rosmsg.POINTCLOUD2, dialect)
    )
    assert back.t_ns == T0
    for f in ("points_l", "t_offset_s", "ring", "intensity"):
        np.testing.assert_array_equal(getattr(back, f), getattr(scan, f))

    ranges = RNG.uniform(0.3, 10, 800).astype(np.float32)
    ranges[::7] = np.inf
    s2 = Scan2d(T0, -np.pi, 2 * np.pi / 800, 1e-4, 0.1, 0.2, 12.0, ranges, np.ones(800, np.float32))
    b2 = rosmsg.scan2d_from_msg(
        _serde(rosmsg.laserscan_message(s2, dialect=dialect), rosmsg.LASERSCAN, dialect)
    )
    np.testing.assert_array_equal(b2.ranges, ranges)
    assert b2.t_ns == T0 and b2.angle_increment == pytest.approx(s2.angle_increment, rel=1e-7)

    q = RNG.normal(size=4)
    q /= np.linalg.norm(q)
    p = RNG.normal(size=3)
    for msg, typ in ((rosmsg.odometry_message(T0, p, q, dialect=dialect), rosmsg.ODOMETRY),
                     (rosmsg.posestamped_message(T0, p, q, dialect=dialect), rosmsg.POSESTAMPED)):  # fmt: skip
        t, p2, q2 = rosmsg.pose_from_msg(_serde(msg, typ, dialect))
        assert t == T0 and np.array_equal(p, p2) and np.array_equal(q, q2)

    for img in (RNG.integers(0, 255, (48, 64), dtype=np.uint8), RNG.integers(0, 255, (48, 64, 3), dtype=np.uint8),
                RNG.integers(0, 65535, (48, 64), dtype=np.uint16)):  # fmt: skip
        t, back_img = rosmsg.image_from_msg(
            _serde(rosmsg.image_message(T0, img, dialect=dialect), rosmsg.IMAGE, dialect)
        )
        assert t == T0 and np.array_equal(back_img, img)


def test_compressed_image_is_decoded() -> None:
    import cv2

    img = RNG.integers(0, 255, (40, 50), dtype=np.uint8)
    ok, png = cv2.imencode(".png", img)
    T = rosmsg.typestore("ros2").types
    msg = T[rosmsg.COMPRESSED_IMAGE](
        header=rosmsg.header(T0, "cam"), format="png", data=png.ravel()
    )
    t, back = rosmsg.image_from_msg(msg)
    assert ok and t == T0 and np.array_equal(back, img)


def _cloud(fields: list[tuple[str, str]], cols: dict[str, np.ndarray], stamp: int) -> object:
    T = rosmsg.typestore("ros2").types
    dt = np.dtype(fields)
    arr = np.zeros(len(next(iter(cols.values()))), dt)
    for k, v in cols.items():
        arr[k] = v
    codes = {"<f4": 7, "<f8": 8, "<u4": 6, "<u2": 4, "|u1": 2}
    PF = T["sensor_msgs/msg/PointField"]
    pf = [
        PF(name=n, offset=dt.fields[n][1], datatype=codes[dt.fields[n][0].str], count=1)
        for n in dt.names
    ]
    return T[rosmsg.POINTCLOUD2](header=rosmsg.header(stamp, "l"), height=1, width=len(arr), fields=pf,
                                 is_bigendian=False, point_step=dt.itemsize, row_step=dt.itemsize * len(arr),
                                 data=np.frombuffer(arr.tobytes(), np.uint8), is_dense=True)  # fmt: skip


@pytest.mark.parametrize(
    "driver,field,dtype,encode",
    [
        ("ouster", "t", "<u4", lambda off, st: np.round(off * 1e9)),  # ns from the stamp
        ("velodyne", "time", "<f4", lambda off, st: off - 0.1),  # s, stamp at the end of the sweep
        ("hesai", "timestamp", "<f8", lambda off, st: st * 1e-9 + off),  # absolute s
        ("livox", "offset_time", "<u4", lambda off, st: np.round(off * 1e9)),  # ns
    ],
)
def test_point_time_fields_of_the_drivers(driver: str, field: str, dtype: str, encode) -> None:  # type: ignore[no-untyped-def]
    """Each driver's field decoded to seconds from the header stamp: integer ns exactly (1 ns), float32
    seconds to float32 precision (6e-9 s at 0.1 s), absolute float64 seconds to their precision at epoch
    times (2.4e-7 s)."""
    n = 300
    off = np.sort(RNG.uniform(0, 0.1, n))
    stamp = T0
    xyz = RNG.normal(size=(n, 3))
    ring_name = "line" if driver == "livox" else "ring"
    fields = [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        (field, dtype),
        (ring_name, "<u1" if driver == "livox" else "<u2"),
    ]
    msg = _cloud(fields, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], field: encode(off, stamp),
                          ring_name: np.arange(n) % 16}, stamp)  # fmt: skip
    scan = rosmsg.scan3d_from_msg(msg)
    want = off - 0.1 if driver == "velodyne" else off
    tol = {"ouster": 1e-9, "livox": 1e-9, "velodyne": 1e-8, "hesai": 3e-7}[driver]
    np.testing.assert_allclose(scan.t_offset_s, want, atol=tol)
    np.testing.assert_array_equal(scan.ring, np.arange(n) % 16)


def _write_bags(tmp: Path) -> dict[str, Path]:
    scans = [_scan(50) for _ in range(3)]
    for k, s in enumerate(scans):
        s.t_ns = T0 + k * 100_000_000
    imu_t = T0 + np.arange(40) * 10_000_000
    out = {}
    for kind in ("ros1", "sqlite3", "mcap"):
        path = tmp / ("b.bag" if kind == "ros1" else f"b_{kind}")
        dialect: rosmsg.Dialect = "ros1" if kind == "ros1" else "ros2"
        ts = rosmsg.typestore(dialect)
        ser = ts.serialize_ros1 if kind == "ros1" else ts.serialize_cdr
        w = (
            Writer1(path)
            if kind == "ros1"
            else Writer2(
                path,
                version=8,
                storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3,
            )
        )
        w.open()
        ci = w.add_connection("/imu", rosmsg.IMU, typestore=ts)
        cp = w.add_connection("/points", rosmsg.POINTCLOUD2, typestore=ts)
        msgs = [
            (
                int(t),
                ci,
                rosmsg.IMU,
                rosmsg.imu_message(
                    int(t), np.array([0, 0, 9.8]), np.full(3, k * 0.01), dialect=dialect
                ),
            )
            for k, t in enumerate(imu_t)
        ]
        msgs += [
            (s.t_ns, cp, rosmsg.POINTCLOUD2, rosmsg.pointcloud2_message(s, dialect=dialect))
            for s in scans
        ]
        for t, c, typ, m in sorted(msgs, key=lambda x: x[0]):
            w.write(c, t, ser(m, typ))
        w.close()
        if kind == "mcap":  # a bare .mcap file, without its folder's metadata.yaml
            f = next(path.glob("*.mcap"))
            shutil.move(f, tmp / "bare.mcap")
            path = tmp / "bare.mcap"
        out[kind] = path
    return out


def test_bag_reader_lists_topics_and_iterates_records_in_time_order(tmp_path: Path) -> None:
    for kind, path in _write_bags(tmp_path).items():
        with Bag(path) as bag:
            assert bag.topics() == {"/imu": rosmsg.IMU, "/points": rosmsg.POINTCLOUD2}, kind
            recs = list(bag.records(["/imu", "/points"]))
            stamps = [r[0] if isinstance(r, tuple) else r.t_ns for _, r in recs]
            assert len(recs) == 43 and stamps == sorted(stamps)
            log = bag.imu()
            assert len(log) == 40 and np.allclose(log.gyro[:, 0], np.arange(40) * 0.01)
            assert [s.t_ns for s in bag.scans3d()] == [T0, T0 + 100_000_000, T0 + 200_000_000]
            with pytest.raises(
                InputError, match=r"no topic '/scan'.*/imu \(sensor_msgs/msg/Imu\), /points"
            ):
                list(bag.records(["/scan"]))


def test_bad_bag_is_an_input_error_naming_it(tmp_path: Path) -> None:
    bad = tmp_path / "broken.bag"
    bad.write_bytes(b"#ROSBAG V2.0\nnot a bag")
    with pytest.raises(InputError, match="broken.bag"):
        Bag(bad)
    with pytest.raises(InputError, match="no such bag"):
        Bag(tmp_path / "missing.mcap")
