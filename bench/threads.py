"""Numba's parallel kernels under load: each threading set-up, idle and with one busy-loop process.

Numba's default OpenMP layer (GNU libgomp) lets idle worker threads spin; when another process holds a
core, the spinning thread competes with it and the parallel call can end up slower than one thread.
This bench times, for each set-up, the calibration call on the imu_tk xsens log (``imu.calibrate``,
the multi-position sweep) and the overlapped Allan kernel (``imu.allan.overlapped_adev``), each in a
fresh process (the threading environment is read when the threading library is loaded), first with
nothing else started by the bench, then with one busy-loop process per extra core. The wall time and
the CPU time (``time.process_time``, all threads) of each call are printed: a spinning thread shows as
CPU time spent for nothing.

OpenBLAS (numpy's linear algebra, which the joint calibration's normal equations use) has its own
thread pool, whose idle threads also spin: ``OPENBLAS_NUM_THREADS`` is varied with the OpenMP set-up.

Run: python bench/threads.py [--repeat N] [--allan-samples N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "imu_tk_xsens"

# name -> (environment, initialise the threading layer before importing imuslam)
# "omp default" loads libgomp before imuslam's thread defaults (threads.configure_process) set OMP_WAIT_POLICY, so it
# measures numba + libgomp as they come (spin for a while, then sleep).
SETUPS: dict[str, tuple[dict[str, str], bool]] = {
    "omp default": ({"NUMBA_THREADING_LAYER": "omp"}, True),
    "omp active": ({"NUMBA_THREADING_LAYER": "omp", "OMP_WAIT_POLICY": "active"}, False),
    "omp passive": ({"NUMBA_THREADING_LAYER": "omp", "OMP_WAIT_POLICY": "passive"}, False),
    "workqueue": ({"NUMBA_THREADING_LAYER": "workqueue"}, False),
    "omp 1 thread": ({"NUMBA_NUM_THREADS": "1"}, False),
    "omp passive, BLAS 2 threads": ({"OPENBLAS_NUM_THREADS": "2"}, False),
    "imuslam (none set)": ({}, False),
}
_ENV_KEYS = ("NUMBA_THREADING_LAYER", "OMP_WAIT_POLICY", "NUMBA_NUM_THREADS", "GOMP_SPINCOUNT",
             "OPENBLAS_NUM_THREADS")  # fmt: skip


def _worker(repeat: int, allan_samples: int, init_first: bool) -> None:
    """Time both calls in this process; print one JSON line."""
    if not init_first:
        from imuslam.threads import configure_process

        configure_process()  # the command line's thread defaults, before numpy and numba load
    import numba
    import numpy as np

    if init_first:  # load the threading library with the environment as it is now

        @numba.njit(parallel=True)
        def _touch(x):  # type: ignore[no-untyped-def]
            s = 0.0
            for i in numba.prange(x.size):
                s += x[i]
            return s

        _touch(np.ones(8))

    from imuslam.imu.allan import cluster_sizes, overlapped_adev
    from imuslam.imu.calibrate import CalibrationConfig, calibrate
    from imuslam.io.load import load_imu

    log = load_imu(DATA / "xsens_acc.mat", DATA / "xsens_gyro.mat")
    cfg = CalibrationConfig(g=9.81744, bias_sign="minus")
    calibrate(log, cfg)  # compile / load the cache
    t_cal, c_cal = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        calibrate(log, cfg)
        t_cal.append(time.perf_counter() - t)
        c_cal.append(time.process_time() - c)
    rng = np.random.default_rng(0)
    y = rng.normal(size=allan_samples)
    ms = cluster_sizes(allan_samples, 100)
    overlapped_adev(y[:1000], 100.0, cluster_sizes(1000, 10))
    t_allan, c_allan = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        overlapped_adev(y, 100.0, ms)
        t_allan.append(time.perf_counter() - t)
        c_allan.append(time.process_time() - c)
    print(
        json.dumps(
            {
                "layer": numba.threading_layer(),
                "threads": numba.get_num_threads(),
                "calibrate": statistics.median(t_cal),
                "calibrate_cpu": statistics.median(c_cal),
                "allan": statistics.median(t_allan),
                "allan_cpu": statistics.median(c_allan),
            }
        )
    )


def _run(
    env_set: dict[str, str], init_first: bool, repeat: int, allan_samples: int
) -> dict[str, float]:
    env = {k: v for k, v in os.environ.items() if k not in _ENV_KEYS}
    env.update(env_set)
    cmd = [sys.executable, __file__, "--worker", "--repeat", str(repeat)]
    cmd += ["--allan-samples", str(allan_samples)] + (["--init-first"] if init_first else [])
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])  # type: ignore[no-any-return]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--allan-samples", type=int, default=2_000_000)
    ap.add_argument("--worker", action="store_true")
    ap.add_argument("--init-first", action="store_true")
    a = ap.parse_args()
    if a.worker:
        _worker(a.repeat, a.allan_samples, a.init_first)
        return
    from rich.console import Console
    from rich.table import Table

    n_busy = max((os.cpu_count() or 2) - 1, 1)
    rows: dict[str, dict[str, dict[str, float]]] = {}
    with open("/proc/loadavg") as f:
        load_start = f.read().split()[0]
    for load in ("idle", "busy"):
        busy = []
        if load == "busy":  # one spinning process per extra core, ended by its pid below
            busy = [
                subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n_busy)
            ]
            time.sleep(0.5)
        try:
            for name, (env_set, init_first) in SETUPS.items():
                rows.setdefault(name, {})[load] = _run(
                    env_set, init_first, a.repeat, a.allan_samples
                )
        finally:
            for p in busy:
                p.kill()
                p.wait()
    with open("/proc/loadavg") as f:
        load_end = f.read().split()[0]
    table = Table(
        title=f"Numba threading under load: median of {a.repeat} calls, xsens calibration and Allan "
        f"kernel ({a.allan_samples:.0e} samples, 100 taus); 'busy' = {n_busy} extra busy-loop "
        f"process(es); 1-min load average {load_start} at the start, {load_end} at the end, "
        f"{os.cpu_count()} cores"
    )
    for c in ("set-up", "layer", "calib. wall / CPU [s]", "calib. +busy wall / CPU [s]",
              "Allan wall / CPU [s]", "Allan +busy wall / CPU [s]"):  # fmt: skip
        table.add_column(c, justify="right")
    for name, r in rows.items():
        i, b = r["idle"], r["busy"]
        table.add_row(
            name,
            f"{i['layer']}x{int(i['threads'])}",
            f"{i['calibrate']:.3f} / {i['calibrate_cpu']:.3f}",
            f"{b['calibrate']:.3f} / {b['calibrate_cpu']:.3f}",
            f"{i['allan']:.3f} / {i['allan_cpu']:.3f}",
            f"{b['allan']:.3f} / {b['allan_cpu']:.3f}",
        )
    Console().print(table)


if __name__ == "__main__":
    main()
