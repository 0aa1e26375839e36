"""The one ROS message layer: typestores (built once, on first use) and conversions both ways between
ROS messages and imuslam's records.

Messages: ``sensor_msgs/Imu``, ``sensor_msgs/PointCloud2`` (x, y, z, intensity, ring and a per-point time
under the names drivers use), ``sensor_msgs/LaserScan`` and ``MultiEchoLaserScan`` (first echo),
``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped`` / ``PointStamped``, ``sensor_msgs/Image`` and
``CompressedImage``. Quaternion order is converted here (ROS x y z w <-> ``quat_wxyz``).

Per-point time in a PointCloud2 (:func:`point_time_offsets`): the field ``t`` (Ouster: uint32 ns from
the stamp; the simulator: float32 s), ``time`` (Velodyne: float32 s relative to the stamp, negative when
the driver stamps the end of the sweep), ``timestamp`` (Hesai / RoboSense: float64 absolute s) or
``offset_time`` (Livox: uint32 ns relative). Integer fields are ns, float fields are s; values that look
like an epoch (more than 1e6 s) are absolute and made relative to the header stamp.
"""

from __future__ import annotations

from functools import cache
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.lidar import Scan2d, Scan3d

FloatArray = NDArray[np.float64]
Dialect = Literal["ros1", "ros2"]

__all__ = [
    "IMU",
    "IMAGE",
    "COMPRESSED_IMAGE",
    "LASERSCAN",
    "MULTIECHO_LASERSCAN",
    "ODOMETRY",
    "POINTCLOUD2",
    "POINTSTAMPED",
    "POSESTAMPED",
    "header",
    "image_from_msg",
    "image_message",
    "imu_message",
    "imu_sample",
    "laserscan_message",
    "odometry_message",
    "point_time_offsets",
    "pointcloud2_message",
    "pointstamped_message",
    "pose_from_msg",
    "posestamped_message",
    "scan2d_from_msg",
    "scan3d_from_msg",
    "stamp_ns",
    "typestore",
]

IMU = "sensor_msgs/msg/Imu"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
LASERSCAN = "sensor_msgs/msg/LaserScan"
MULTIECHO_LASERSCAN = "sensor_msgs/msg/MultiEchoLaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
POSESTAMPED = "geometry_msgs/msg/PoseStamped"
POINTSTAMPED = "geometry_msgs/msg/PointStamped"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"

TIME_FIELDS = ("t", "time", "timestamp", "offset_time")
RING_FIELDS = ("ring", "line")
INTENSITY_FIELDS = ("intensity", "reflectivity")
# sensor_msgs/PointField datatypes
_PF_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_PF_CODES = {np.dtype(v).str[1:]: k for k, v in _PF_DTYPES.items()}


@cache
def typestore(dialect: Dialect = "ros2") -> Any:
    """The rosbags typestore (ROS 1 Noetic or ROS 2 Humble), built on first use only."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if dialect == "ros1" else Stores.ROS2_HUMBLE)


def stamp_ns(msg: Any) -> int:
    """The header stamp of a message, ns."""
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


def header(t_ns: int, frame_id: str, dialect: Dialect = "ros2", seq: int = 0) -> Any:
    T = typestore(dialect).types
    stamp = T["builtin_interfaces/msg/Time"](
        sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)
    )
    if dialect == "ros1":
        return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def _vec(v: FloatArray, dialect: Dialect) -> Any:
    return typestore(dialect).types["geometry_msgs/msg/Vector3"](
        x=float(v[0]), y=float(v[1]), z=float(v[2])
    )


def _point(v: FloatArray, dialect: Dialect) -> Any:
    return typestore(dialect).types["geometry_msgs/msg/Point"](
        x=float(v[0]), y=float(v[1]), z=float(v[2])
    )


def _quat(q_wxyz: FloatArray, dialect: Dialect) -> Any:
    return typestore(dialect).types["geometry_msgs/msg/Quaternion"](
        x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]), w=float(q_wxyz[0])
    )


def _pose(p: FloatArray, q_wxyz: FloatArray, dialect: Dialect) -> Any:
    return typestore(dialect).types["geometry_msgs/msg/Pose"](
        position=_point(p, dialect), orientation=_quat(q_wxyz, dialect)
    )


# ---------------------------------------------------------------------------------------------------
# IMU


def imu_sample(msg: Any) -> tuple[int, FloatArray, FloatArray]:
    """(t_ns, accel (3,) m/s^2, gyro (3,) rad/s) of a ``sensor_msgs/Imu``."""
    a, w = msg.linear_acceleration, msg.angular_velocity
    return stamp_ns(msg), np.array([a.x, a.y, a.z]), np.array([w.x, w.y, w.z])


def imu_message(t_ns: int, accel: FloatArray, gyro: FloatArray, frame_id: str = "imu_link",
                dialect: Dialect = "ros2", seq: int = 0) -> Any:  # fmt: skip
    """A ``sensor_msgs/Imu`` without orientation (REP-145: covariance[0] = -1)."""
    T = typestore(dialect).types
    cov = np.zeros(9)
    ocov = np.zeros(9)
    ocov[0] = -1.0
    return T[IMU](
        header=header(t_ns, frame_id, dialect, seq), orientation=_quat(np.array([1.0, 0, 0, 0]), dialect),
        orientation_covariance=ocov, angular_velocity=_vec(gyro, dialect), angular_velocity_covariance=cov,
        linear_acceleration=_vec(accel, dialect), linear_acceleration_covariance=cov,
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------------
# PointCloud2


def _cloud_array(msg: Any) -> NDArray[Any]:
    names, formats, offsets = [], [], []
    end = ">" if msg.is_bigendian else "<"
    for f in msg.fields:
        if f.datatype not in _PF_DTYPES:
            raise InputError(f"PointCloud2 field '{f.name}': unknown datatype {f.datatype}")
        names.append(f.name)
        formats.append(
            end + _PF_DTYPES[f.datatype]
            if f.count == 1
            else (end + _PF_DTYPES[f.datatype], f.count)
        )
        offsets.append(f.offset)
        end_byte = f.offset + np.dtype(_PF_DTYPES[f.datatype]).itemsize * max(int(f.count), 1)
        if f.offset < 0 or end_byte > msg.point_step:
            raise InputError(
                f"PointCloud2 field '{f.name}' (bytes {f.offset} to {end_byte}) lies beyond the "
                f"point_step of {msg.point_step} bytes; expected every field inside a point"
            )
    dt = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": msg.point_step}
    )
    n = int(msg.width) * int(msg.height)
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.row_step * msg.height != data.size or msg.point_step * msg.width > msg.row_step:
        raise InputError(
            f"PointCloud2: {data.size} bytes for {msg.height} rows of {msg.row_step} "
            f"(point_step {msg.point_step}, width {msg.width})"
        )
    rows = data.reshape(msg.height, msg.row_step)[:, : msg.point_step * msg.width]
    return np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dt, count=n)


def point_time_offsets(arr: NDArray[Any], stamp: int) -> tuple[FloatArray, str | None]:
    """Per-point time offsets (P,) s relative to the header stamp (ns), and the field used (None: zeros)."""
    names = arr.dtype.names or ()
    for name in TIME_FIELDS:
        if name in names:
            col = arr[name]
            if np.issubdtype(col.dtype, np.integer):
                v = col.astype(np.int64)
                if v.size and np.abs(v).max() > 10**15:  # absolute ns
                    return (v - stamp).astype(np.float64) * 1e-9, name
                return v.astype(np.float64) * 1e-9, name
            s = col.astype(np.float64)
            if s.size and np.nanmax(np.abs(s)) > 1e15:  # absolute ns as floats (livox_ros_driver2)
                return (s - float(stamp)) * 1e-9, name
            if s.size and np.nanmax(np.abs(s)) > 1e6:  # absolute seconds
                whole = stamp // 1_000_000_000
                return (s - whole) - (stamp - whole * 1_000_000_000) * 1e-9, name
            return s, name
    return np.zeros(arr.shape[0]), None


def scan3d_from_msg(msg: Any) -> Scan3d:
    """A ``sensor_msgs/PointCloud2`` as a :class:`Scan3d` (points with a NaN coordinate dropped)."""
    arr = _cloud_array(msg)
    names = arr.dtype.names or ()
    for c in ("x", "y", "z"):
        if c not in names:
            raise InputError(f"PointCloud2 without field '{c}' (fields: {', '.join(names)})")
    stamp = stamp_ns(msg)
    pts = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float32)
    toff, _ = point_time_offsets(arr, stamp)
    ring_f = next((f for f in RING_FIELDS if f in names), None)
    inten_f = next((f for f in INTENSITY_FIELDS if f in names), None)
    ring = arr[ring_f].astype(np.uint16) if ring_f else np.zeros(len(arr), np.uint16)
    inten = arr[inten_f].astype(np.float32) if inten_f else np.zeros(len(arr), np.float32)
    ok = np.isfinite(pts).all(axis=1)
    return Scan3d(stamp, pts[ok], toff[ok].astype(np.float32), ring[ok], inten[ok])


# the drivers' point layouts (``pointcloud2_message``): name, dtype; fields starting with _ are padding
POINT_LAYOUTS = {
    # ouster-ros (driver 0.10+, the default point type): t in uint32 ns from the scan start
    "ouster": [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("_pad0", "<f4"), ("intensity", "<f4"),
               ("t", "<u4"), ("reflectivity", "<u2"), ("ring", "<u2"), ("ambient", "<u2"),
               ("_pad1", "<u2"), ("range", "<u4")],
    # livox_ros_driver2 (xfer_format 0): timestamp in float64 ns since the epoch, line = the laser
    "livox": [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("tag", "u1"),
              ("line", "u1"), ("timestamp", "<f8")],
}  # fmt: skip


def _fill_layout(arr: NDArray[Any], scan: Scan3d, layout: str) -> None:
    """The time, ring and extra fields of a driver's layout from ``scan``."""
    t_rel_ns = np.round(scan.t_offset_s.astype(np.float64) * 1e9)
    if layout == "ouster":
        arr["t"] = np.maximum(t_rel_ns, 0).astype(np.uint32)
        arr["ring"] = scan.ring if len(scan.ring) == len(arr) else 0
        arr["reflectivity"] = np.clip(scan.intensity * 255, 0, 65535).astype(np.uint16)
        arr["range"] = np.round(np.linalg.norm(scan.points_l, axis=1) * 1e3).astype(np.uint32)
    else:
        arr["timestamp"] = float(scan.t_ns) + t_rel_ns
        arr["line"] = scan.ring % 6 if len(scan.ring) == len(arr) else 0


def pointcloud2_message(scan: Scan3d, frame_id: str = "lidar_link", dialect: Dialect = "ros2",
                        time_field: str = "t", layout: str = "default") -> Any:  # fmt: skip
    """A ``sensor_msgs/PointCloud2`` stamped ``scan.t_ns`` with fields x, y, z, intensity (float32),
    ``time_field`` (float32 s from the stamp) and ring (uint16); or a driver's ``layout``
    (``POINT_LAYOUTS``: ``ouster``, ``livox``)."""
    T = typestore(dialect).types
    if layout == "default":
        spec = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), (time_field, "<f4"),
                ("ring", "<u2"), ("_pad", "<u2")]  # fmt: skip
    else:
        spec = POINT_LAYOUTS[layout]
    dt = np.dtype(spec)
    arr = np.zeros(len(scan.points_l), dtype=dt)
    arr["x"], arr["y"], arr["z"] = scan.points_l[:, 0], scan.points_l[:, 1], scan.points_l[:, 2]
    arr["intensity"] = scan.intensity
    if layout == "default":
        arr[time_field], arr["ring"] = scan.t_offset_s, scan.ring
    else:
        _fill_layout(arr, scan, layout)
    PF = T["sensor_msgs/msg/PointField"]
    fl = dt.fields
    assert fl is not None
    fields = [
        PF(name=n, offset=fl[n][1], datatype=_PF_CODES[fl[n][0].str[1:]], count=1)
        for n, _ in spec
        if not n.startswith("_")
    ]
    return T[POINTCLOUD2](
        header=header(scan.t_ns, frame_id, dialect), height=1, width=len(arr), fields=fields,
        is_bigendian=False, point_step=dt.itemsize, row_step=dt.itemsize * len(arr),
        data=np.frombuffer(arr.tobytes(), dtype=np.uint8), is_dense=True,
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------------
# LaserScan


def scan2d_from_msg(msg: Any) -> Scan2d:
    """A ``LaserScan`` (or the first echo of a ``MultiEchoLaserScan``) as a :class:`Scan2d`; ranges
    outside [range_min, range_max] become inf."""
    if hasattr(msg.ranges, "__len__") and len(msg.ranges) and hasattr(msg.ranges[0], "echoes"):
        ranges = np.array(
            [e.echoes[0] if len(e.echoes) else np.inf for e in msg.ranges], np.float32
        )
        inten = np.array(
            [e.echoes[0] if len(e.echoes) else 0.0 for e in msg.intensities], np.float32
        )
    else:
        ranges = np.asarray(msg.ranges, np.float32).copy()
        inten = np.asarray(msg.intensities, np.float32).copy()
    if len(ranges) > 1 and msg.angle_increment != 0:
        # a scan whose angle fields disagree with its number of ranges cannot be placed beam by beam
        expected = (msg.angle_max - msg.angle_min) / msg.angle_increment + 1.0
        if abs(expected - len(ranges)) > 1.01:
            raise InputError(
                f"LaserScan stamped {stamp_ns(msg)} ns: angle_min {msg.angle_min:.6g}, angle_max "
                f"{msg.angle_max:.6g}, angle_increment {msg.angle_increment:.6g} give {expected:.1f} beams "
                f"but it has {len(ranges)} ranges"
            )
    bad = ~np.isfinite(ranges) | (ranges < msg.range_min) | (ranges > msg.range_max)
    ranges[bad] = np.inf
    if inten.shape != ranges.shape:
        inten = np.zeros_like(ranges)
    return Scan2d(stamp_ns(msg), float(msg.angle_min), float(msg.angle_increment), float(msg.time_increment),
                  float(msg.scan_time), float(msg.range_min), float(msg.range_max), ranges, inten)  # fmt: skip


def laserscan_message(scan: Scan2d, frame_id: str = "laser", dialect: Dialect = "ros2") -> Any:
    T = typestore(dialect).types
    return T[LASERSCAN](
        header=header(scan.t_ns, frame_id, dialect), angle_min=scan.angle_min,
        angle_max=scan.angle_min + scan.angle_increment * (len(scan.ranges) - 1),
        angle_increment=scan.angle_increment, time_increment=scan.time_increment, scan_time=scan.scan_time,
        range_min=scan.range_min, range_max=scan.range_max, ranges=np.asarray(scan.ranges, np.float32),
        intensities=np.asarray(scan.intensities, np.float32),
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------------
# poses


def pose_from_msg(msg: Any) -> tuple[int, FloatArray, FloatArray]:
    """(t_ns, position (3,), quat_wxyz (4,)) of a PoseStamped, PoseWithCovarianceStamped or Odometry;
    a PointStamped gives the identity rotation."""
    if hasattr(msg, "point"):
        pt = msg.point
        return stamp_ns(msg), np.array([pt.x, pt.y, pt.z]), np.array([1.0, 0.0, 0.0, 0.0])
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    o = pose.orientation
    p = pose.position
    return stamp_ns(msg), np.array([p.x, p.y, p.z]), np.array([o.w, o.x, o.y, o.z])


def posestamped_message(t_ns: int, p: FloatArray, q_wxyz: FloatArray, frame_id: str = "map",
                        dialect: Dialect = "ros2") -> Any:  # fmt: skip
    T = typestore(dialect).types
    return T[POSESTAMPED](header=header(t_ns, frame_id, dialect), pose=_pose(p, q_wxyz, dialect))


def pointstamped_message(
    t_ns: int, p: FloatArray, frame_id: str = "map", dialect: Dialect = "ros2"
) -> Any:
    T = typestore(dialect).types
    return T[POINTSTAMPED](header=header(t_ns, frame_id, dialect), point=_point(p, dialect))


def odometry_message(t_ns: int, p: FloatArray, q_wxyz: FloatArray, frame_id: str = "odom",
                     child_frame_id: str = "base_link", v_b: FloatArray | None = None,
                     omega_b: FloatArray | None = None, dialect: Dialect = "ros2") -> Any:  # fmt: skip
    """A ``nav_msgs/Odometry``: pose in ``frame_id``, twist (linear v_b, angular omega_b) in the child."""
    T = typestore(dialect).types
    cov = np.zeros(36)
    z = np.zeros(3)
    return T[ODOMETRY](
        header=header(t_ns, frame_id, dialect), child_frame_id=child_frame_id,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(p, q_wxyz, dialect), covariance=cov),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=_vec(z if v_b is None else v_b, dialect),
                                               angular=_vec(z if omega_b is None else omega_b, dialect)),
            covariance=cov,
        ),
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------------
# images

_ENCODINGS = {"mono8": (np.uint8, 1), "8UC1": (np.uint8, 1), "bgr8": (np.uint8, 3), "rgb8": (np.uint8, 3),
              "mono16": (np.uint16, 1), "16UC1": (np.uint16, 1), "bgra8": (np.uint8, 4),
              "rgba8": (np.uint8, 4), "32FC1": (np.float32, 1)}  # fmt: skip


def image_from_msg(msg: Any) -> tuple[int, NDArray[Any]]:
    """(t_ns, image (H, W) or (H, W, C)) of an ``Image`` or ``CompressedImage`` (decoded by OpenCV);
    colour stays in the message's channel order (bgr8 as BGR)."""
    if hasattr(msg, "format"):  # CompressedImage
        import cv2

        img = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"CompressedImage at {stamp_ns(msg)} ns: cannot decode '{msg.format}'")
        return stamp_ns(msg), img
    if msg.encoding not in _ENCODINGS:
        raise InputError(
            f"Image encoding '{msg.encoding}'; expected one of {', '.join(_ENCODINGS)}"
        )
    dtype, ch = _ENCODINGS[msg.encoding]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row = np.asarray(msg.data, np.uint8).reshape(msg.height, msg.step)[
        :, : msg.width * ch * dt.itemsize
    ]
    img = np.frombuffer(np.ascontiguousarray(row).tobytes(), dtype=dt).reshape(
        msg.height, msg.width, ch
    )
    return stamp_ns(msg), (img[:, :, 0] if ch == 1 else img).astype(dtype)


def image_message(
    t_ns: int, img: NDArray[Any], frame_id: str = "camera", dialect: Dialect = "ros2"
) -> Any:
    """An ``Image``: uint8 (H, W) mono8, (H, W, 3) bgr8; uint16 (H, W) mono16."""
    T = typestore(dialect).types
    a = np.ascontiguousarray(img)
    if a.dtype == np.uint8:
        enc = "mono8" if a.ndim == 2 else "bgr8"
    elif a.dtype == np.uint16 and a.ndim == 2:
        enc = "mono16"
    else:
        raise InputError(f"image of {a.dtype} {a.shape}: expected uint8 mono/bgr or uint16 mono")
    h, w = a.shape[:2]
    return T[IMAGE](header=header(t_ns, frame_id, dialect), height=h, width=w, encoding=enc, is_bigendian=0,
                    step=a.strides[0], data=np.frombuffer(a.tobytes(), np.uint8))  # fmt: skip
