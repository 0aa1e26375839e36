"""Trajectory plots: top view and error over time (PNG, written atomically)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from imuslam.eval.metrics import EvalResult
from imuslam.interfaces.trajectory import Trajectory
from imuslam.io.figures import save_figure


def plot_evaluation(
    res: EvalResult, ref: Trajectory, est: Trajectory, out_dir: str | Path
) -> list[Path]:
    """``trajectories.png`` (x-y top view) and ``ape.png`` (translation error over time)."""
    out = Path(out_dir)
    fig = Figure(figsize=(7, 7))
    ax = fig.subplots()
    ax.plot(ref.p_w[:, 0], ref.p_w[:, 1], "k-", lw=1, label="reference")
    ax.plot(est.p_w[:, 0], est.p_w[:, 1], "C1-", lw=1, label=f"estimate ({res.align} aligned)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend()
    save_figure(fig, out / "trajectories.png")
    fig = Figure(figsize=(10, 4))
    ax = fig.subplots()
    ax.plot(res.t_s, res.ape_trans_series, "C0-", lw=0.8)
    ax.axhline(
        res.ape_trans.rmse, color="k", ls="--", lw=0.8, label=f"RMSE {res.ape_trans.rmse:.4g} m"
    )
    ax.set_xlabel("time [s]")
    ax.set_ylabel("APE translation [m]")
    ax.legend()
    save_figure(fig, out / "ape.png")
    return [out / "trajectories.png", out / "ape.png"]
