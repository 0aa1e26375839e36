"""Reading ROS bags (ROS 1 ``.bag``, ROS 2 sqlite3 or MCAP folders, standalone ``.mcap`` files) as
imuslam records, through rosbags (no ROS install).

:class:`Bag` lists topics and iterates the messages of chosen topics in time order, converted by
:mod:`imuslam.io.rosmsg` (IMU, LiDAR, 2D scans, odometry, poses); the estimators' readers
(``io.lidarsets.BagLidarDataset``, ``io.stereosets.BagStereo``) build on it. Every rosbags
error is an :class:`~imuslam.errors.InputError` naming the bag; a missing topic lists the topics present.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import SimpleNamespace, TracebackType
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan2d, Scan3d
from imuslam.interfaces.trajectory import Trajectory
from imuslam.io import rosmsg

BagKind = Literal["ros1", "ros2", "mcap"]

__all__ = ["Bag", "BagKind", "bag_kind", "list_topics"]


def bag_kind(path: str | Path) -> BagKind:
    """``ros1`` for a ``.bag`` file, ``mcap`` for an ``.mcap`` file or a ROS 2 folder of MCAP, else ``ros2``."""
    p = Path(path)
    if p.suffix == ".bag":
        return "ros1"
    if p.suffix == ".mcap" or (p.is_dir() and any(p.glob("*.mcap"))):
        return "mcap"
    return "ros2"


class Bag:
    """An open bag: ``with Bag(path) as bag: bag.topics(); for topic, rec in bag.records([...])``."""

    def __init__(self, path: str | Path) -> None:
        from rosbags.highlevel import AnyReader, AnyReaderError

        self.path = Path(path)
        p = self.path
        if not p.exists():
            raise InputError(f"{path}: no such bag")
        # A .mcap file is read as itself (it holds its schemas), never through the folder it lies in:
        # that folder's metadata.yaml may describe another bag. An sqlite3 .db3 needs its folder's.
        if p.suffix == ".db3" and p.is_file() and (p.parent / "metadata.yaml").is_file():
            p = p.parent
        if p.is_dir() and not (p / "metadata.yaml").is_file():
            raise InputError(f"{path}: a folder without metadata.yaml; expected a ROS 2 bag folder")
        self.dialect: rosmsg.Dialect = "ros1" if p.suffix == ".bag" else "ros2"
        try:
            self.reader = AnyReader([p], default_typestore=rosmsg.typestore(self.dialect))
            self.reader.open()
        except (AnyReaderError, Exception) as exc:  # rosbags raises several types for a bad bag
            raise InputError(f"{path}: cannot open as a ROS bag: {exc}") from exc

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        self.close()

    @property
    def connections(self) -> list[Any]:
        return list(self.reader.connections)

    def topics(self) -> dict[str, str]:
        """Topic -> message type."""
        return {c.topic: c.msgtype for c in self.reader.connections}

    def listing(self) -> str:
        return ", ".join(f"{t} ({m})" for t, m in self.topics().items()) or "none"

    def connections_of(
        self, topics: Sequence[str], types: Sequence[str] | None = None
    ) -> list[Any]:
        """The connections of ``topics``; a topic not present (or of another type) is an InputError
        listing the topics present."""
        have = self.topics()
        for t in topics:
            if t not in have or (types is not None and have[t] not in types):
                want = f" of type {' or '.join(types)}" if types else ""
                raise InputError(
                    f"{self.path}: no topic '{t}'{want}; the bag has: {self.listing()}"
                )
        return [c for c in self.reader.connections if c.topic in topics]

    def topic_of_type(self, types: Sequence[str], topic: str | None = None) -> str:
        """``topic`` if it has one of ``types``, else the only topic of those types (InputError when none or
        several, listing the topics)."""
        if topic is not None:
            self.connections_of([topic], types)
            return topic
        cands = sorted({t for t, m in self.topics().items() if m in types})
        if len(cands) != 1:
            what = "no" if not cands else "several"
            raise InputError(
                f"{self.path}: {what} {' / '.join(types)} topics; name one. The bag has: {self.listing()}"
            )
        return cands[0]

    def count(self, topic: str) -> int:
        return sum(c.msgcount for c in self.reader.connections if c.topic == topic)

    def raw(self, connections: Sequence[Any] | None = None) -> Iterator[tuple[Any, int, bytes]]:
        """(connection, receive time ns, serialised bytes) in time order; a bag damaged after its header
        (a truncated or overwritten chunk) is an InputError naming the bag and the last good message."""
        it = self.reader.messages(connections=connections) if connections is not None else (
            self.reader.messages())  # fmt: skip
        k = 0
        while True:
            try:
                item = next(it, None)
            except Exception as exc:  # rosbags' ReaderError / AnyReaderError, struct, decompression
                raise InputError(f"{self.path}: corrupted after message {k}: {exc}") from exc
            if item is None:
                return
            yield item
            k += 1

    def deserialize(self, raw: bytes, msgtype: str, k: int) -> Any:
        """Message ``k`` of ``msgtype`` from its bytes; bytes that do not decode name the message."""
        try:
            return self.reader.deserialize(raw, msgtype)
        except Exception as exc:  # a damaged message: struct, index or decode errors
            raise InputError(
                f"{self.path}: message {k} ({msgtype}) does not decode: {exc}"
            ) from exc

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        """(topic, receive time ns, deserialised message) of ``topics`` in time order."""
        for k, (c, t, raw) in enumerate(self.raw(self.connections_of(topics))):
            yield c.topic, int(t), self.deserialize(raw, c.msgtype, k)

    def records(self, topics: Sequence[str]) -> Iterator[tuple[str, Any]]:
        """(topic, record) in time order: Imu -> (t_ns, accel, gyro); PointCloud2 -> Scan3d;
        LaserScan / MultiEchoLaserScan -> Scan2d; Odometry / PoseStamped / PointStamped ->
        (t_ns, p, quat_wxyz); Image / CompressedImage -> (t_ns, image)."""
        types = self.topics()
        for topic, _, msg in self.messages(topics):
            yield topic, convert(types[topic], msg, f"{self.path}:{topic}")

    # whole topics as records

    def imu(self, topic: str | None = None) -> ImuLog:
        """The Imu messages of ``topic`` (the only Imu topic when None), by header stamp, checked and
        repaired as every reader's stamps (:func:`imuslam.io.timestamps.check_and_repair`)."""
        from imuslam.io.readers import check_samples
        from imuslam.io.timestamps import check_and_repair

        tp = self.topic_of_type([rosmsg.IMU], topic)
        n = self.count(tp)
        t = np.empty(n, np.int64)
        acc = np.empty((n, 3))
        gyr = np.empty((n, 3))
        k = 0
        for _, _, m in self.messages([tp]):
            if k >= n:
                raise InputError(f"{self.path}: more {tp} messages than its index counts ({n})")
            t[k], acc[k], gyr[k] = rosmsg.imu_sample(m)
            k += 1
        src = f"{self.path}:{tp}"
        if k == 0:
            raise InputError(f"{src}: the topic has no messages")
        check_samples(acc[:k], gyr[:k], src)
        tc = check_and_repair(t[:k], src)
        return ImuLog(tc.t_ns, acc[:k], gyr[:k], "m/s^2", "rad/s", src, list(tc.warnings))

    def trajectory(self, topic: str | None = None) -> Trajectory:
        """Poses of a PoseStamped / Odometry / PointStamped topic, by header stamp."""
        tp = self.topic_of_type([rosmsg.POSESTAMPED, rosmsg.ODOMETRY, rosmsg.POINTSTAMPED], topic)
        from imuslam.io.posecheck import check_poses, check_times

        rows = [rosmsg.pose_from_msg(m) for _, _, m in self.messages([tp])]
        src = f"{self.path}:{tp}"
        if len(rows) < 2:
            raise InputError(f"{src}: {len(rows)} pose(s); a trajectory needs at least 2")
        t_ns = np.array([r[0] for r in rows], dtype=np.int64)
        check_times(t_ns, src)
        p_w, R_w_b = check_poses(np.array([r[1] for r in rows], dtype=float),
                                 np.array([r[2] for r in rows], dtype=float), src)  # fmt: skip
        return Trajectory(t_ns, p_w, R_w_b, src)

    def scans3d(self, topic: str | None = None) -> Iterator[Scan3d]:
        tp = self.topic_of_type([rosmsg.POINTCLOUD2], topic)
        for _, _, m in self.messages([tp]):
            yield rosmsg.scan3d_from_msg(m)

    def scans2d(self, topic: str | None = None) -> Iterator[Scan2d]:
        """The scans of a LaserScan / MultiEchoLaserScan topic (first echo) in time order. A ROS 1
        connection of the standard definition (its md5 sum) is read from the message bytes directly."""
        tp = self.topic_of_type([rosmsg.LASERSCAN, rosmsg.MULTIECHO_LASERSCAN], topic)
        direct: dict[str, bool] = {}  # md5 sum -> multi-echo, of the definitions read directly
        if self.dialect == "ros1":
            ts = rosmsg.typestore("ros1")
            for t, multi in ((rosmsg.LASERSCAN, False), (rosmsg.MULTIECHO_LASERSCAN, True)):
                direct[ts.generate_msgdef(t)[1]] = multi
        for k, (c, _, raw) in enumerate(self.raw(self.connections_of([tp]))):
            if c.digest in direct:
                try:
                    m = _ros1_scan(raw, direct[c.digest])
                except (struct.error, IndexError, ValueError) as exc:
                    raise InputError(
                        f"{self.path}: message {k} ({c.msgtype}) does not decode: {exc}"
                    ) from exc
            else:
                m = self.deserialize(raw, c.msgtype, k)
            yield rosmsg.scan2d_from_msg(m)


def _ros1_scan(raw: bytes, multi: bool) -> SimpleNamespace:
    """A ROS 1 ``sensor_msgs/LaserScan`` (or ``MultiEchoLaserScan``, as the first echo of each beam:
    inf range and 0 intensity where a beam has none) from its serialised bytes (little endian,
    unpadded): the fields :func:`rosmsg.scan2d_from_msg` reads, with rosbags' types."""
    _seq, sec, nanosec, n_frame = struct.unpack_from("<IiII", raw, 0)
    o = 16 + n_frame
    fields = struct.unpack_from("<7f", raw, o)
    o += 28
    if multi:
        ranges, o = _first_echoes(raw, o, float("inf"))
        inten, o = _first_echoes(raw, o, 0.0)
    else:
        ranges, o = _float32s(raw, o)
        inten, o = _float32s(raw, o)
    names = ("angle_min", "angle_max", "angle_increment", "time_increment", "scan_time", "range_min",
             "range_max")  # fmt: skip
    stamp = SimpleNamespace(sec=sec, nanosec=nanosec)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), **dict(zip(names, fields, strict=True)),
                           ranges=ranges, intensities=inten)  # fmt: skip


def _float32s(raw: bytes, o: int) -> tuple[NDArray[np.float32], int]:
    """A ``float32[]`` at byte ``o``: (values, the offset after it)."""
    (n,) = struct.unpack_from("<I", raw, o)
    return np.frombuffer(raw, "<f4", n, o + 4).astype(np.float32), o + 4 + 4 * n


def _first_echoes(raw: bytes, o: int, none: float) -> tuple[NDArray[np.float32], int]:
    """A ``LaserEcho[]`` at byte ``o`` (a count, then per beam a count and that many float32): (each
    beam's first echo, ``none`` for a beam without one, the offset after it)."""
    (n,) = struct.unpack_from("<I", raw, o)
    o += 4
    # from here on the message is 4-byte words: each beam's count, then its echoes
    words = np.frombuffer(raw, "<u4", (len(raw) - o) // 4, o)
    w = words.tolist()
    pos = [0] * n
    k = 0
    for b in range(n):
        pos[b] = k
        k += 1 + w[k]
    if k > len(w):
        raise ValueError(f"LaserEcho[] of {n} beams runs past the message's end")
    at = np.asarray(pos, np.int64)
    first = words.view("<f4")[np.minimum(at + 1, max(len(w) - 1, 0))] if n else np.zeros(0, "<f4")
    return np.where(words[at] > 0, first, np.float32(none)).astype(np.float32), o + 4 * k


def convert(msgtype: str, msg: Any, where: str = "") -> Any:
    """A deserialised message as its record (see :meth:`Bag.records`)."""
    if msgtype == rosmsg.IMU:
        return rosmsg.imu_sample(msg)
    if msgtype == rosmsg.POINTCLOUD2:
        return rosmsg.scan3d_from_msg(msg)
    if msgtype in (rosmsg.LASERSCAN, rosmsg.MULTIECHO_LASERSCAN):
        return rosmsg.scan2d_from_msg(msg)
    if msgtype in (rosmsg.ODOMETRY, rosmsg.POSESTAMPED, rosmsg.POINTSTAMPED):
        return rosmsg.pose_from_msg(msg)
    if msgtype in (rosmsg.IMAGE, rosmsg.COMPRESSED_IMAGE):
        return rosmsg.image_from_msg(msg)
    raise InputError(f"{where}: no record for message type {msgtype}")


def list_topics(path: str | Path) -> dict[str, str]:
    """Topic -> message type of every connection in the bag."""
    with Bag(path) as b:
        return b.topics()
