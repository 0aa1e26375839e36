"""``imuslam lio --rrd``: the recording read back with rerun's reader holds the run (the trajectory of
trajectory.tum, the per-scan figures of scans.csv, the IMU as logged, the ground truth as the metrics
align it), and the recording obeys the output rules."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.io.trajectory import read_trajectory

pytest.importorskip("rerun")  # the test extra installs it; a plain install has no viewer

RUNNER = CliRunner()


def tum_stamps_ns(path: Path) -> np.ndarray:
    """The TUM file's stamps as written (9 decimals), exact to the nanosecond."""
    from decimal import Decimal

    rows = [ln.split()[0] for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    return np.array([int(Decimal(r) * 10**9) for r in rows], dtype=np.int64)


TOPICS = ["--imu-topic", "/imu/data", "--points-topic", "/points"]


@pytest.fixture(scope="module")
def run(lio_run: dict[str, object]) -> dict[str, object]:
    """The 3 s simulated street through ``lio --rrd`` (conftest)."""
    return lio_run


def test_the_pose_per_scan_is_trajectory_tum(run: dict) -> None:  # type: ignore[type-arg]
    rec, tum = run["rec"], read_trajectory(run["out"] / "trajectory.tum", "tum")
    body = rec["/world/body"]
    assert body.rows == len(tum) == 30
    assert {"sensor_time", "scan"} <= body.timelines
    stamps = tum_stamps_ns(run["out"] / "trajectory.tum")
    np.testing.assert_array_equal(body.times_ns(), stamps)  # the sensor's own clock, exact
    # float32 in the recording: 1e-7 relative of positions within 20 m
    np.testing.assert_allclose(body.array("Transform3D:translation"), tum.p_w, atol=2e-5)
    R = body.array("Transform3D:mat3x3").reshape(-1, 3, 3).transpose(0, 2, 1)  # column-major
    np.testing.assert_allclose(R, tum.R_w_b, atol=1e-5)
    strip = np.array(rec["/world/trajectory"].static["LineStrips3D:strips"][0][0])
    np.testing.assert_allclose(strip, tum.p_w, atol=2e-5)


def test_the_per_scan_figures_are_scans_csv(run: dict) -> None:  # type: ignore[type-arg]
    rec = run["rec"]
    csv = np.loadtxt(run["out"] / "scans.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(rec["/scan/iterations"].array("Scalars:scalars"), csv[:, 4])
    np.testing.assert_array_equal(rec["/scan/correspondences"].array("Scalars:scalars"), csv[:, 5])
    pts = rec["/world/body/scan"].columns["Points3D:positions"]
    assert [len(p) for p in pts] == list(
        csv[:, 3].astype(int)
    )  # the registered points, all of them


def test_the_scans_land_on_the_local_map(run: dict) -> None:  # type: ignore[type-arg]
    """A scan's points moved by its pose are the points the estimator inserted into its local map
    (logged after the insertion): those the map's voxels admitted coincide to float32 precision. A
    frame mistake (LiDAR for IMU, 0.2 m apart here) or a pose of the wrong scan leaves none there."""
    rec = run["rec"]
    body, scans, lmap = rec["/world/body"], rec["/world/body/scan"], rec["/world/local_map"]
    assert lmap.rows >= 1
    for j, t_map in enumerate(lmap.times_ns()):
        k = int(np.flatnonzero(body.times_ns() == t_map)[0])
        T = body.array("Transform3D:translation")[k]
        R = body.array("Transform3D:mat3x3")[k].reshape(3, 3).T
        p_w = np.array(scans.columns["Points3D:positions"][k]) @ R.T + T
        d, _ = cKDTree(np.array(lmap.columns["Points3D:positions"][j])).query(p_w)
        assert np.mean(d < 1e-3) > 0.02, (k, np.percentile(d, [5, 50]))


def test_the_ground_truth_is_aligned_as_the_metrics(run: dict) -> None:  # type: ignore[type-arg]
    rec = run["rec"]
    metrics = json.loads((run["out"] / "metrics.json").read_text())
    tum = read_trajectory(run["out"] / "trajectory.tum", "tum")
    gt = np.array(rec["/world/ground_truth"].static["LineStrips3D:strips"][0][0])
    truth = read_trajectory(run["root"] / "gt.tum", "tum")
    at = np.searchsorted(truth.t_ns, tum.t_ns)  # the truth's sample nearest each scan end (as the
    at -= (at > 0) & (
        np.abs(truth.t_ns[at - 1] - tum.t_ns) < np.abs(truth.t_ns[at] - tum.t_ns)
    )  # metrics)
    assert np.abs(truth.t_ns[at] - tum.t_ns).max() < 0.001e9
    err = np.sqrt(np.mean(np.sum((gt[at] - tum.p_w) ** 2, axis=1)))
    assert err == pytest.approx(metrics["ape_trans"]["rmse"], rel=1e-3, abs=1e-5)


def test_the_imu_and_covariance(run: dict) -> None:  # type: ignore[type-arg]
    rec, imu = run["rec"], run["imu"]
    acc = rec["/imu/raw/accel"]
    np.testing.assert_array_equal(acc.times_ns(), imu.t_ns)
    np.testing.assert_allclose(acc.array("Scalars:scalars"), imu.accel, rtol=1e-12)
    assert "/imu/corrected/accel" not in rec  # no --calib: nothing corrected
    res = rec["/scan/residual_rms_m"].array("Scalars:scalars")
    # one per filter update (the filter's first scan starts it without one); the simulator's 2 cm range
    # noise seen on the map's planes: the matched points' RMS distance lies between its projection on a
    # normal and its sum over scan and map (2.5 x 2 cm)
    assert len(res) == rec["/world/covariance"].rows - 1
    assert np.all((res > 0.005) & (res < 0.05))
    cov = rec["/world/covariance"]
    half = cov.array("Ellipsoids3D:half_sizes")
    assert 0 < cov.rows <= 30 and np.all(half > 0) and np.all(half < 1.0)  # 1-sigma, metres


def test_the_recording_carries_its_layout(run: dict) -> None:  # type: ignore[type-arg]
    """The recording's blueprint: the 3D world on two thirds of the window, a plot for every per-scan
    series the recording holds, the IMU's gyro and accel (read back from the file's blueprint store)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(run["rrd"])
    (store,) = reader.blueprints()
    views: list[tuple[str, str]] = []
    shares: list[list[float]] = []
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        if "ViewBlueprint:space_origin" in rb.schema.names:
            origins = rb.column("ViewBlueprint:space_origin").to_pylist()
            kinds = rb.column("ViewBlueprint:class_identifier").to_pylist()
            views += [(o[0], k[0]) for o, k in zip(origins, kinds, strict=True) if o and k]
        if "ContainerBlueprint:col_shares" in rb.schema.names:
            shares += [s for s in rb.column("ContainerBlueprint:col_shares").to_pylist() if s]
    assert ("world", "3D") in views and shares == [[2.0, 1.0]]
    series = {p.removeprefix("/") for p in run["rec"] if p.startswith("/scan/")}
    assert len(series) == 5 and all((p, "TimeSeries") in views for p in series)
    assert views.count(("imu", "TimeSeries")) == 2  # gyro and accel
    assert len(views) == 1 + 5 + 2


def test_rrd_is_never_an_input_nor_an_existing_file(run: dict, tmp_path: Path) -> None:  # type: ignore[type-arg]
    root = run["root"]
    gt = root / "gt.tum"
    before = gt.read_bytes()
    for target, words in ((gt, "--rrd"), (run["rrd"], "exists")):
        r = RUNNER.invoke(app, ["lio", str(root / "bag"), *TOPICS, "--gt", str(gt), "--out",
                                str(tmp_path / "o"), "--rrd", str(target)])  # fmt: skip
        assert r.exit_code == 2 and words in r.output, r.output
    assert gt.read_bytes() == before
    assert not (tmp_path / "o").exists()


def test_without_rerun_one_line_and_exit_2(run: dict, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def,type-arg]
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun raises ImportError
    r = RUNNER.invoke(app, ["lio", str(run["root"] / "bag"), *TOPICS, "--max-scans", "2",
                            "--out", str(tmp_path / "o"), "--rrd", str(tmp_path / "x.rrd")])  # fmt: skip
    assert r.exit_code == 2
    assert "pip install 'imuslam[viz]'" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "x.rrd").exists()


def test_a_run_without_the_options_imports_no_rerun(run: dict, tmp_path: Path) -> None:  # type: ignore[type-arg]
    code = ("import sys\nfrom imuslam.cli import main\nsys.argv = ['imuslam', 'lio', sys.argv[1], '--imu-topic', "
            "'/imu/data', '--points-topic', '/points', '--max-scans', '3', '--out', sys.argv[2]]\n"
            "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "print('rerun' in sys.modules, 'imuslam.viz.lio' in sys.modules)")  # fmt: skip
    p = subprocess.run([sys.executable, "-c", code, str(run["root"] / "bag"), str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().splitlines()[-1] == "False False"
