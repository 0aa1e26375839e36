"""What ``map2d``'s map.png encodes (the view over the occupied extent, every series in the legend, the
reference drawn in the map's frame) and its input options (--no-imu reads no IMU, a scan topic to
choose names --scan-topic)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from imuslam.eval.slam2d_gt import reference_in_map
from imuslam.slam2d.config import Slam2dConfig
from imuslam.slam2d.grid import GridParams, ProbabilityGrid
from imuslam.slam2d.output import map_figure
from imuslam.slam2d.records import LoopConstraint, Slam2dResult

BAG = "cartographer_backpack_2d/b0-2014-07-21-12-42-53-short.bag"


def _room_grid() -> ProbabilityGrid:
    """A 10 m x 6 m room seen from its centre 20 times, and two beams through a door hitting 20 m away."""
    grid = ProbabilityGrid(GridParams(resolution=0.05), np.zeros(2), 10.0)
    s = np.linspace(0, 1, 400)[:, None]
    walls = np.vstack([np.c_[-5 + 10 * s, -3 + 0 * s], np.c_[-5 + 10 * s, 3 + 0 * s],
                       np.c_[-5 + 0 * s, -3 + 6 * s], np.c_[5 + 0 * s, -3 + 6 * s]])  # fmt: skip
    for _ in range(20):
        grid.insert(np.zeros(2), walls)
    grid.insert(np.zeros(2), np.array([[20.0, 0.5], [20.0, 0.6]]))
    return grid


def _result(P: np.ndarray, n_loops: int) -> Slam2dResult:
    loops = [LoopConstraint(k, 0, np.eye(3), 0.7, 0, np.eye(3)) for k in range(n_loops)]
    return Slam2dResult(np.arange(len(P), dtype=np.int64), P, P, None, np.arange(len(P)), 1, loops,
                        n_loops, {}, {}, 0.7, Slam2dConfig(), "room")  # fmt: skip


def test_the_map_is_viewed_over_the_occupied_extent_with_every_series_named() -> None:
    grid = _room_grid()
    t = np.linspace(0, 2 * np.pi, 50)
    P = np.c_[2 * np.cos(t), np.sin(t), t]
    ref = P[:, :2] + 0.05
    fig = map_figure(grid, _result(P, 3), "room", ref)
    ax = fig.axes[0]
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    # the walls (+-5 m, +-3 m) and the trajectory are inside, with at most a 1 m margin and a cell
    assert x0 <= -5 and x1 >= 5 and y0 <= -3 and y1 >= 3
    assert x0 >= -6.1 and x1 <= 6.1 and y0 >= -4.1 and y1 <= 4.1  # not the 20 m beams
    assert grid.cropped_known()[0].shape[1] * 0.05 > 24  # which the known extent holds
    labels = ax.get_legend_handles_labels()[1]
    assert labels == ["reference (SE(2) aligned)", "SLAM", "loop closure (3)", "start"]
    drawn = {ln.get_label(): ln for ln in ax.get_lines()}
    assert np.allclose(drawn["reference (SE(2) aligned)"].get_xdata(), ref[:, 0])
    assert len(drawn["loop closure (3)"].get_xdata()) == 3


def test_without_loops_or_reference_the_legend_names_only_what_is_drawn() -> None:
    P = np.c_[np.linspace(0, 1, 10), np.zeros(10), np.zeros(10)]
    labels = map_figure(_room_grid(), _result(P, 0), "room").axes[0].get_legend_handles_labels()[1]
    assert labels == ["SLAM", "start"]


def test_a_trajectory_reference_is_moved_into_the_map_frame(tmp_path: Path) -> None:
    # the reference in its own frame: the SLAM poses turned by 30 deg and shifted by (4, -2) m
    t_ns = 1_000_000_000 + np.arange(40, dtype=np.int64) * 100_000_000
    P = np.c_[np.linspace(0, 6, 40), np.sin(np.linspace(0, 3, 40)), np.linspace(0, 1, 40)]
    a = np.deg2rad(30.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    xy = P[:, :2] @ R.T + [4.0, -2.0]
    yaw = P[:, 2] + a
    rows = np.c_[t_ns * 1e-9, xy, 0 * yaw, 0 * yaw, 0 * yaw, np.sin(yaw / 2), np.cos(yaw / 2)]
    gt = tmp_path / "gt.tum"
    np.savetxt(gt, rows, fmt="%.9f")
    drawn = reference_in_map(gt, None, t_ns, P)  # type: ignore[arg-type]
    assert drawn.shape == (40, 2)
    assert np.max(np.abs(drawn - P[:, :2])) < 1e-6


@pytest.mark.slow  # the bag's scans take about 9 s to read
def test_no_imu_reads_no_imu(
    shared_data: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from imuslam.io.bag import Bag
    from imuslam.io.laserload import load_laser_log

    def no_read(*args: object) -> None:
        raise AssertionError("the IMU was read")

    monkeypatch.setattr(Bag, "imu", no_read)
    with caplog.at_level(logging.WARNING):
        log_ = load_laser_log(shared_data / BAG, "auto", "horizontal_laser_2d", with_imu=False)
    assert log_.imu() is None
    assert len(log_) == 345
    assert "gap" not in caplog.text  # the bag's IMU has one (1073th sample), never looked at


@pytest.mark.parametrize("topic", [None, "nope"])
def test_a_scan_topic_to_choose_names_the_option(
    shared_data: Path, tmp_path: Path, topic: str | None
) -> None:
    from typer.testing import CliRunner

    from imuslam.cli import app

    args = ["map2d", str(shared_data / BAG), "--out", str(tmp_path / "o")]
    r = CliRunner().invoke(app, args + (["--scan-topic", topic] if topic else []))
    assert r.exit_code == 2
    assert "--scan-topic" in r.output
    assert "horizontal_laser_2d" in r.output
    assert not (tmp_path / "o").exists()
