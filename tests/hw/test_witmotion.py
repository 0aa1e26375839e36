"""WitMotion protocol: packets through a real pseudo-terminal with corruption, and a fuzz test."""

import os
import threading

import numpy as np
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from imuslam.hw.witmotion import (
    ACC_SCALE,
    GYRO_SCALE,
    HEADER,
    KNOWN_TYPES,
    UNLOCK,
    ImuAssembler,
    WitMotionParser,
    checksum,
    content_command,
    encode,
    encode_imu,
    imu_samples,
    rate_command,
)


def _stream(n: int, rng: np.random.Generator) -> tuple[bytes, np.ndarray, np.ndarray, int]:
    """n IMU samples (0x51 + 0x52 + 0x53 per frame) with garbage, cut packets and bad checksums between
    frames. Returns the bytes, the true accel / gyro of the intact frames, and the count of broken ones."""
    acc = rng.normal(size=(n, 3)) * 5
    gyr = rng.normal(size=(n, 3)) * 2
    out = bytearray()
    keep = []
    broken = 0
    for i in range(n):
        frame = encode_imu(acc[i], gyr[i]) + encode(0x53, (100, -200, 300, 0))
        r = rng.uniform()
        if r < 0.05:  # garbage before the frame, including stray headers
            out += (
                bytes(rng.integers(0, 256, size=int(rng.integers(1, 30)), dtype=np.uint8))
                + b"\x55\x51"
            )
        if r > 0.95:  # a packet of the frame is cut short
            cut = bytearray(frame)
            del cut[int(rng.integers(12, 21))]
            out += cut
            broken += 1
            continue
        if 0.90 < r <= 0.95:  # a bad checksum in the rate packet
            f = bytearray(frame)
            f[21] ^= 0x5A
            out += f
            broken += 1
            continue
        out += frame
        keep.append(i)
    return bytes(out), acc[keep], gyr[keep], broken


def _quantised(x: np.ndarray, scale: float) -> np.ndarray:
    return np.round(x / scale) * scale


def test_every_valid_packet_recovered_through_a_pty() -> None:
    rng = np.random.default_rng(0)
    data, acc, gyr, broken = _stream(2000, rng)
    master, slave = os.openpty()
    port = serial.Serial(os.ttyname(slave), 115200, timeout=0.5)

    def writer() -> None:
        for k in range(0, len(data), 97):  # odd chunk sizes cut packets across reads
            os.write(master, data[k : k + 97])

    th = threading.Thread(target=writer)
    th.start()
    parser = WitMotionParser()
    asm = ImuAssembler()
    got_a, got_g = [], []
    received = 0
    while received < len(data):
        chunk = port.read(256)
        if not chunk:
            break
        received += len(chunk)
        s = asm.push(parser.feed(chunk))
        got_a.append(s.accel)
        got_g.append(s.gyro)
    th.join()
    port.close()
    os.close(master)
    os.close(slave)
    a, g = np.concatenate(got_a), np.concatenate(got_g)
    assert received == len(data)
    # Every intact frame is recovered, in order. A broken packet whose 8 damaged bytes happen to pass the
    # 8-bit checksum (one in 256) is indistinguishable from a real one: with ~100 broken frames about 0.4
    # such extras are expected, and more than 3 has a probability below 1e-3.
    qa, qg = _quantised(acc, ACC_SCALE), _quantised(gyr, GYRO_SCALE)
    j = 0
    for i in range(len(a)):
        if (
            j < len(qa)
            and np.allclose(a[i], qa[j], atol=1e-9)
            and np.allclose(g[i], qg[j], atol=1e-12)
        ):
            j += 1
    assert j == len(qa)
    assert len(a) - len(qa) <= 3
    assert parser.n_bad_checksum >= 1 and broken > 0


def test_commands() -> None:
    assert UNLOCK == bytes.fromhex("ffaa6988b5")
    assert rate_command(100) == bytes.fromhex("ffaa030900")
    assert content_command("accel", "gyro") == bytes.fromhex("ffaa020600")
    p = encode(0x51, (1, -1, 2, 3))
    assert len(p) == 11 and p[0] == 0x55 and checksum(p) == p[10]


_NOT_HEADER = st.integers(0, 255).filter(lambda b: b != HEADER)
_TYPES = [t for t in KNOWN_TYPES if t != HEADER]


@st.composite
def _frames_with_known_checksums(draw: st.DrawFn) -> tuple[list[bytes], list[bytes], int]:
    """Chunks of a stream of packets, each written here byte by byte with a right or a deliberately wrong
    checksum, separated by garbage. No byte other than a packet's first is 0x55, so a reference needs no
    parser: the packets to accept are exactly the good ones in order, the corrupt ones are counted.
    Returns the chunks, the good packets and the number of bad ones."""
    stream = bytearray()
    good: list[bytes] = []
    n_bad = 0
    for _ in range(draw(st.integers(0, 25))):
        stream += bytes(draw(st.lists(_NOT_HEADER, max_size=14)))
        body = bytearray([HEADER, draw(st.sampled_from(_TYPES))])
        body += bytes(draw(st.lists(_NOT_HEADER, min_size=8, max_size=8)))
        right = sum(body) & 0xFF
        if draw(st.booleans()):
            cs = (right + draw(st.integers(1, 255))) & 0xFF
            if cs == HEADER:
                cs = (cs + 1) & 0xFF if (cs + 1) & 0xFF != right else (cs + 2) & 0xFF
            stream += body + bytes([cs])
            n_bad += 1
        else:
            if right == HEADER:  # keep the checksum byte from looking like a header
                body[2] = (body[2] + 1) & 0xFF if body[2] != HEADER - 1 else (body[2] + 2) & 0xFF
                right = sum(body) & 0xFF
            stream += body + bytes([right])
            good.append(bytes(body + bytes([right])))
    stream += bytes(22)  # trailing non-header bytes: the last packet is complete and decided
    cuts = sorted(draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    chunks = [bytes(stream[a:b]) for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
    return chunks, good, n_bad


@settings(max_examples=300)
@given(_frames_with_known_checksums())
def test_fuzz_accepts_exactly_the_good_checksums(
    case: tuple[list[bytes], list[bytes], int],
) -> None:
    chunks, good, n_bad = case
    parser = WitMotionParser()
    got_t, got_v = [], []
    for c in chunks:
        p = parser.feed(c)
        assert p.values.shape == (len(p.ptype), 4)
        got_t += [int(x) for x in p.ptype]
        got_v += [tuple(int(x) for x in v) for v in p.values]
    assert got_t == [g[1] for g in good]
    assert got_v == [tuple(int(x) for x in np.frombuffer(g[2:10], "<i2")) for g in good]
    assert parser.n_packets == len(good)
    assert parser.n_bad_checksum == n_bad


@settings(max_examples=300)
@given(st.lists(st.binary(min_size=0, max_size=64), max_size=20))
def test_fuzz_never_crashes_and_every_accepted_packet_sums_right(chunks: list[bytes]) -> None:
    """Arbitrary bytes: no exception, and each accepted packet is a run of 11 bytes of the input whose
    checksum (summed here, not by the code) is right."""
    parser = WitMotionParser()
    data = b"".join(chunks)
    pos = 0
    for c in chunks:
        p = parser.feed(c)
        assert p.values.shape == (len(p.ptype), 4)
        for t, v in zip(p.ptype, p.values, strict=True):
            pk = bytes([HEADER, int(t)]) + np.asarray(v, "<i2").tobytes()
            k = data.find(pk, pos)
            assert k >= 0 and k + 10 < len(data) and data[k + 10] == sum(pk) % 256
            pos = k + 11
        imu_samples(p)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=200), st.integers(min_value=1, max_value=50))
def test_fuzz_prefix_garbage_then_valid(garbage: bytes, k: int) -> None:
    """Whatever comes before, a run of valid frames afterwards is recovered (at most one frame lost to
    resynchronisation)."""
    frames = b"".join(
        encode_imu(np.array([1.0, 2.0, 9.8]), np.array([0.1, 0.0, -0.1])) for _ in range(k)
    )
    parser = WitMotionParser()
    s = imu_samples(parser.feed(garbage + frames))
    assert len(s.accel) >= k - 1
