"""``imuslam map2d --rrd``: the recording read back with rerun's reader holds the run (a pose and the
hits per scan on the log's clock, the trajectory of trajectory.tum, the map of map.pgm / map.yaml, the
growing submaps, the loop edges as they are added)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.io.mapfiles import read_map_server

pytest.importorskip("rerun")
from imuslam.viz.readback import load  # noqa: E402
from imuslam.viz.slam2d import occupancy_from_pgm  # noqa: E402

RUNNER = CliRunner()


@pytest.fixture(scope="module")
def run(map2d_run: dict[str, Path]) -> dict[str, Path]:
    """The 40 s simulated room through ``map2d --rrd`` (conftest)."""
    return map2d_run


def tum_stamps_ns(path: Path) -> np.ndarray:
    from decimal import Decimal

    rows = [ln.split()[0] for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    return np.array([int(Decimal(r) * 10**9) for r in rows], dtype=np.int64)


def test_one_pose_and_scan_per_scan_on_the_logs_clock(run: dict[str, Path]) -> None:
    rec = load(run["rrd"])
    stamps = np.load(run["sim"] / "sim.npz")["scan_t_ns"]
    body, scans = rec["/world/body"], rec["/world/body/scan"]
    assert body.rows == scans.rows == len(stamps) == 400
    np.testing.assert_array_equal(body.times_ns(), stamps)
    np.testing.assert_array_equal(np.array(body.columns["scan"]), np.arange(len(stamps)))
    assert all(len(p) > 10 for p in scans.columns["Points3D:positions"])
    # the live poses are the local SLAM's, which the loops then correct by centimetres in a room
    tum = np.loadtxt(run["out"] / "trajectory.tum")
    d = np.linalg.norm(body.array("Transform3D:translation") - tum[:, 1:4], axis=1)
    assert d[0] < 1e-6 and d.max() < 0.3


def test_the_final_trajectory_and_map_are_the_files(run: dict[str, Path]) -> None:
    rec = load(run["rrd"])
    tum = np.loadtxt(run["out"] / "trajectory.tum")
    assert np.array_equal(
        tum_stamps_ns(run["out"] / "trajectory.tum"), np.load(run["sim"] / "sim.npz")["scan_t_ns"]
    )
    strip = np.array(rec["/world/trajectory"].static["LineStrips3D:strips"][0][0])
    np.testing.assert_allclose(strip, tum[:, 1:4], atol=2e-5)
    img, res, (x0, y0) = read_map_server(run["out"] / "map.yaml")
    m = rec["/world/map"].static
    fmt = m["GridMap:format"][0][0]
    assert (fmt["width"], fmt["height"]) == (img.shape[1], img.shape[0])
    assert m["GridMap:cell_size"][0][0] == pytest.approx(res)
    data = np.array(m["GridMap:data"][0], np.uint8).reshape(img.shape)
    assert np.array_equal(data, occupancy_from_pgm(img))
    assert np.allclose(m["GridMap:translation"][0][0], [x0, y0, 0.0], atol=1e-5)


def test_the_submaps_grow(run: dict[str, Path]) -> None:
    rec = load(run["rrd"])
    subs = sorted(k for k in rec if k.startswith("/world/submaps/"))
    assert subs and rec[subs[0]].rows >= 2
    data = [np.array(d[0], np.uint8) for d in rec[subs[0]].columns["GridMap:data"]]
    known = [int(np.sum(d != 255)) for d in data]
    assert known[-1] > known[0] > 0  # more cells observed as the robot moves on


def test_the_loop_edges(run: dict[str, Path]) -> None:
    import json

    rec = load(run["rrd"])
    n = json.loads((run["out"] / "metrics.json").read_text())["loop_constraints"]
    assert n > 0  # a 40 s room closes loops
    final = rec["/world/loop_edges"].static["LineStrips3D:strips"][0]
    assert len(final) == n
    live = [len(x) for x in rec["/world/loops"].columns["LineStrips3D:strips"]]
    assert (
        live == sorted(live) and 0 < live[-1] <= n
    )  # added as found; the rest at the final vetting
    tum = np.loadtxt(run["out"] / "trajectory.tum")[:, 1:4]
    ends = np.array(final).reshape(-1, 3)
    assert np.min(np.linalg.norm(ends[:, None] - tum[None], axis=2), axis=1).max() < 1e-4
