"""``imuslam view``: a lio and a map2d results folder in one recording (``--rrd``), read back with rerun's
reader: each run's trajectory as trajectory.tum holds it, its map as map.ply / map.pgm hold it, its
metrics; and what it refuses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.io.mapfiles import read_map_server
from imuslam.io.pointcloud import read_ply
from imuslam.io.trajectory import read_trajectory

pytest.importorskip("rerun")
from imuslam.viz.readback import load  # noqa: E402
from imuslam.viz.slam2d import occupancy_from_pgm  # noqa: E402

RUNNER = CliRunner()


@pytest.fixture(scope="module")
def viewed(lio_run: dict, map2d_run: dict, tmp_path_factory: pytest.TempPathFactory) -> dict:  # type: ignore[type-arg]
    rrd = tmp_path_factory.mktemp("view") / "both.rrd"
    r = RUNNER.invoke(app, ["view", str(lio_run["out"]), str(map2d_run["out"]), "--rrd", str(rrd)])
    assert r.exit_code == 0, r.output
    return {"rec": load(rrd), "lio": lio_run["out"], "map2d": map2d_run["out"], "output": r.output}


def test_two_runs_side_by_side(viewed: dict) -> None:  # type: ignore[type-arg]
    rec = viewed["rec"]
    # both folders are named "out": the parent's name tells them apart
    lio, m2 = "viz_lio0_out", "viz_map2d0_out"
    for name, folder in ((lio, viewed["lio"]), (m2, viewed["map2d"])):
        tum = read_trajectory(folder / "trajectory.tum", "tum")
        body = rec[f"/world/{name}/body"]
        assert body.rows == len(tum)
        np.testing.assert_array_equal(body.times_ns(), tum.t_ns)
        np.testing.assert_allclose(body.array("Transform3D:translation"), tum.p_w, atol=2e-5)
        strip = np.array(rec[f"/world/{name}/trajectory"].static["LineStrips3D:strips"][0][0])
        np.testing.assert_allclose(strip, tum.p_w, atol=2e-5)
        text = rec[f"/metrics/{name}"].static["TextDocument:text"][0][0]
        assert json.loads(text) == json.loads((folder / "metrics.json").read_text())
    pts = np.array(rec[f"/world/{lio}/map"].static["Points3D:positions"][0])
    np.testing.assert_allclose(pts, read_ply(viewed["lio"] / "map.ply"), atol=1e-4)
    img, res, (x0, y0) = read_map_server(viewed["map2d"] / "map.yaml")
    g = rec[f"/world/{m2}/grid"].static
    data = np.array(g["GridMap:data"][0], np.uint8).reshape(img.shape)
    assert np.array_equal(data, occupancy_from_pgm(img))
    assert np.allclose(g["GridMap:translation"][0][0], [x0, y0, 0.0], atol=1e-5)
    assert f"/world/{lio}/grid" not in rec and f"/world/{m2}/map" not in rec  # only what each holds


def test_view_refuses_what_is_no_results_folder(lio_run: dict, tmp_path: Path) -> None:  # type: ignore[type-arg]
    (tmp_path / "empty").mkdir()
    r = RUNNER.invoke(app, ["view", str(tmp_path / "empty"), "--rrd", str(tmp_path / "x.rrd")])
    assert r.exit_code == 2 and "expected an imuslam results folder" in r.output
    inside = lio_run["out"] / "x.rrd"  # a recording written into the folder it shows
    r = RUNNER.invoke(app, ["view", str(lio_run["out"]), "--rrd", str(inside)])
    assert r.exit_code == 2 and "--rrd" in r.output
    assert not (tmp_path / "x.rrd").exists() and not inside.exists()


def test_without_a_display_one_line(lio_run: dict, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[type-arg]
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    r = RUNNER.invoke(app, ["view", str(lio_run["out"])])
    assert r.exit_code == 2 and "--rrd" in r.output and "Traceback" not in r.output


def test_stamps_128_ns_apart_stay_apart(tmp_path: Path) -> None:
    """vio's trajectory.tum holds an IMU sample beside a frame's mid-time 128 ns apart (EuRoC): the
    reader keeps both stamps as written (float64 seconds would merge them), and so does the view."""
    run = tmp_path / "vio_out"
    run.mkdir()
    stamps = ["1403715273.582142976", "1403715273.587142912", "1403715273.587143040"]
    run.joinpath("trajectory.tum").write_text(
        "# t x y z qx qy qz qw\n" + "".join(f"{t} {k} 0 0 0 0 0 1\n" for k, t in enumerate(stamps))
    )
    tum = read_trajectory(run / "trajectory.tum", "tum")
    expected = np.array([1403715273582142976, 1403715273587142912, 1403715273587143040])
    np.testing.assert_array_equal(tum.t_ns, expected)
    r = RUNNER.invoke(app, ["view", str(run), "--rrd", str(tmp_path / "v.rrd")])
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(
        load(tmp_path / "v.rrd")["/world/vio_out/body"].times_ns(), expected
    )
