"""Timestamp checks and repair: order, duplicates, gaps and quantised stamps.

Quantised stamps (e.g. a 200 Hz IMU logged with 0.01 s resolution, so that up to three samples share one
stamp and half the steps are zero) make every integration step wrong; they are detected and replaced by a
uniform time base fitted to the stamps (a least-squares line of time against sample index), with a
warning. Out-of-order stamps are an error; gaps are reported.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError

log = logging.getLogger(__name__)


@dataclass
class TimeCheck:
    """What :func:`check_and_repair` found and did. ``t_ns`` is the (possibly re-timed) time base."""

    t_ns: NDArray[np.int64]
    rate_hz: float
    retimed: bool = False
    n_gaps: int = 0
    warnings: list[str] = field(default_factory=list)


def check_and_repair(
    t_ns: NDArray[np.int64],
    source: str,
    line_of: NDArray[np.int64] | None = None,
    gap_factor: float = 3.0,
) -> TimeCheck:
    """Check stamps (N,) int64 ns; re-time quantised stamps; report gaps.

    line_of: (N,) line number of each sample in ``source``, to name the line of an error.
    Raises InputError on stamps that go backwards, or on duplicates that are not a quantisation pattern.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    n = t.shape[0]
    if n < 2:
        raise InputError(f"{source}: {n} sample(s); a log needs at least 2")
    d = np.diff(t)
    where = (
        (lambda i: f"line {int(line_of[i])}") if line_of is not None else (lambda i: f"sample {i}")
    )
    back = np.flatnonzero(d < 0)
    if back.size:
        i = int(back[0]) + 1
        raise InputError(
            f"{source}: time goes backwards at {where(i)} ({t[i]} ns after {t[i - 1]} ns); "
            "expected non-decreasing timestamps"
        )
    warnings: list[str] = []
    zero = d == 0
    span_s = (t[-1] - t[0]) * 1e-9
    if span_s <= 0:
        raise InputError(f"{source}: all {n} samples share one timestamp")
    rate = (n - 1) / span_s
    if zero.any():
        pos = d[d > 0]
        step = int(np.min(pos)) if pos.size else 0
        # Quantised: every positive step is a multiple of one resolution larger than the mean period.
        mean_period = span_s * 1e9 / (n - 1)
        multiples = pos / step if step else np.array([np.inf])
        quantised = step > 1.2 * mean_period and np.all(
            np.abs(multiples - np.round(multiples)) < 0.05
        )
        if not quantised:
            i = int(np.flatnonzero(zero)[0]) + 1
            raise InputError(
                f"{source}: duplicate timestamp at {where(i)} ({t[i]} ns) that is not a quantisation "
                "pattern; expected strictly increasing timestamps"
            )
        idx = np.arange(n, dtype=float)
        slope, icpt = np.polyfit(idx, (t - t[0]).astype(float), 1)
        new = t[0] + np.round(icpt + slope * idx).astype(np.int64)
        resid = (t - new) * 1e-9
        msg = (
            f"{source}: timestamps are quantised to {step * 1e-9:g} s at {1e9 / slope:.2f} Hz "
            f"({int(zero.sum())} zero steps); re-timed at the fitted rate (max shift {np.abs(resid).max():.4f} s)"
        )
        log.warning(msg)
        warnings.append(msg)
        t = new
        rate = 1e9 / slope
        d = np.diff(t)
        retimed = True
    else:
        retimed = False
    med = float(np.median(d))
    gaps = np.flatnonzero(d > gap_factor * med)
    if gaps.size:
        i = int(gaps[0]) + 1
        msg = (
            f"{source}: {gaps.size} gap(s) longer than {gap_factor:g} sample periods, the first at "
            f"{where(i)} ({d[gaps[0]] * 1e-9:.3f} s)"
        )
        log.warning(msg)
        warnings.append(msg)
    return TimeCheck(t, float(rate), retimed, int(gaps.size), warnings)
