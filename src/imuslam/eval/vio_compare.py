"""Trajectory error of several estimates of one run on common times (fused, VO only, IMU only, ...).

Estimates come at different rates (a filter at the IMU rate, VO at the frame rate); comparing each as it
is would give RPE over different intervals. Here every estimate and the reference are interpolated
(position linearly, rotation by slerp) at the same times, the frame times inside every span, and then
scored with :func:`imuslam.eval.metrics.evaluate` pairing by index.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.eval.associate import interpolate
from imuslam.eval.metrics import EvalResult, evaluate
from imuslam.io.trajectory import Trajectory

if TYPE_CHECKING:
    from matplotlib.figure import Figure


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


def _span(tracks: dict[str, Trajectory]) -> tuple[int, int]:
    """The time span the estimates cover together, ns."""
    return min(int(tr.t_ns[0]) for tr in tracks.values()), max(
        int(tr.t_ns[-1]) for tr in tracks.values()
    )


def _ref_in_track_frame(ref: Trajectory, track: Trajectory, align: str) -> Trajectory:
    """``ref`` over ``track``'s time span, mapped into ``track``'s frame by the evaluation's
    ``align`` (the inverse of :func:`imuslam.eval.align.align` of the track onto the reference)."""
    from imuslam.eval.align import align as align_fn

    keep = np.flatnonzero((ref.t_ns >= track.t_ns[0]) & (ref.t_ns <= track.t_ns[-1]))
    crop = ref.subset(keep)
    t = common_times(track.t_ns, ref)
    if len(t) < 3 or len(crop) == 0:
        return crop
    s, R, tv = align_fn(interpolate(ref, t), interpolate(track, t), align)  # type: ignore[arg-type]
    return Trajectory(crop.t_ns, (crop.p_w - tv) @ R / s, R.T @ crop.R_w_b, crop.source)


def tracks_figure(
    ref: Trajectory | None,
    tracks: dict[str, Trajectory],
    frame: tuple[str, ...] = ("fused", "vo"),
    align: str = "se3",
) -> Figure:
    """Top view of every track in the first track's frame, and of the reference over the estimates'
    time span only (a reference of the whole sequence would set the scale of a short run), mapped into
    that frame by the evaluation's ``align``. The axes cover the tracks named in ``frame`` and the
    cropped reference; a track that leaves them (the IMU alone drifts) is clipped and its legend entry
    says so."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 7))
    ax = fig.add_subplot()
    pts = [tr.p_w[:, :2] for name, tr in tracks.items() if name in frame and len(tr)]
    if ref is not None and len(tracks):
        r = _ref_in_track_frame(ref, next(iter(tracks.values())), align)
        if len(r):
            ax.plot(r.p_w[:, 0], r.p_w[:, 1], "k-", lw=1.2, label=f"reference ({align} aligned)")
            pts.append(r.p_w[:, :2])
    if not pts:
        pts = [tr.p_w[:, :2] for tr in tracks.values() if len(tr)]
    xy = np.concatenate(pts) if pts else np.zeros((1, 2))
    mid = 0.5 * (xy.min(axis=0) + xy.max(axis=0))
    half = 0.55 * max(float(np.max(xy.max(axis=0) - xy.min(axis=0))), 0.01)  # square, 5 % margin
    lo_xy, hi_xy = mid - half, mid + half
    for i, (name, tr) in enumerate(tracks.items()):
        inside = np.all((tr.p_w[:, :2] >= lo_xy) & (tr.p_w[:, :2] <= hi_xy))
        label = name if inside else f"{name} (leaves the frame)"
        ax.plot(tr.p_w[:, 0], tr.p_w[:, 1], f"C{i}-", lw=0.9, label=label)
    ax.set_xlim(lo_xy[0], hi_xy[0])
    ax.set_ylim(lo_xy[1], hi_xy[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(
        f"top view, {(_span(tracks)[1] - _span(tracks)[0]) * 1e-9:.1f} s" if tracks else "top view"
    )
    ax.legend()
    return fig


def gate_label(gate_prob: float | None) -> str:
    """The legend entry of the chi-square gate at ``gate_prob`` (``VioConfig.gate_prob``)."""
    return "no gate" if gate_prob is None else f"gate {100 * gate_prob:g} %"


def nis_figure(
    nis: dict[str, tuple[NDArray[np.float64], NDArray[np.bool_], int]], gate_prob: float | None
) -> Figure:
    """NIS per update and kind, the chi-square gate at the filter's ``gate_prob`` and E[NIS] = dof."""
    from matplotlib.figure import Figure
    from scipy.stats import chi2

    fig = Figure(figsize=(10, 2.6 * len(nis)))
    ax = None
    for i, (kind, (vals, acc, dof)) in enumerate(nis.items()):
        ax = fig.add_subplot(len(nis), 1, i + 1)
        k = np.arange(len(vals))
        ax.semilogy(k[acc], vals[acc], "C0.", ms=3, label="accepted")
        ax.semilogy(k[~acc], vals[~acc], "C3x", ms=4, label="rejected")
        if gate_prob is not None:
            ax.axhline(
                chi2.ppf(gate_prob, dof), color="k", ls="--", lw=0.8, label=gate_label(gate_prob)
            )
        ax.axhline(dof, color="g", ls=":", lw=0.8, label=f"E[NIS] = {dof} (dof)")
        ax.set_ylabel(f"NIS {kind}")
        ax.legend(loc="upper right", fontsize=7)
    if ax is not None:
        ax.set_xlabel("update")
    return fig


def nis_consistency(kind: str, st: dict[str, Any]) -> str:
    """One line on a measurement kind's mean NIS (accepted updates) against the 95 % band of the mean
    of that many chi-square(dof) values (``GateStats.summary``), and what falling outside means."""
    if "nis_mean_accepted" not in st:
        return f"NIS {kind}: no accepted update"
    m, (lo, hi), dof = st["nis_mean_accepted"], st["nis_mean_band_95"], st["dof"]
    head = f"NIS {kind}: mean {m:.3g} over {st['accepted']} updates ({dof} dof), 95 % band {lo:.3g}-{hi:.3g}"
    if m < lo:
        return f"{head}: below, the filter's covariance is larger than its errors (pessimistic)"
    if m > hi:
        return f"{head}: above, the errors are larger than the covariance says (overconfident)"
    return f"{head}: inside, errors and covariance agree"


def bias_figure(
    bias: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
) -> Figure:
    """Estimated accelerometer and gyro biases with their 1-sigma band."""
    from matplotlib.figure import Figure

    t, b, s = bias
    fig = Figure(figsize=(10, 5))
    ax = None
    for j, (lab, unit) in enumerate((("accelerometer bias", "m/s^2"), ("gyro bias", "rad/s"))):
        ax = fig.add_subplot(2, 1, j + 1)
        for a in range(3):
            y = b[:, 3 * j + a]
            e = s[:, 3 * j + a]
            ax.plot(t, y, f"C{a}-", lw=0.9, label="xyz"[a])
            ax.fill_between(t, y - e, y + e, color=f"C{a}", alpha=0.2)
        ax.set_ylabel(f"{lab} [{unit}]")
        ax.legend(fontsize=7)
    if ax is not None:
        ax.set_xlabel("time [s]")
    return fig


def plot_vio(
    ref: Trajectory | None,
    tracks: dict[str, Trajectory],
    nis: dict[str, tuple[NDArray[np.float64], NDArray[np.bool_], int]],
    bias: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    out_dir: str,
    gate_prob: float | None = 0.9999,
) -> list[str]:
    """``tracks.png`` (:func:`tracks_figure`), ``nis.png`` (:func:`nis_figure`, the gate at the
    filter's ``gate_prob``), ``biases.png`` (:func:`bias_figure`). Returns the file names."""
    from imuslam.io.figures import save_figure

    save_figure(tracks_figure(ref, tracks), f"{out_dir}/tracks.png")
    names = ["tracks.png"]
    if nis:
        save_figure(nis_figure(nis, gate_prob), f"{out_dir}/nis.png")
        names.append("nis.png")
    if len(bias[0]):
        save_figure(bias_figure(bias), f"{out_dir}/biases.png")
        names.append("biases.png")
    return names
