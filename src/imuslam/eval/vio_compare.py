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
        res = evaluate(r, interpolate(tr, t), align, rpe_delta, rpe_unit, by_index=True)  # type: ignore[arg-type]
        out[name] = res
    return out


def plot_vio(
    ref: Trajectory | None,
    tracks: dict[str, Trajectory],
    nis: dict[str, tuple[NDArray[np.float64], NDArray[np.bool_], int]],
    bias: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    out_dir: str,
) -> list[str]:
    """``tracks.png`` (top view of every track, and the reference), ``nis.png`` (NIS per update and kind
    with the 99.9 % gate), ``biases.png`` (estimated biases with 1-sigma). Returns the file names."""
    from matplotlib.figure import Figure
    from scipy.stats import chi2

    from imuslam.io.figures import save_figure

    names = []
    fig = Figure(figsize=(7, 7))
    ax = fig.add_subplot()
    if ref is not None:
        ax.plot(ref.p_w[:, 0], ref.p_w[:, 1], "k-", lw=1.2, label="reference")
    for i, (name, tr) in enumerate(tracks.items()):
        ax.plot(tr.p_w[:, 0], tr.p_w[:, 1], f"C{i}-", lw=0.9, label=name)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend()
    save_figure(fig, f"{out_dir}/tracks.png")
    names.append("tracks.png")
    if nis:
        fig = Figure(figsize=(10, 2.6 * len(nis)))
        for i, (kind, (vals, acc, dof)) in enumerate(nis.items()):
            ax = fig.add_subplot(len(nis), 1, i + 1)
            k = np.arange(len(vals))
            ax.semilogy(k[acc], vals[acc], "C0.", ms=3, label="accepted")
            ax.semilogy(k[~acc], vals[~acc], "C3x", ms=4, label="rejected")
            ax.axhline(chi2.ppf(0.999, dof), color="k", ls="--", lw=0.8, label="gate 99.9 %")
            ax.axhline(dof, color="g", ls=":", lw=0.8, label=f"E[NIS] = {dof}")
            ax.set_ylabel(f"NIS {kind}")
            ax.legend(loc="upper right", fontsize=7)
        ax.set_xlabel("update")
        save_figure(fig, f"{out_dir}/nis.png")
        names.append("nis.png")
    t, b, s = bias
    if len(t):
        fig = Figure(figsize=(10, 5))
        for j, (lab, unit) in enumerate((("accelerometer bias", "m/s^2"), ("gyro bias", "rad/s"))):
            ax = fig.add_subplot(2, 1, j + 1)
            for a in range(3):
                y = b[:, 3 * j + a]
                e = s[:, 3 * j + a]
                ax.plot(t, y, f"C{a}-", lw=0.9, label="xyz"[a])
                ax.fill_between(t, y - e, y + e, color=f"C{a}", alpha=0.2)
            ax.set_ylabel(f"{lab} [{unit}]")
            ax.legend(fontsize=7)
        ax.set_xlabel("time [s]")
        save_figure(fig, f"{out_dir}/biases.png")
        names.append("biases.png")
    return names
