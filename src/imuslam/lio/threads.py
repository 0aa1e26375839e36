"""Single-threaded BLAS for the odometry loop.

The per-scan products are small (thousands of rows by 6-18 columns); OpenBLAS's thread pool makes them
hundreds of times slower on a busy machine (measured: 7 ms against 820 ms for one iterated update with
2600 rows on 2 shared cores). :func:`blas_threads` sets numpy's bundled OpenBLAS to ``n`` threads for a
block and restores it; it does nothing when numpy uses another BLAS.
"""

from __future__ import annotations

import ctypes
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

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
    libs = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for f in sorted(libs.glob("*openblas*.so*")):
        try:
            return ctypes.CDLL(str(f))
        except OSError:
            continue
    return None


@contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Run the block with ``n`` BLAS threads (numpy's OpenBLAS), then restore the previous count."""
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
