"""EvalPipeline: a Sim(3)-transformed copy of a trajectory is recovered (scale, zero APE), and the one
results writer leaves config.yaml, metrics.json and a TUM file whose stamps are the exact t_ns."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from imuslam.eval.metrics import EvalResult
from imuslam.eval.pipeline import EvalConfig, EvalPipeline
from imuslam.geometry.so3 import exp
from imuslam.interfaces.trajectory import Trajectory


def _pair(rng: np.random.Generator) -> tuple[Trajectory, Trajectory, float]:
    n = 400
    # epoch stamps (2014) with odd nanoseconds: a float64 in seconds cannot hold them exactly
    t_ns = 1_403_715_524_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_001 + 7
    s = np.linspace(0, 4 * np.pi, n)
    p = np.column_stack([10 * np.cos(s), 6 * np.sin(s), 0.5 * s])
    R = np.stack([exp([0.1 * np.sin(k), 0.05 * np.cos(k), k]) for k in s])
    ref = Trajectory(t_ns, p, R, "ref")
    scale, R_e_w, t_e = 0.37, exp(rng.normal(size=3)), rng.normal(size=3) * 5
    est = Trajectory(t_ns, scale * p @ R_e_w.T + t_e, R_e_w[None] @ R, "est")
    return ref, est, scale


def test_sim3_copy_is_recovered_and_written(tmp_path: Path) -> None:
    ref, est, scale = _pair(np.random.default_rng(3))
    cfg = EvalConfig(align="sim3", rpe_delta=10)
    pipe = EvalPipeline(ref, est, cfg)
    res = pipe.run()
    assert isinstance(res, EvalResult)
    assert res.n_pairs == len(ref)
    assert abs(res.scale - 1 / scale) < 1e-9  # est maps into ref by 1/scale
    assert res.ape_trans.rmse < 1e-9 and res.ape_rot_deg.rmse < 1e-6 and res.rpe_trans.rmse < 1e-9
    assert res.estimate_aligned is not None and res.reference is not None
    np.testing.assert_allclose(res.estimate_aligned.p_w, ref.p_w, atol=1e-9)

    out = pipe.save(res, tmp_path / "out", plots=False, gt="ref.tum", est="est.tum")
    assert sorted(p.name for p in out.iterdir()) == [
        ".imuslam-results.json",
        "config.yaml",
        "estimate_aligned.tum",
        "metrics.json",
    ]
    cfg_back = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg_back.pop("gt") == "ref.tum" and cfg_back.pop("est") == "est.tum"
    assert EvalConfig.model_validate(cfg_back) == cfg
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_pairs"] == len(ref) and abs(metrics["scale"] - 1 / scale) < 1e-9
    stamps = [ln.split()[0] for ln in (out / "estimate_aligned.tum").read_text().splitlines()[1:]]
    assert [int(s.replace(".", "")) for s in stamps] == ref.t_ns.tolist()
    assert all(len(s.split(".")[1]) == 9 for s in stamps)
