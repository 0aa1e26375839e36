"""ROS 1 bags, ROS 2 bags (sqlite3 and MCAP) with ``sensor_msgs/msg/Imu``, through ``rosbags`` (no ROS).

Read an IMU topic into an :class:`ImuLog`; write an ImuLog as a bag; copy a bag with its IMU topic
replaced by a corrected log and every other message copied byte for byte.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog
from imuslam.io.atomic import atomic_path
from imuslam.io.timestamps import check_and_repair

IMU_TYPE = "sensor_msgs/msg/Imu"
BagKind = Literal["ros1", "ros2", "mcap"]
_TS1 = get_typestore(Stores.ROS1_NOETIC)
_TS2 = get_typestore(Stores.ROS2_HUMBLE)


def bag_kind(path: str | Path) -> BagKind:
    """``ros1`` for a ``.bag`` file, ``mcap`` for an ``.mcap`` file or a ROS 2 folder of MCAP, else ``ros2``."""
    p = Path(path)
    if p.suffix == ".bag":
        return "ros1"
    if p.suffix == ".mcap" or (p.is_dir() and any(p.glob("*.mcap"))):
        return "mcap"
    return "ros2"


def _open(path: Path) -> AnyReader:
    p = path
    if p.suffix == ".mcap" and p.is_file():
        p = p.parent  # a ROS 2 bag is its folder (metadata.yaml beside the .mcap)
    if not p.exists():
        raise InputError(f"{path}: no such bag")
    try:
        reader = AnyReader([p], default_typestore=_TS1 if p.suffix == ".bag" else _TS2)
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for a bad bag
        raise InputError(f"{path}: cannot open as a ROS bag: {exc}") from exc
    return reader


def list_topics(path: str | Path) -> dict[str, str]:
    """Topic -> message type of every connection in the bag."""
    reader = _open(Path(path))
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def read_imu_bag(path: str | Path, topic: str | None = None) -> ImuLog:
    """The ``sensor_msgs/Imu`` messages of ``topic`` (the only Imu topic when None), stamped by their
    header. A bag without the topic is an InputError listing the topics it has."""
    p = Path(path)
    reader = _open(p)
    try:
        conns = [c for c in reader.connections if c.msgtype == IMU_TYPE]
        listing = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
        if topic is not None:
            conns = [c for c in conns if c.topic == topic]
            if not conns:
                raise InputError(f"{p}: no {IMU_TYPE} topic '{topic}'; the bag has: {listing}")
        elif len({c.topic for c in conns}) != 1:
            what = "no" if not conns else "several"
            raise InputError(f"{p}: {what} {IMU_TYPE} topics; pass --topic. The bag has: {listing}")
        n = sum(c.msgcount for c in conns)
        t = np.empty(n, dtype=np.int64)
        acc = np.empty((n, 3))
        gyr = np.empty((n, 3))
        k = 0
        for conn, _, raw in reader.messages(connections=conns):
            m: Any = reader.deserialize(raw, conn.msgtype)
            t[k] = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            a, w = m.linear_acceleration, m.angular_velocity
            acc[k] = (a.x, a.y, a.z)
            gyr[k] = (w.x, w.y, w.z)
            k += 1
    finally:
        reader.close()
    src = f"{p}:{conns[0].topic}"
    if k == 0:
        raise InputError(f"{src}: the topic has no messages")
    tc = check_and_repair(t[:k], src)
    return ImuLog(tc.t_ns, acc[:k], gyr[:k], "m/s^2", "rad/s", src, list(tc.warnings))


def _imu_msgs(log: ImuLog, frame_id: str, typestore: Any) -> Iterator[tuple[int, Any]]:
    Imu = typestore.types["sensor_msgs/msg/Imu"]
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    Vec = typestore.types["geometry_msgs/msg/Vector3"]
    Quat = typestore.types["geometry_msgs/msg/Quaternion"]
    cov = np.zeros(9)
    cov_unknown = np.zeros(9)
    cov_unknown[0] = -1.0  # REP-145: orientation not provided
    for i in range(len(log)):
        t = int(log.t_ns[i])
        a, w = log.accel[i], log.gyro[i]
        hdr_kw: dict[str, Any] = {
            "stamp": Time(sec=t // 1_000_000_000, nanosec=t % 1_000_000_000),
            "frame_id": frame_id,
        }
        if "seq" in Header.__dataclass_fields__:
            hdr_kw["seq"] = i
        msg = Imu(
            header=Header(**hdr_kw),
            orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=cov_unknown,
            angular_velocity=Vec(x=float(w[0]), y=float(w[1]), z=float(w[2])),
            angular_velocity_covariance=cov,
            linear_acceleration=Vec(x=float(a[0]), y=float(a[1]), z=float(a[2])),
            linear_acceleration_covariance=cov,
        )
        yield t, msg


def _check_si(log: ImuLog) -> None:
    if log.accel_unit != "m/s^2" or log.gyro_unit != "rad/s":
        raise InputError(
            f"{log.source}: sensor_msgs/Imu carries m/s^2 and rad/s; this log is in {log.accel_unit} and "
            f"{log.gyro_unit} (calibrate or convert it first)"
        )


def write_imu_bag(
    log: ImuLog,
    path: str | Path,
    kind: BagKind | None = None,
    topic: str = "/imu/data",
    frame_id: str = "imu_link",
) -> None:
    """Write ``log`` (SI units) as ``sensor_msgs/Imu`` on ``topic``, atomically. ``kind`` from the name."""
    _check_si(log)
    p = Path(path)
    k = kind or bag_kind(p)
    with atomic_path(p) as tmp:
        if k == "ros1":
            w1 = Writer1(tmp)
            w1.open()
            c1 = w1.add_connection(topic, IMU_TYPE, typestore=_TS1)
            for t, msg in _imu_msgs(log, frame_id, _TS1):
                w1.write(c1, t, _TS1.serialize_ros1(msg, IMU_TYPE))
            w1.close()
        else:
            plugin = StoragePlugin.MCAP if k == "mcap" else StoragePlugin.SQLITE3
            w2 = Writer2(tmp, version=8, storage_plugin=plugin)
            w2.open()
            c2 = w2.add_connection(topic, IMU_TYPE, typestore=_TS2)
            for t, msg in _imu_msgs(log, frame_id, _TS2):
                w2.write(c2, t, _TS2.serialize_cdr(msg, IMU_TYPE))
            w2.close()


def replace_imu_topic(src: str | Path, dst: str | Path, topic: str, corrected: ImuLog) -> int:
    """Copy bag ``src`` to ``dst`` (same kind) with the Imu messages of ``topic`` replaced, in order, by
    the samples of ``corrected`` (whose stamps must equal the originals); every other message is copied
    byte for byte. Returns the number of replaced messages. Written atomically."""
    _check_si(corrected)
    sp, dp = Path(src), Path(dst)
    kind = bag_kind(sp)
    reader = _open(sp)
    try:
        if not any(c.topic == topic and c.msgtype == IMU_TYPE for c in reader.connections):
            listing = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections)
            raise InputError(f"{sp}: no {IMU_TYPE} topic '{topic}'; the bag has: {listing}")
        ts = _TS1 if kind == "ros1" else _TS2
        with atomic_path(dp) as tmp:
            writer: Any
            if kind == "ros1":
                writer = Writer1(tmp)
            else:
                plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
                writer = Writer2(tmp, version=8, storage_plugin=plugin)
            writer.open()
            out_conns = {}
            for c in reader.connections:
                if kind == "ros1":
                    out_conns[c.id] = writer.add_connection(
                        c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest, typestore=ts
                    )
                else:
                    out_conns[c.id] = writer.add_connection(
                        c.topic, c.msgtype, typestore=reader.typestore
                    )
            i = 0
            for c, t, raw in reader.messages():
                if c.topic == topic and c.msgtype == IMU_TYPE:
                    msg: Any = reader.deserialize(raw, c.msgtype)
                    stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                    if i >= len(corrected) or int(corrected.t_ns[i]) != stamp:
                        raise InputError(
                            f"{sp}:{topic}: message {i} (stamp {stamp} ns) has no matching corrected sample"
                        )
                    a, w = corrected.accel[i], corrected.gyro[i]
                    (
                        msg.linear_acceleration.x,
                        msg.linear_acceleration.y,
                        msg.linear_acceleration.z,
                    ) = map(float, a)
                    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(
                        float, w
                    )
                    data = (
                        ts.serialize_ros1(msg, c.msgtype)
                        if kind == "ros1"
                        else ts.serialize_cdr(msg, c.msgtype)
                    )
                    writer.write(out_conns[c.id], t, data)
                    i += 1
                else:
                    writer.write(out_conns[c.id], t, raw)
            writer.close()
            if i != len(corrected):
                raise InputError(
                    f"{sp}:{topic}: {i} messages but {len(corrected)} corrected samples"
                )
    finally:
        reader.close()
    return i
