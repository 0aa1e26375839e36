"""Speed-up of ``imuslam study --quick`` on a Dask LocalCluster of 2 worker processes against 1.

Each run starts from an empty results folder (no cell cache) and includes the cluster's start-up. The
workers are single-threaded processes with numba / OpenMP / BLAS pinned to one thread
(``threads.WORKER_ENV``), so one worker uses one core. Before timing, a one-seed study compiles
the numba kernels into their on-disk cache, so no timed run pays a compilation.

Printed per run: wall time, CPU seconds of each worker process (``getrusage`` in the worker, start-up
included) and of this process (client and scheduler), and two speed-ups against 1 worker:
- wall: what a user sees; meaningful only on an otherwise idle machine;
- CPU bound: the 1-worker run's worker CPU over the busiest 2-worker worker's CPU, i.e. the wall
  speed-up if each worker had a core of its own (not affected by other jobs on the machine).
The 1- and 2-worker runs alternate (``repeats`` times each) and the best wall of each is shown.

Run: PYTHONPATH=src .venv/bin/python bench/study.py [repeats]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import dataclass

from rich.console import Console
from rich.table import Table

from imuslam.study.config import parse_study
from imuslam.study.presets import QUICK
from imuslam.study.runner import run_study
from imuslam.threads import configure_process


@dataclass
class Run:
    wall_s: float
    cells: int
    worker_cpu_s: list[float]
    client_cpu_s: float
    load: tuple[float, float, float]


def timed(workers: int) -> Run:
    study = parse_study(QUICK, "--quick")
    with tempfile.TemporaryDirectory() as d:
        c0 = time.process_time()
        t0 = time.perf_counter()
        res = run_study(study, d, workers=workers, progress=False)
        dt = time.perf_counter() - t0
        client = time.process_time() - c0
    n_bad = int((res.table["status"] != "ok").sum())
    if n_bad:
        raise SystemExit(f"{n_bad} cells failed: {res.table['error'].iloc[0]}")
    return Run(dt, len(res.table), sorted(res.worker_cpu_s.values()), client, os.getloadavg())


def warm_up() -> None:
    """Compile (or load) every numba kernel the quick study uses, into the on-disk cache."""
    one_seed = {**QUICK, "seeds": [0]}
    with tempfile.TemporaryDirectory() as d:
        run_study(parse_study(one_seed, "--quick"), d, serial=True, progress=False)


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    warm_up()
    runs: dict[int, list[Run]] = {1: [], 2: []}
    for _ in range(repeats):
        for w in (1, 2):
            runs[w].append(timed(w))
    best = {w: min(r, key=lambda x: x.wall_s) for w, r in runs.items()}
    base = best[1]
    table = Table(
        title=f"imuslam study --quick on a LocalCluster, best wall of {repeats}; "
        f"{os.cpu_count()} cores"
    )
    for c in (
        "workers",
        "cells",
        "wall [s]",
        "CPU per worker [s]",
        "CPU client+scheduler [s]",
        "speed-up (wall)",
        "speed-up (CPU bound)",
        "load avg after (1, 5, 15 min)",
    ):
        table.add_column(c, justify="right")
    for w, r in best.items():
        table.add_row(
            str(w),
            str(r.cells),
            f"{r.wall_s:.1f}",
            ", ".join(f"{x:.1f}" for x in r.worker_cpu_s),
            f"{r.client_cpu_s:.1f}",
            f"{base.wall_s / r.wall_s:.2f}x",
            f"{sum(base.worker_cpu_s) / max(r.worker_cpu_s):.2f}x",
            ", ".join(f"{x:.1f}" for x in r.load),
        )
    Console(width=180).print(table)
    print(
        f"1 worker {base.wall_s:.1f} s, 2 workers {best[2].wall_s:.1f} s: "
        f"speed-up {base.wall_s / best[2].wall_s:.2f}x (wall), "
        f"{sum(base.worker_cpu_s) / max(best[2].worker_cpu_s):.2f}x (CPU bound)"
    )


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
