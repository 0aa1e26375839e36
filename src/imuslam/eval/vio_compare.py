"""Trajectory error of several estimates of one run on common times (fused, VO only, IMU only, ...).

Estimates come at different rates (a filter at the IMU rate, VO at the frame rate); comparing each as it
is would give RPE over different intervals. Here every estimate and the reference are interpolated
(position linearly, rotation by slerp) at the same times, the frame times inside every span, and then
scored with :func:`imuslam.eval.metrics.evaluate` pairing by index.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.eval.associate import interpolate
from imuslam.eval.metrics import EvalResult, evaluate
from imuslam.io.trajectory import Trajectory


def common_times(times_ns: NDArray[np.int64], *tracks: Trajectory) -> NDArray[np.int64]:
    """The stamps of ``times_ns`` inside the time span of every track."""
    t = np.asarray(times_ns, dtype=np.int64)
    lo = max(int(tr.t_ns[0]) for tr in tracks)
    hi = min(int(tr.t_ns[-1]) for tr in tracks)
    return t[(t >= lo) & (t <= hi)]


def compare_tracks(
    ref: Trajectory,
    tracks: dict[str, Trajectory],
    times_ns: NDArray[np.int64],
    align: str = "se3",
    rpe_delta: float = 1.0,
    rpe_unit: str = "frames",
) -> dict[str, EvalResult]:
    """ATE / RPE of each track against ``ref`` at the common ``times_ns`` (see module docstring)."""
    t = common_times(times_ns, ref, *tracks.values())
    if len(t) < 3:
        raise InputError(
            f"{ref.source}: {len(t)} common times with the estimates; the reference must cover the run"
        )
    r = interpolate(ref, t)
    out: dict[str, EvalResult] = {}
    for name, tr in tracks.items():
        res, _, _ = evaluate(r, interpolate(tr, t), align, rpe_delta, rpe_unit, by_index=True)  # type: ignore[arg-type]
        out[name] = res
    return out
