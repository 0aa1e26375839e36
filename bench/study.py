"""Wall time of the quick study (``imuslam study --quick``) on a Dask LocalCluster of 1 and of 2 worker
processes (each single-threaded), every run from an empty results folder (no cache), cluster start-up
included; and serially in this process for reference. The machine's load average is printed beside,
since other jobs share the cores.

Run: .venv/bin/python bench/study.py [repeats]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

from rich.console import Console
from rich.table import Table

from imuslam.study.config import parse_study
from imuslam.study.presets import QUICK
from imuslam.study.runner import run_study


def timed(
    workers: int | None, serial: bool = False
) -> tuple[float, int, tuple[float, float, float]]:
    study = parse_study(QUICK, "--quick")
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        res = run_study(study, d, workers=workers, serial=serial, progress=False)
        dt = time.perf_counter() - t0
    return dt, len(res.table), os.getloadavg()


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    table = Table(
        title=f"imuslam study --quick, wall time (best of {repeats}); {os.cpu_count()} cores"
    )
    for c in (
        "backend",
        "cells",
        "wall [s]",
        "speed-up vs 1 worker",
        "load average (1, 5, 15 min) after",
    ):
        table.add_column(c, justify="right")
    timed(None, serial=True)  # warm the numba cache on disk, so no run pays the compilation
    runs: dict[str, tuple[float, int, tuple[float, float, float]]] = {}
    for name, workers, serial in (
        ("1 worker", 1, False),
        ("2 workers", 2, False),
        ("serial, in-process", None, True),
    ):
        best = min((timed(workers, serial) for _ in range(repeats)), key=lambda r: r[0])
        runs[name] = best
    base = runs["1 worker"][0]
    for name, (dt, n, load) in runs.items():
        table.add_row(
            name, str(n), f"{dt:.1f}", f"{base / dt:.2f}x", ", ".join(f"{x:.1f}" for x in load)
        )
    Console(width=160).print(table)


if __name__ == "__main__":
    main()
