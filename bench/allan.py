"""Speed of the overlapped Allan deviation: 1e7 samples at 100 log-spaced taus, against allantools' oadev
measured in the same run (same taus, same numbers). Run: .venv/bin/python bench/allan.py [n_samples]
"""

from __future__ import annotations

import sys
import time

import numba
import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.imu.allan import cluster_sizes, overlapped_adev
from imuslam.threads import configure_process


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10_000_000
    rng = np.random.default_rng(0)
    y = rng.normal(size=n) + np.cumsum(rng.normal(size=n)) * 1e-3
    ms = cluster_sizes(n, 100)
    overlapped_adev(y[:1000], 100.0, cluster_sizes(1000, 10))  # compile
    t = time.perf_counter()
    taus, ad, _ = overlapped_adev(y, 100.0, ms)
    t_ours = time.perf_counter() - t
    label = f"imuslam (numba {numba.threading_layer()}, {numba.get_num_threads()} threads)"
    table = Table(title=f"Overlapped Allan deviation, {n:.0e} samples, {len(ms)} taus")
    for c in ("implementation", "time [s]", "speed-up", "max rel. difference"):
        table.add_column(c, justify="right")
    try:
        import allantools

        t = time.perf_counter()
        _, ad2, _, _ = allantools.oadev(y, rate=100.0, data_type="freq", taus=taus)
        t_at = time.perf_counter() - t
        diff = float(np.max(np.abs(ad / ad2 - 1)))
        table.add_row("allantools.oadev", f"{t_at:.2f}", "1.0", "-")
        table.add_row(label, f"{t_ours:.2f}", f"{t_at / t_ours:.1f}", f"{diff:.1e}")
    except ImportError:
        table.add_row(label, f"{t_ours:.2f}", "-", "allantools not installed")
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
