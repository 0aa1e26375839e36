"""Static-interval detection on accelerometer data (Tedaldi 2014, section IV-A; imu_tk's detector).

The detector value at sample i is the norm of the per-axis sample variances over a centred window of
``2h + 1`` samples, ``s(i) = sqrt(var_x^2 + var_y^2 + var_z^2)``; a sample is static when
``s(i) < k * s_init`` with ``s_init`` the same norm over the initial still period. Interval semantics
follow imu_tk: an interval starts at the first static window centre and ends at the first non-static
one (``end`` is that index), so a valid interval holds ``end - start >= n`` samples.
All variances come from cumulative sums: O(N) per log, and each threshold of a sweep is O(N) more.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def window_half_size(window_s: float, rate_hz: float) -> int:
    """Half size h of the centred window of about ``window_s`` seconds (at least 11 samples, odd)."""
    n = max(int(round(window_s * rate_hz)), 11)
    if n % 2 == 0:
        n += 1
    return n // 2


def init_variance_norm(accel: FloatArray, n_init: int) -> float:
    """Norm of the per-axis unbiased variances of samples ``0..n_init`` (inclusive), as imu_tk."""
    x = np.asarray(accel[: n_init + 1], dtype=float)
    return float(np.linalg.norm(np.var(x, axis=0, ddof=1)))


def windowed_variance_norm(accel: FloatArray, half: int) -> FloatArray:
    """Detector value (N,) per sample; NaN where the centred window of ``2*half + 1`` samples leaves the log.

    accel: (N, 3) samples in any unit (the result is in that unit squared).
    """
    x = np.asarray(accel, dtype=float)
    x = x - x.mean(axis=0)  # keeps the cumulative sums well conditioned for raw counts
    n = x.shape[0]
    w = 2 * half + 1
    out = np.full(n, np.nan)
    if n < w:
        return out
    c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(x, axis=0)])
    c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(x * x, axis=0)])
    s1 = c1[w:] - c1[:-w]
    s2 = c2[w:] - c2[:-w]
    var = np.maximum((s2 - s1 * s1 / w) / (w - 1), 0.0)
    out[half : n - half] = np.linalg.norm(var, axis=1)
    return out


def static_intervals(detector: FloatArray, threshold: float) -> IntArray:
    """Intervals (K, 2) of ``[start, end]`` sample indices where ``detector < threshold``.

    ``end`` is the first non-static index after the run (imu_tk's convention); a run still open at the
    last valid window centre ends there.
    """
    valid = np.isfinite(detector)
    static = np.zeros(detector.shape[0] + 2, dtype=np.int8)
    static[1:-1] = valid & (np.nan_to_num(detector, nan=np.inf) < threshold)
    edges = np.diff(static)
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    last_valid = int(np.flatnonzero(valid)[-1]) if valid.any() else -1
    # A run that reaches the end of the valid region closes at its last valid sample.
    ends = np.where(ends > last_valid, last_valid, ends)
    return np.stack([starts, ends], axis=1).astype(np.int64)


@dataclass
class StaticDetection:
    """Result of one threshold: all intervals, and those long enough to use."""

    k: float
    threshold: float
    intervals: IntArray
    valid: IntArray


def detect(
    accel: FloatArray,
    detector: FloatArray,
    init_norm: float,
    k: float,
    min_samples: int,
) -> StaticDetection:
    """Static intervals at threshold ``k * init_norm``; ``valid`` keeps those with ``end - start >= min_samples``."""
    th = k * init_norm
    iv = static_intervals(detector, th)
    keep = (iv[:, 1] - iv[:, 0]) >= min_samples
    return StaticDetection(k, th, iv, iv[keep])
