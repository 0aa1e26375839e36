"""Wheel odometry (``nav_msgs/Odometry``, as :class:`WheelOdometry` with its twist) and GNSS fixes (``sensor_msgs/NavSatFix``) from ROS 1 / ROS 2 bags,
and GNSS latitude / longitude / altitude to a local East-North-Up frame (WGS84 through ECEF)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.odometry import WheelOdometry
from imuslam.io.bag import Bag

FloatArray = NDArray[np.float64]


@dataclass
class FixLog:
    """t_ns (N,), latitude / longitude (deg), altitude (m), status (N,) (-1: no fix)."""

    t_ns: NDArray[np.int64]
    lat_deg: FloatArray
    lon_deg: FloatArray
    alt_m: FloatArray
    status: NDArray[np.int64]
    source: str


def _messages(path: str | Path, topic: str, msgtype: str) -> Iterator[Any]:
    """The deserialised messages of ``topic``, which must hold ``msgtype`` (InputError listing the bag's
    topics otherwise)."""
    with Bag(path) as bag:
        bag.connections_of([topic], [msgtype])
        for _, _, msg in bag.messages([topic]):
            yield msg


def _stamp(msg) -> int:  # type: ignore[no-untyped-def]
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def read_odometry_bag(path: str | Path, topic: str) -> WheelOdometry:
    """Every ``nav_msgs/Odometry`` message of ``topic``, sorted by header stamp: the planar pose and the
    body twist (no encoder ticks: zeros)."""
    t, lin, ang, pose = [], [], [], []
    for m in _messages(path, topic, "nav_msgs/msg/Odometry"):
        t.append(_stamp(m))
        tw = m.twist.twist
        lin.append((tw.linear.x, tw.linear.y, tw.linear.z))
        ang.append((tw.angular.x, tw.angular.y, tw.angular.z))
        q = m.pose.pose.orientation
        yaw = np.arctan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))
        pose.append((m.pose.pose.position.x, m.pose.pose.position.y, yaw))
    if len(t) < 2:
        raise InputError(
            f"{path}: topic '{topic}' holds {len(t)} odometry messages; at least 2 needed"
        )
    o = np.argsort(np.asarray(t), kind="stable")
    return WheelOdometry(np.asarray(t, np.int64)[o], np.zeros((len(t), 2), np.int64), np.asarray(pose)[o],
                         np.asarray(lin)[o], np.asarray(ang)[o], f"{path}:{topic}")  # fmt: skip


def read_fix_bag(path: str | Path, topic: str) -> FixLog:
    """Every ``sensor_msgs/NavSatFix`` of ``topic``, sorted by header stamp."""
    t, la, lo, al, st = [], [], [], [], []
    for m in _messages(path, topic, "sensor_msgs/msg/NavSatFix"):
        t.append(_stamp(m))
        la.append(m.latitude)
        lo.append(m.longitude)
        al.append(m.altitude)
        st.append(m.status.status)
    if not t:
        raise InputError(f"{path}: topic '{topic}' holds no NavSatFix message")
    o = np.argsort(np.asarray(t), kind="stable")
    return FixLog(np.asarray(t, np.int64)[o], np.asarray(la)[o], np.asarray(lo)[o], np.asarray(al)[o],
                  np.asarray(st, np.int64)[o], f"{path}:{topic}")  # fmt: skip


def lla_to_enu(
    lat_deg: FloatArray, lon_deg: FloatArray, alt_m: FloatArray, origin: tuple[float, float, float]
) -> FloatArray:
    """WGS84 geodetic -> ECEF -> local ENU (N, 3) m about ``origin`` (lat deg, lon deg, alt m)
    (e.g. Groves, "Principles of GNSS, Inertial and Multisensor Integrated Navigation", eqs. 2.112, 2.150)."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)

    def ecef(lat: FloatArray, lon: FloatArray, h: FloatArray) -> FloatArray:
        la, lo = np.deg2rad(lat), np.deg2rad(lon)
        n = a / np.sqrt(1 - e2 * np.sin(la) ** 2)
        return np.stack([(n + h) * np.cos(la) * np.cos(lo), (n + h) * np.cos(la) * np.sin(lo),
                         (n * (1 - e2) + h) * np.sin(la)], axis=-1)  # fmt: skip

    lat0, lon0, h0 = origin
    d = ecef(
        np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(alt_m, float)
    ) - ecef(np.array(lat0), np.array(lon0), np.array(h0))
    la, lo = np.deg2rad(lat0), np.deg2rad(lon0)
    R = np.array([
        [-np.sin(lo), np.cos(lo), 0.0],
        [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
        [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)],
    ])  # fmt: skip
    return d @ R.T
