"""``imuslam vio --rrd`` on the simulated stereo rig: the recording read back with rerun's reader holds
the left image, tracks and inliers per pair on the camera's clock, the fused and VO trajectories of
trajectory.tum and vo.tum, the NIS of every update with the configured gate, and the biases."""

from __future__ import annotations

import json
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2
from typer.testing import CliRunner

from imuslam.cli import app

pytest.importorskip("rerun")
from imuslam.viz.readback import load  # noqa: E402

RUNNER = CliRunner()


def tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (exact ns, as written) and positions of a TUM file."""
    rows = [ln.split() for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    t = np.array([int(Decimal(r[0]) * 10**9) for r in rows], dtype=np.int64)
    return t, np.array([[float(x) for x in r[1:4]] for r in rows])


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict:  # type: ignore[type-arg]
    root = tmp_path_factory.mktemp("viz_vio")
    r = RUNNER.invoke(app, ["vio", "sim", "--sim-duration", "2", "--out", str(root / "out"),
                            "--no-progress", "--rrd", str(root / "run.rrd")])  # fmt: skip
    assert r.exit_code == 0, r.output
    return {"out": root / "out", "rec": load(root / "run.rrd")}


def test_images_tracks_and_inliers_per_pair(run: dict) -> None:  # type: ignore[type-arg]
    rec, out = run["rec"], run["out"]
    m = json.loads((out / "metrics.json").read_text())
    t_vo, _ = tum(out / "vo.tum")  # one VO pose per used pair, at its stamp
    cam = rec["/camera/left"]
    assert cam.rows == m["frames"]["used"] == len(t_vo)
    np.testing.assert_array_equal(cam.times_ns(), t_vo)
    inl = rec["/camera/left/inliers"]
    assert inl.rows == cam.rows - 1  # every pair after the first is tracked
    n_in = [len(p) for p in inl.columns["Points2D:positions"]]
    assert np.mean(n_in) == pytest.approx(m["vo"]["mean_inliers"])
    tracked = rec["/frame/tracked"].array("Scalars:scalars")
    assert np.mean(tracked) == pytest.approx(m["vo"]["mean_tracked"])
    n_out = [len(p) for p in rec["/camera/left/outliers"].columns["Points2D:positions"]]
    assert np.array_equal(np.array(n_in) + np.array(n_out), tracked)
    strips = rec["/camera/left/tracks"].columns["LineStrips2D:strips"]
    assert [len(s) for s in strips] == list(tracked.astype(int))


def test_fused_and_vo_trajectories_are_the_files(run: dict) -> None:  # type: ignore[type-arg]
    rec, out = run["rec"], run["out"]
    for name, f in (("fused", "trajectory.tum"), ("vo", "vo.tum")):
        t, p = tum(out / f)
        body = rec[f"/world/{name}/body"]
        np.testing.assert_array_equal(body.times_ns(), t)
        np.testing.assert_allclose(body.array("Transform3D:translation"), p, atol=2e-5)
    assert "/world/ground_truth" in rec  # the simulator's truth


def test_nis_with_the_configured_gate_and_biases(run: dict) -> None:  # type: ignore[type-arg]
    rec, out = run["rec"], run["out"]
    m = json.loads((out / "metrics.json").read_text())
    gate_prob = yaml.safe_load((out / "config.yaml").read_text())["gate_prob"]
    for kind, st in m["gating"].items():
        nis = rec[f"/filter/nis/{kind}"].array("Scalars:scalars")
        assert len(nis) == st["accepted"] + st["rejected"]
        gate = rec[f"/filter/nis/{kind}/gate"].array("Scalars:scalars")
        assert np.allclose(gate, chi2.ppf(gate_prob, st["dof"]))
        acc = nis <= gate
        assert nis[acc].mean() == pytest.approx(st["nis_mean_accepted"], rel=1e-9)
    for name in ("accel", "gyro"):
        b = rec[f"/filter/bias/{name}"].array("Scalars:scalars")
        s = rec[f"/filter/bias/{name}_1sigma"].array("Scalars:scalars")
        np.testing.assert_allclose(b[-1], m["final_bias"][name], rtol=1e-12)
        assert np.all(s > 0) and s.shape == b.shape
