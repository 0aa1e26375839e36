"""Writing simulated sensor streams as a ROS 2 bag (MCAP) with standard messages, through the one
message layer (:mod:`imuslam.io.rosmsg`) and rosbags.

Topics and frames (REP-103 / REP-105): ``/imu/data`` sensor_msgs/Imu (imu_link); ``/points``
sensor_msgs/PointCloud2 (lidar_link; fields x, y, z, intensity float32, t float32 seconds from the scan
start, ring uint16); ``/scan`` sensor_msgs/LaserScan (laser); ``/odom`` nav_msgs/Odometry (odom ->
base_link); ``/ground_truth`` geometry_msgs/PoseStamped (map); ``/rtk`` geometry_msgs/PointStamped (map).
Messages are written in time order by merging lazily generated streams.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.rosbag2 import StoragePlugin, Writer

from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan2d, Scan3d
from imuslam.io import rosmsg
from imuslam.io.atomic import atomic_path

Message = tuple[int, str, Any]  # (t_ns, topic, message)


def imu_messages(
    log: ImuLog, topic: str = "/imu/data", frame: str = "imu_link"
) -> Iterator[Message]:
    for i in range(len(log)):
        t = int(log.t_ns[i])
        yield t, topic, rosmsg.imu_message(t, log.accel[i], log.gyro[i], frame)


def pointcloud_message(scan: Scan3d, frame: str = "lidar_link") -> tuple[int, Any]:
    """A PointCloud2 stamped at the scan start (its per-point ``t`` is the offset from it)."""
    return scan.t_ns, rosmsg.pointcloud2_message(scan, frame)


def laserscan_message(scan: Scan2d, frame: str = "laser") -> Any:
    return rosmsg.laserscan_message(scan, frame)


def pose_messages(
    t_ns: NDArray[np.int64],
    p: NDArray[np.float64],
    q_wxyz: NDArray[np.float64],
    topic: str,
    frame: str = "map",
) -> Iterator[Message]:
    for i in range(len(t_ns)):
        t = int(t_ns[i])
        yield t, topic, rosmsg.posestamped_message(t, p[i], q_wxyz[i], frame)


def point_messages(
    t_ns: NDArray[np.int64], p: NDArray[np.float64], topic: str, frame: str = "map"
) -> Iterator[Message]:
    for i in range(len(t_ns)):
        t = int(t_ns[i])
        yield t, topic, rosmsg.pointstamped_message(t, p[i], frame)


def odometry_messages(
    t_ns: NDArray[np.int64], xy_yaw: NDArray[np.float64], topic: str = "/odom"
) -> Iterator[Message]:
    for i in range(len(t_ns)):
        t = int(t_ns[i])
        yaw = xy_yaw[i, 2]
        q = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        p = np.array([xy_yaw[i, 0], xy_yaw[i, 1], 0.0])
        yield t, topic, rosmsg.odometry_message(t, p, q, "odom", "base_link")


MSGTYPE = {
    "/imu/data": "sensor_msgs/msg/Imu", "/points": "sensor_msgs/msg/PointCloud2", "/scan": "sensor_msgs/msg/LaserScan",
    "/odom": "nav_msgs/msg/Odometry", "/ground_truth": "geometry_msgs/msg/PoseStamped", "/rtk": "geometry_msgs/msg/PointStamped",
}  # fmt: skip


def write_bag(
    path: str | Path,
    streams: Iterable[Iterable[Message]],
    progress: Callable[[int], None] | None = None,
) -> int:
    """Merge time-sorted message streams into a ROS 2 MCAP bag at ``path`` (a folder), atomically.

    Returns the number of messages written; ``progress(t_ns)`` is called per message if given.
    """
    n = 0
    ts = rosmsg.typestore("ros2")
    with atomic_path(path) as tmp:
        w = Writer(tmp, version=8, storage_plugin=StoragePlugin.MCAP)
        w.open()
        conns: dict[str, Any] = {}
        for t, topic, msg in _merge(streams):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, MSGTYPE[topic], typestore=ts)
            w.write(conns[topic], t, ts.serialize_cdr(msg, MSGTYPE[topic]))
            n += 1
            if progress is not None:
                progress(t)
        w.close()
    return n


def _merge(streams: Iterable[Iterable[Message]]) -> Iterator[Message]:
    tagged = [((m[0], k, m[1], m[2]) for m in s) for k, s in enumerate(streams)]
    for t, _, topic, msg in heapq.merge(*tagged, key=lambda x: (x[0], x[1])):
        yield t, topic, msg
