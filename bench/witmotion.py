"""WitMotion parser throughput on 1e6 packets with 1 % corruption (target >= 100k packets/s).

Run: .venv/bin/python bench/witmotion.py
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.hw.witmotion import ImuAssembler, WitMotionParser, encode_imu
from imuslam.threads import configure_process


def main() -> None:
    rng = np.random.default_rng(0)
    frames = [encode_imu(rng.normal(size=3) * 5, rng.normal(size=3)) for _ in range(1000)]
    data = bytearray(b"".join(frames * 500))  # 1e6 packets
    n_pk = len(data) // 11
    hits = rng.choice(len(data), size=n_pk // 100, replace=False)
    data_np = np.frombuffer(bytes(data), dtype=np.uint8).copy()
    data_np[hits] ^= 0xA5
    blob = data_np.tobytes()
    WitMotionParser().feed(blob[:4096])  # JIT warm-up
    for chunk in (4096, 65536):
        parser, asm = WitMotionParser(), ImuAssembler()
        t = time.perf_counter()
        n_samples = 0
        for k in range(0, len(blob), chunk):
            n_samples += len(asm.push(parser.feed(blob[k : k + chunk])).accel)
        dt = time.perf_counter() - t
        table = Table(
            title=f"WitMotion parser, {n_pk:,} packets, 1 % corrupted bytes, {chunk}-byte reads"
        )
        for c in ("packets/s", "valid packets", "bad checksums", "IMU samples", "time [s]"):
            table.add_column(c, justify="right")
        table.add_row(
            f"{n_pk / dt:,.0f}",
            f"{parser.n_packets:,}",
            f"{parser.n_bad_checksum:,}",
            f"{n_samples:,}",
            f"{dt:.2f}",
        )
        Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
