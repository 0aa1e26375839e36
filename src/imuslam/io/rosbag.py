"""ROS 1 bags, ROS 2 bags (sqlite3 and MCAP) with ``sensor_msgs/msg/Imu``, through ``rosbags`` (no ROS).

Read an IMU topic into an :class:`ImuLog`; write an ImuLog as a bag; copy a bag with its IMU topic
replaced by a corrected log and every other message copied byte for byte.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog
from imuslam.io import rosmsg
from imuslam.io.atomic import atomic_path
from imuslam.io.bag import Bag, BagKind, bag_kind, list_topics

__all__ = [
    "BagKind",
    "bag_kind",
    "list_topics",
    "read_imu_bag",
    "replace_imu_topic",
    "write_imu_bag",
]

IMU_TYPE = rosmsg.IMU


def read_imu_bag(path: str | Path, topic: str | None = None) -> ImuLog:
    """The ``sensor_msgs/Imu`` messages of ``topic`` (the only Imu topic when None), stamped by their
    header. A bag without the topic is an InputError listing the topics it has."""
    with Bag(path) as bag:
        return bag.imu(topic)


def _imu_msgs(log: ImuLog, frame_id: str, dialect: rosmsg.Dialect) -> Iterator[tuple[int, Any]]:
    for i in range(len(log)):
        t = int(log.t_ns[i])
        yield t, rosmsg.imu_message(t, log.accel[i], log.gyro[i], frame_id, dialect, seq=i)


def _check_si(log: ImuLog) -> None:
    if log.accel_unit != "m/s^2" or log.gyro_unit != "rad/s":
        raise InputError(
            f"{log.source}: sensor_msgs/Imu carries m/s^2 and rad/s; this log is in {log.accel_unit} and "
            f"{log.gyro_unit} (calibrate or convert it first)"
        )


def _writer2(tmp: Path, plugin: StoragePlugin) -> Any:
    return Writer2(tmp, version=8, storage_plugin=plugin)


def _single_mcap(tmp: Path) -> None:
    """rosbags writes a ROS 2 bag as a folder ``x.mcap/x.mcap.mcap`` + metadata.yaml: keep the one
    .mcap file (it holds its schemas and is read on its own) under the name ``x.mcap``."""
    inner = tmp / f"{tmp.name}.mcap"
    single = tmp.with_name(tmp.name + ".single")
    os.replace(inner, single)
    shutil.rmtree(tmp)
    os.replace(single, tmp)


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
            ts1 = rosmsg.typestore("ros1")
            c1 = w1.add_connection(topic, IMU_TYPE, typestore=ts1)
            for t, msg in _imu_msgs(log, frame_id, "ros1"):
                w1.write(c1, t, ts1.serialize_ros1(msg, IMU_TYPE))
            w1.close()
        else:
            plugin = StoragePlugin.MCAP if k == "mcap" else StoragePlugin.SQLITE3
            w2 = _writer2(tmp, plugin)
            w2.open()
            ts2 = rosmsg.typestore("ros2")
            c2 = w2.add_connection(topic, IMU_TYPE, typestore=ts2)
            for t, msg in _imu_msgs(log, frame_id, "ros2"):
                w2.write(c2, t, ts2.serialize_cdr(msg, IMU_TYPE))
            w2.close()
            if p.suffix == ".mcap":
                _single_mcap(tmp)


def _same_compression(src: Path, kind: str, writer: Any) -> None:
    """Set ``writer`` (not yet open) to compress as bag ``src`` does: a ROS 1 bag's chunks (bz2, lz4:
    from the decompressor its first chunk needs), a ROS 2 bag's file or message compression."""
    if kind == "ros1":
        from rosbags.rosbag1 import Reader as Reader1

        with Reader1(src) as r:
            chunk = next(iter(r.chunks.values()), None)
        mod = getattr(getattr(chunk, "decompressor", None), "__module__", "") or ""
        fmt = {"bz2": Writer1.CompressionFormat.BZ2, "lz4": Writer1.CompressionFormat.LZ4}.get(
            mod.split(".")[0]
        )
        if fmt is not None:
            writer.set_compression(fmt)
        return
    from rosbags.rosbag2 import CompressionFormat, CompressionMode
    from rosbags.rosbag2 import Reader as Reader2

    if kind == "mcap" or not src.is_dir():
        return  # an .mcap file compresses its own chunks
    with Reader2(src) as r:
        fmt2, mode2 = r.compression_format, r.compression_mode
    if fmt2 and mode2 and mode2.upper() in CompressionMode.__members__:
        writer.set_compression(CompressionMode[mode2.upper()], CompressionFormat[fmt2.upper()])


def replace_imu_topic(src: str | Path, dst: str | Path, topic: str, corrected: ImuLog) -> int:
    """Copy bag ``src`` to ``dst`` (same kind and compression) with the Imu messages of ``topic``
    replaced, in order, by the samples of ``corrected`` (whose stamps must equal the originals); every
    other message is copied byte for byte. Returns the number of replaced messages. Written
    atomically."""
    _check_si(corrected)
    sp, dp = Path(src), Path(dst)
    kind = bag_kind(sp)
    bag = Bag(sp)
    reader = bag.reader
    try:
        bag.connections_of([topic], [IMU_TYPE])
        ts = rosmsg.typestore("ros1" if kind == "ros1" else "ros2")
        with atomic_path(dp) as tmp:
            writer: Any
            if kind == "ros1":
                writer = Writer1(tmp)
            else:
                plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
                writer = _writer2(tmp, plugin)
            _same_compression(sp, kind, writer)
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
            for k, (c, t, raw) in enumerate(bag.raw()):
                if c.topic == topic and c.msgtype == IMU_TYPE:
                    msg = bag.deserialize(raw, c.msgtype, k)
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
            if kind != "ros1" and dp.suffix == ".mcap":
                _single_mcap(tmp)
            if i != len(corrected):
                raise InputError(
                    f"{sp}:{topic}: {i} messages but {len(corrected)} corrected samples"
                )
    finally:
        reader.close()
    return i
