"""Writing simulated sensor streams as a ROS 2 bag (MCAP) with standard messages, through rosbags.

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
from rosbags.typesys import Stores, get_typestore

from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan2d, Scan3d
from imuslam.io.atomic import atomic_path

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
Message = tuple[int, str, Any]  # (t_ns, topic, message)


def _stamp(t_ns: int) -> Any:
    return T["builtin_interfaces/msg/Time"](
        sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)
    )


def _header(t_ns: int, frame: str) -> Any:
    return T["std_msgs/msg/Header"](stamp=_stamp(t_ns), frame_id=frame)


def _vec(x: NDArray[np.float64]) -> Any:
    return T["geometry_msgs/msg/Vector3"](x=float(x[0]), y=float(x[1]), z=float(x[2]))


def _quat(q_wxyz: NDArray[np.float64]) -> Any:
    return T["geometry_msgs/msg/Quaternion"](
        x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]), w=float(q_wxyz[0])
    )


def _pose(p: NDArray[np.float64], q: NDArray[np.float64]) -> Any:
    return T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
        orientation=_quat(q),
    )


def imu_messages(
    log: ImuLog, topic: str = "/imu/data", frame: str = "imu_link"
) -> Iterator[Message]:
    cov = np.zeros(9)
    ocov = np.zeros(9)
    ocov[0] = -1.0  # REP-145: no orientation
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    for i in range(len(log)):
        t = int(log.t_ns[i])
        yield t, topic, T["sensor_msgs/msg/Imu"](
            header=_header(t, frame), orientation=_quat(ident), orientation_covariance=ocov,
            angular_velocity=_vec(log.gyro[i]), angular_velocity_covariance=cov,
            linear_acceleration=_vec(log.accel[i]), linear_acceleration_covariance=cov,
        )  # fmt: skip


_PC_DTYPE = np.dtype(
    [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("intensity", "<f4"),
        ("t", "<f4"),
        ("ring", "<u2"),
        ("_pad", "<u2"),
    ]
)


def pointcloud_message(scan: Scan3d, frame: str = "lidar_link") -> tuple[int, Any]:
    """A PointCloud2 stamped at the scan start (its per-point ``t`` is the offset from it).

    PointField datatypes: 7 = FLOAT32, 4 = UINT16 (sensor_msgs/PointField).
    """
    PF = T["sensor_msgs/msg/PointField"]
    arr = np.zeros(len(scan.points_l), dtype=_PC_DTYPE)
    arr["x"], arr["y"], arr["z"] = scan.points_l[:, 0], scan.points_l[:, 1], scan.points_l[:, 2]
    arr["intensity"], arr["t"], arr["ring"] = scan.intensity, scan.t_offset_s, scan.ring
    fields = [
        PF(name="x", offset=0, datatype=7, count=1), PF(name="y", offset=4, datatype=7, count=1),
        PF(name="z", offset=8, datatype=7, count=1), PF(name="intensity", offset=12, datatype=7, count=1),
        PF(name="t", offset=16, datatype=7, count=1), PF(name="ring", offset=20, datatype=4, count=1),
    ]  # fmt: skip
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=_header(scan.t0_ns, frame), height=1, width=len(arr), fields=fields, is_bigendian=False,
        point_step=_PC_DTYPE.itemsize, row_step=_PC_DTYPE.itemsize * len(arr),
        data=np.frombuffer(arr.tobytes(), dtype=np.uint8), is_dense=True,
    )  # fmt: skip
    return scan.t0_ns, msg


def laserscan_message(scan: Scan2d, frame: str = "laser") -> Any:
    return T["sensor_msgs/msg/LaserScan"](
        header=_header(scan.t0_ns, frame), angle_min=scan.angle_min,
        angle_max=scan.angle_min + scan.angle_increment * (len(scan.ranges) - 1),
        angle_increment=scan.angle_increment, time_increment=scan.time_increment, scan_time=scan.scan_time,
        range_min=scan.range_min, range_max=scan.range_max, ranges=scan.ranges, intensities=scan.intensities,
    )  # fmt: skip


def pose_messages(
    t_ns: NDArray[np.int64],
    p: NDArray[np.float64],
    q_wxyz: NDArray[np.float64],
    topic: str,
    frame: str = "map",
) -> Iterator[Message]:
    for i in range(len(t_ns)):
        t = int(t_ns[i])
        yield (
            t,
            topic,
            T["geometry_msgs/msg/PoseStamped"](
                header=_header(t, frame), pose=_pose(p[i], q_wxyz[i])
            ),
        )


def point_messages(
    t_ns: NDArray[np.int64], p: NDArray[np.float64], topic: str, frame: str = "map"
) -> Iterator[Message]:
    for i in range(len(t_ns)):
        t = int(t_ns[i])
        pt = T["geometry_msgs/msg/Point"](x=float(p[i, 0]), y=float(p[i, 1]), z=float(p[i, 2]))
        yield t, topic, T["geometry_msgs/msg/PointStamped"](header=_header(t, frame), point=pt)


def odometry_messages(
    t_ns: NDArray[np.int64], xy_yaw: NDArray[np.float64], topic: str = "/odom"
) -> Iterator[Message]:
    cov = np.zeros(36)
    for i in range(len(t_ns)):
        t = int(t_ns[i])
        yaw = xy_yaw[i, 2]
        q = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        pose = T["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(np.array([xy_yaw[i, 0], xy_yaw[i, 1], 0.0]), q), covariance=cov
        )
        tw = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=_vec(np.zeros(3)), angular=_vec(np.zeros(3))),
            covariance=cov,
        )
        yield (
            t,
            topic,
            T["nav_msgs/msg/Odometry"](
                header=_header(t, "odom"), child_frame_id="base_link", pose=pose, twist=tw
            ),
        )


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
    with atomic_path(path) as tmp:
        w = Writer(tmp, version=8, storage_plugin=StoragePlugin.MCAP)
        w.open()
        conns: dict[str, Any] = {}
        for t, topic, msg in _merge(streams):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, MSGTYPE[topic], typestore=TS)
            w.write(conns[topic], t, TS.serialize_cdr(msg, MSGTYPE[topic]))
            n += 1
            if progress is not None:
                progress(t)
        w.close()
    return n


def _merge(streams: Iterable[Iterable[Message]]) -> Iterator[Message]:
    tagged = [((m[0], k, m[1], m[2]) for m in s) for k, s in enumerate(streams)]
    for t, _, topic, msg in heapq.merge(*tagged, key=lambda x: (x[0], x[1])):
        yield t, topic, msg
