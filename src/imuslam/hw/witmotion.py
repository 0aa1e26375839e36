"""The WitMotion serial protocol of the BWT901CL / WT901 family (WitMotion "WT901 / BWT901CL user
manual", communication protocol section).

Every output packet is 11 bytes: ``0x55, type, 8 data bytes (four little-endian int16), checksum`` with
checksum = low byte of the sum of the first 10 bytes. Types and scales:
0x50 time (YY MM DD hh mm ss, ms as uint16); 0x51 acceleration a / 32768 * 16 g, temperature / 100 degC;
0x52 angular rate w / 32768 * 2000 deg/s; 0x53 angle / 32768 * 180 deg (roll, pitch, yaw);
0x54 magnetometer (raw counts); 0x59 quaternion / 32768 (w, x, y, z).
Configuration commands are 5 bytes ``0xFF 0xAA register low high``: unlock ``FF AA 69 88 B5``, save
``FF AA 00 00 00``; register 0x02 selects the content (bit 0 time, 1 acceleration, 2 rate, 3 angle,
4 magnetometer, 9 quaternion), 0x03 the output rate, 0x04 the baud rate.

The parser takes any byte chunks, finds packets with a vectorised checksum test, resynchronises after
garbage or a cut packet, counts bad checksums, and never raises on bad input.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)

HEADER = 0x55
TIME, ACCEL, GYRO, ANGLE, MAG, QUAT = 0x50, 0x51, 0x52, 0x53, 0x54, 0x59
KNOWN_TYPES = (0x50, 0x51, 0x52, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A)
G0 = 9.80665
ACC_SCALE = 16.0 * G0 / 32768.0  # m/s^2 per count
GYRO_SCALE = np.deg2rad(2000.0 / 32768.0)  # rad/s per count
ANGLE_SCALE = np.deg2rad(180.0 / 32768.0)  # rad per count
QUAT_SCALE = 1.0 / 32768.0

RATE_CODES = {
    0.2: 0x01,
    0.5: 0x02,
    1: 0x03,
    2: 0x04,
    5: 0x05,
    10: 0x06,
    20: 0x07,
    50: 0x08,
    100: 0x09,
    200: 0x0B,
}
BAUD_CODES = {
    4800: 0x01,
    9600: 0x02,
    19200: 0x03,
    38400: 0x04,
    57600: 0x05,
    115200: 0x06,
    230400: 0x07,
}
CONTENT_BITS = {"time": 0, "accel": 1, "gyro": 2, "angle": 3, "mag": 4, "quat": 9}


def checksum(b: bytes | NDArray[np.uint8]) -> int:
    return int(np.sum(np.frombuffer(bytes(b[:10]), dtype=np.uint8), dtype=np.int64) & 0xFF)


def encode(ptype: int, values: tuple[int, int, int, int]) -> bytes:
    """One 11-byte packet of ``ptype`` holding four int16 values."""
    body = bytes([HEADER, ptype]) + np.asarray(values, dtype="<i2").tobytes()
    return body + bytes([sum(body) & 0xFF])


def encode_imu(
    accel_mps2: NDArray[np.float64], gyro_rps: NDArray[np.float64], temp_c: float = 25.0
) -> bytes:
    """0x51 + 0x52 packets for one sample (saturating at the int16 range), as the sensor sends them."""
    a = np.clip(np.round(np.asarray(accel_mps2) / ACC_SCALE), -32768, 32767).astype(int)
    w = np.clip(np.round(np.asarray(gyro_rps) / GYRO_SCALE), -32768, 32767).astype(int)
    return encode(ACCEL, (a[0], a[1], a[2], int(round(temp_c * 100)))) + encode(
        GYRO, (w[0], w[1], w[2], 0)
    )


def command(register: int, value: int) -> bytes:
    """A configuration write ``FF AA register low high``."""
    return bytes([0xFF, 0xAA, register & 0xFF, value & 0xFF, (value >> 8) & 0xFF])


UNLOCK = bytes([0xFF, 0xAA, 0x69, 0x88, 0xB5])
SAVE = command(0x00, 0x0000)


def rate_command(rate_hz: float) -> bytes:
    if rate_hz not in RATE_CODES:
        raise ValueError(
            f"output rate {rate_hz} Hz not supported; choose one of {sorted(RATE_CODES)}"
        )
    return command(0x03, RATE_CODES[rate_hz])


def baud_command(baud: int) -> bytes:
    if baud not in BAUD_CODES:
        raise ValueError(f"baud {baud} not supported; choose one of {sorted(BAUD_CODES)}")
    return command(0x04, BAUD_CODES[baud])


def content_command(*items: str) -> bytes:
    bits = 0
    for it in items:
        if it not in CONTENT_BITS:
            raise ValueError(f"unknown content '{it}'; choose from {', '.join(CONTENT_BITS)}")
        bits |= 1 << CONTENT_BITS[it]
    return command(0x02, bits)


@numba.njit(cache=True)
def _select(
    cands: NDArray[np.int64], n: int
) -> tuple[NDArray[np.int64], int]:  # pragma: no cover - compiled
    """Non-overlapping packets among valid candidate offsets (sorted), greedy in stream order.

    Returns the packets and the offset from which bytes must be kept for the next chunk.
    A candidate followed by another valid packet exactly 11 bytes on wins over an overlapping one that is
    not: a cut packet's header followed by the next packet's bytes passes the checksum one time in 256
    and must not hide the real packet.
    """
    m = cands.shape[0]
    chain = np.zeros(m, dtype=np.bool_)  # followed by a valid packet exactly 11 bytes on
    for i in range(m - 1):
        if cands[i + 1] == cands[i] + 11:
            chain[i] = True
    out = np.empty(m, dtype=np.int64)
    k = 0
    nxt = -1
    stop = n
    for i in range(m):
        c = cands[i]
        if c < nxt or c + 11 > n:
            continue
        if not chain[i] and c + 22 > n:
            # an overlapping packet that would decide may still be incomplete: wait for more bytes
            stop = c
            break
        if not chain[i]:
            shadow = False
            j = i + 1
            while j < m and cands[j] < c + 11:
                if chain[j]:
                    shadow = True
                    break
                j += 1
            if shadow:
                continue
        out[k] = c
        k += 1
        nxt = c + 11
    return out[:k], stop


@dataclass
class Packets:
    """Decoded packets of one chunk: type (K,) uint8 and the four int16 values (K, 4), in stream order."""

    ptype: NDArray[np.uint8]
    values: NDArray[np.int16]


@dataclass
class WitMotionParser:
    """Incremental parser: ``feed(chunk)`` returns the complete valid packets found so far."""

    buffer: bytearray = field(default_factory=bytearray)
    n_packets: int = 0
    n_bad_checksum: int = 0
    n_skipped_bytes: int = 0

    def feed(self, chunk: bytes) -> Packets:
        self.buffer.extend(chunk)
        buf = np.frombuffer(bytes(self.buffer), dtype=np.uint8)
        n = buf.size
        if n < 11:
            return Packets(np.zeros(0, np.uint8), np.zeros((0, 4), np.int16))
        heads = np.flatnonzero(buf[: n - 10] == HEADER)
        typed = heads[np.isin(buf[heads + 1], KNOWN_TYPES)]
        cs = np.concatenate([[0], np.cumsum(buf, dtype=np.int64)])
        ok = ((cs[typed + 10] - cs[typed]) & 0xFF) == buf[typed + 10]
        good, stop = _select(typed[ok].astype(np.int64), n)
        # A typed header whose checksum fails and that no accepted packet covers counts as corrupt.
        bad = typed[~ok]
        if bad.size and good.size:
            pos = np.searchsorted(good, bad, side="right") - 1
            covered = (pos >= 0) & (bad < good[np.maximum(pos, 0)] + 11)
            bad = bad[~covered]
        # keep the tail that may hold the start of a cut packet
        end = int(good[-1] + 11) if good.size else 0
        tail_start = min(max(end, n - 10), stop) if stop < n else max(end, n - 10)
        self.n_bad_checksum += int(np.count_nonzero(bad < tail_start))
        used = good.size * 11
        self.n_skipped_bytes += tail_start - used
        self.n_packets += int(good.size)
        idx = good[:, None] + np.arange(11)[None, :]
        pk = buf[idx] if good.size else np.zeros((0, 11), np.uint8)
        del self.buffer[:tail_start]
        vals = (
            np.ascontiguousarray(pk[:, 2:10]).view("<i2").reshape(-1, 4)
            if good.size
            else np.zeros((0, 4), np.int16)
        )
        return Packets(pk[:, 1].copy(), vals.astype(np.int16))


@dataclass
class ImuSamples:
    """IMU samples decoded from packets: accel (N, 3) m/s^2, gyro (N, 3) rad/s, temperature (N,) degC."""

    accel: NDArray[np.float64]
    gyro: NDArray[np.float64]
    temp_c: NDArray[np.float64]


def imu_samples(p: Packets) -> ImuSamples:
    """Pair each angular-rate packet with the acceleration packet just before it (the sensor sends them in
    that order within one output frame); unpaired packets are dropped."""
    t = p.ptype
    ia = np.flatnonzero(t == ACCEL)
    ig = np.flatnonzero(t == GYRO)
    if ia.size == 0 or ig.size == 0:
        z = np.zeros((0, 3))
        return ImuSamples(z, z.copy(), np.zeros(0))
    k = np.searchsorted(ia, ig) - 1
    ok = k >= 0
    ig, k = ig[ok], k[ok]
    ia_pair = ia[k]
    # only an accel packet with no other rate packet between it and this one
    prev_g = np.concatenate([[-1], ig[:-1]])
    ok = ia_pair > prev_g
    ig, ia_pair = ig[ok], ia_pair[ok]
    v = p.values.astype(np.float64)
    return ImuSamples(v[ia_pair, :3] * ACC_SCALE, v[ig, :3] * GYRO_SCALE, v[ia_pair, 3] / 100.0)


@dataclass
class ImuAssembler:
    """Pairs rate packets with their acceleration packets across chunk boundaries."""

    pending: Packets | None = None

    def push(self, p: Packets) -> ImuSamples:
        if self.pending is not None:
            p = Packets(
                np.concatenate([self.pending.ptype, p.ptype]),
                np.concatenate([self.pending.values, p.values]),
            )
            self.pending = None
        out = imu_samples(p)
        # an acceleration packet after the last rate packet waits for its partner
        ia = np.flatnonzero(p.ptype == ACCEL)
        ig = np.flatnonzero(p.ptype == GYRO)
        if ia.size and (ig.size == 0 or ia[-1] > ig[-1]):
            k = int(ia[-1])
            self.pending = Packets(p.ptype[k : k + 1].copy(), p.values[k : k + 1].copy())
        return out


class WitMotionImu:
    """A BWT901CL / WT901 on a serial port (pyserial): configure it and iterate over IMU samples.

    Each sample is stamped with the host's receive time of its chunk (ns, ``time.time_ns``); at 100 Hz
    and 115200 baud a chunk spans a few samples, so stamps are re-spread uniformly over the chunk.
    """

    def __init__(
        self,
        port: str,
        baud: int = 115200,
        timeout_s: float = 0.05,
        serial_port: Any = None,
        clock_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        """Open ``port``; or use ``serial_port``, any object with pyserial's ``read``, ``write``,
        ``in_waiting``, ``is_open`` and ``close`` (a test's fake). ``clock_ns`` stamps the received chunks."""
        if serial_port is None:
            import serial

            serial_port = serial.Serial(port, baud, timeout=timeout_s)
        self.serial = serial_port
        self.clock_ns = clock_ns
        self.parser = WitMotionParser()
        self.assembler = ImuAssembler()

    def configure(
        self, rate_hz: float = 100, content: tuple[str, ...] = ("accel", "gyro", "angle")
    ) -> None:
        for cmd in (UNLOCK, rate_command(rate_hz), UNLOCK, content_command(*content), SAVE):
            self.serial.write(cmd)
            time.sleep(0.1)

    def samples(
        self, rate_hz: float = 100.0
    ) -> Iterator[tuple[int, NDArray[np.float64], NDArray[np.float64]]]:
        """Yield (t_ns, accel m/s^2 (3,), gyro rad/s (3,)) forever (until the port closes)."""
        period = int(1e9 / rate_hz)
        while self.serial.is_open:
            chunk = self.serial.read(max(self.serial.in_waiting, 11))
            t_rx = self.clock_ns()
            if not chunk:
                continue
            s = self.assembler.push(self.parser.feed(chunk))
            n = len(s.accel)
            for i in range(n):
                yield t_rx - (n - 1 - i) * period, s.accel[i], s.gyro[i]

    def close(self) -> None:
        self.serial.close()
