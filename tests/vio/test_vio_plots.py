"""What ``vio``'s pictures and summary encode: the top view framed on the estimate (the reference cropped
to its time span), the NIS gate at the filter's configured probability, the NIS consistency line."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from imuslam.eval.vio_compare import nis_consistency, nis_figure, tracks_figure
from imuslam.geometry.so3 import exp as so3_exp
from imuslam.io.trajectory import Trajectory
from imuslam.vio.config import VioConfig
from imuslam.vio.filter import GateStats


def _traj(t_s: np.ndarray, p: np.ndarray, name: str) -> Trajectory:
    R = np.stack([so3_exp(np.array([0.0, 0.0, 0.1 * t])) for t in t_s])
    return Trajectory(np.round(t_s * 1e9).astype(np.int64), p, R, name)


def test_tracks_are_framed_on_the_estimate_and_the_reference_cropped_to_its_span() -> None:
    # a reference of 145 s over a 5 m room, an estimate of 4.7 s over about 0.5 m (the EuRoC
    # excerpt), in its own frame: the reference rotated 90 deg about z and shifted by (3, -1, 0.5) m
    t_ref = np.arange(0.0, 145.0, 0.005)
    ref = _traj(t_ref, np.c_[2.5 * np.cos(t_ref / 8), 2.5 * np.sin(t_ref / 5), 0 * t_ref], "gt")
    t_est = np.arange(40.0, 44.7, 0.05)
    sel = (ref.t_ns >= round(40e9)) & (ref.t_ns <= round(t_est[-1] * 1e9))
    R = so3_exp(np.array([0.0, 0.0, np.pi / 2]))
    p_ref = np.c_[2.5 * np.cos(t_est / 8), 2.5 * np.sin(t_est / 5), 0 * t_est]
    p_est = (p_ref - [3.0, -1.0, 0.5]) @ R  # p_ref = R p_est + t
    fused = _traj(t_est, p_est, "fused")
    vo = _traj(t_est, p_est + 0.02, "vo")
    imu = _traj(
        t_est, p_est + np.c_[(t_est - 40) ** 3, 0 * t_est, 0 * t_est], "imu"
    )  # drifts 100 m
    fig = tracks_figure(ref, {"fused": fused, "vo": vo, "imu": imu})
    ax = fig.axes[0]
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    for tr in (fused, vo):  # the estimate is inside the frame
        assert x0 <= tr.p_w[:, 0].min() and tr.p_w[:, 0].max() <= x1
        assert y0 <= tr.p_w[:, 1].min() and tr.p_w[:, 1].max() <= y1
    span = max(np.ptp(p_est[:, 0]), np.ptp(p_est[:, 1]))
    # the frame is the estimate's size (with a 5 % margin), not the 5 m room nor the IMU's 100 m
    assert max(x1 - x0, y1 - y0) < 1.2 * span + 0.05 < 5.0
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    drawn = lines["reference (se3 aligned)"]
    assert len(drawn.get_xdata()) == sel.sum()  # the reference over the estimate's span only
    # drawn in the estimate's frame: on the fused track (interpolated at the reference's times)
    ref_xy = np.c_[drawn.get_xdata(), drawn.get_ydata()]
    fused_x = np.interp(ref.t_ns[sel], fused.t_ns, fused.p_w[:, 0])
    fused_y = np.interp(ref.t_ns[sel], fused.t_ns, fused.p_w[:, 1])
    assert np.max(np.hypot(ref_xy[:, 0] - fused_x, ref_xy[:, 1] - fused_y)) < 1e-3
    labels = ax.get_legend_handles_labels()[1]
    assert labels == ["reference (se3 aligned)", "fused", "vo", "imu (leaves the frame)"]


@pytest.mark.parametrize("gate_prob", [0.999, VioConfig().gate_prob])
def test_the_nis_gate_is_the_configured_one(gate_prob: float) -> None:
    rng = np.random.default_rng(0)
    vals = rng.chisquare(3, 200)
    acc = vals < chi2.ppf(gate_prob, 3)
    fig = nis_figure({"vo_velocity": (vals, acc, 3)}, gate_prob)
    ax = fig.axes[0]
    gate = [ln for ln in ax.get_lines() if ln.get_label().startswith("gate")]
    assert len(gate) == 1
    assert gate[0].get_ydata()[0] == pytest.approx(chi2.ppf(gate_prob, 3))
    assert gate[0].get_label() == f"gate {100 * gate_prob:g} %"
    assert set(ax.get_legend_handles_labels()[1]) >= {"accepted", "rejected", "E[NIS] = 3 (dof)"}


def test_without_a_gate_no_gate_line_is_drawn() -> None:
    fig = nis_figure({"vo_rate": (np.ones(5), np.ones(5, bool), 3)}, None)
    assert not [ln for ln in fig.axes[0].get_lines() if ln.get_label().startswith("gate")]


@pytest.mark.parametrize("scale, verdict", [(0.1, "below"), (1.0, "inside"), (3.0, "above")])
def test_the_nis_consistency_line_places_the_mean_against_its_band(
    scale: float, verdict: str
) -> None:
    # NIS of a filter whose covariance is 1/scale of its errors' (scale 0.1: pessimistic, as the
    # EuRoC excerpt's 0.31 for 3 dof)
    rng = np.random.default_rng(1)
    st = GateStats(dof=3)
    st.nis = list(scale * rng.chisquare(3, 400))
    st.accepted_mask = [True] * 400
    st.accepted = 400
    line = nis_consistency("vo_velocity", st.summary())
    lo, hi = chi2.ppf([0.025, 0.975], 1200) / 400
    assert f"95 % band {lo:.3g}-{hi:.3g}" in line
    assert f": {verdict}" in line
    assert ("pessimistic" in line) == (verdict == "below")
    assert ("overconfident" in line) == (verdict == "above")
