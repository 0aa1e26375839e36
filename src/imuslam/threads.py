"""The process's thread set-up: one place, called by the command line, the study workers and the benches.

numba's parallel kernels run on OpenMP (GNU libgomp), whose idle threads spin by default. When other
processes hold the cores (a study runs several workers per machine) the spinning thread competes with
them and a 0.12 s calibration call takes 0.36 s. :func:`configure_process` makes OpenMP threads wait
passively (``OMP_WAIT_POLICY=PASSIVE``) unless the variable is already set: the two-thread gain is kept
on an idle machine and a busy one costs about what one thread would (``bench/threads.py``). libgomp
reads it once, when it is loaded (numba's first parallel kernel), so the call must come before that.

OpenBLAS (numpy's and scipy's linear algebra) starts one thread per core, and its idle threads spin too.
The matrices here are small (a calibration's normal equations are about 100 x 100, a filter's 18 x 18),
so a second thread gains nothing and, with the other core busy, the xsens calibration costs 2.5x the CPU
time and 2x the wall time. :func:`configure_process` therefore sets ``OPENBLAS_NUM_THREADS=1`` unless it
is set; OpenBLAS reads it when numpy is imported, so the call must come before numpy's import to count.
Where numpy is already loaded, :func:`blas_threads` sets the pool's size for a block at run time.

Importing imuslam changes nothing: a library user who wants these defaults calls
:func:`configure_process` first (or sets the variables), as ``imuslam``'s own entry points do.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

PROCESS_DEFAULTS: dict[str, str] = {"OMP_WAIT_POLICY": "PASSIVE", "OPENBLAS_NUM_THREADS": "1"}
"""Applied by :func:`configure_process` where the user has not set them."""

WORKER_ENV: dict[str, str] = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}
"""A study worker process is one core: its numba, OpenMP and BLAS pools hold one thread each (numba reads
``NUMBA_NUM_THREADS`` when it is imported, so these are set before the worker process starts)."""


def configure_process() -> None:
    """Set :data:`PROCESS_DEFAULTS` in ``os.environ`` where unset (before numpy and numba load)."""
    for name, value in PROCESS_DEFAULTS.items():
        os.environ.setdefault(name, value)


_SET = (
    "scipy_openblas_set_num_threads64_",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)
_GET = (
    "scipy_openblas_get_num_threads64_",
    "openblas_get_num_threads64_",
    "openblas_get_num_threads",
)


def _openblas() -> ctypes.CDLL | None:
    import numpy as np

    libs = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for f in sorted(libs.glob("*openblas*.so*")):
        try:
            return ctypes.CDLL(str(f))
        except OSError:
            continue
    return None


@contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Run the block with ``n`` BLAS threads (numpy's bundled OpenBLAS), then restore the previous count;
    nothing changes when numpy uses another BLAS.

    The odometry loop's per-scan products are small (thousands of rows by 6-18 columns); OpenBLAS's
    thread pool makes them hundreds of times slower on a busy machine (measured: 7 ms against 820 ms for
    one iterated update with 2600 rows on 2 shared cores)."""
    lib = _openblas()
    setter = next((getattr(lib, s) for s in _SET if lib is not None and hasattr(lib, s)), None)
    getter = next((getattr(lib, s) for s in _GET if lib is not None and hasattr(lib, s)), None)
    if setter is None or getter is None:
        yield
        return
    before = int(getter())
    setter(ctypes.c_int(n))
    try:
        yield
    finally:
        setter(ctypes.c_int(before))
