"""Compiled loops of the trajectory metrics, in their own module so ``imuslam eval`` loads numba only
when a metric needs one (the RPE over path lengths)."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@numba.njit(cache=True)
def path_ids(p: FloatArray, delta: float) -> IntArray:  # pragma: no cover - compiled
    """Indices of the poses where the path length since the last kept pose first reaches ``delta``
    (evo's rule: the distance is accumulated pose by pose and restarts at every kept pose)."""
    ids = np.empty(p.shape[0], dtype=np.int64)
    ids[0] = 0
    k = 1
    acc = 0.0
    for i in range(1, p.shape[0]):
        acc += np.sqrt(np.sum((p[i] - p[i - 1]) ** 2))
        if acc >= delta:
            ids[k] = i
            k += 1
            acc = 0.0
    return ids[:k]
