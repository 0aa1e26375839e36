"""A study's reports say how to read them: what the cell counts are, the sign of the mean difference
(checked against a known effect), and every verdict a claim can get."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from imuslam.study.config import parse_study
from imuslam.study.report import READING, write_outputs

STUDY = {"name": "t", "seeds": list(range(8)), "align": {"duration_s": 20.0}, "claims": [{
    "name": "align", "scenarios": [{"name": "street", "duration_s": 10.0}], "imu": ["online"],
    "alignment": ["none", "kf"], "estimators": [{"name": "ins"}], "compare": "alignment",
    "expect": ["kf", "none"], "eval_align": "none", "practical_bound": 0.05,
    "reason": "5 cm: one map cell", "max_seeds": 8}]}  # fmt: skip


def _rows(effect: float) -> pd.DataFrame:
    """ATE of 'none' = ATE of 'kf' + ``effect`` m per seed (kf claimed better), pair noise 0.1 m."""
    rng = np.random.default_rng(4)
    rows = []
    for s in range(8):
        common = rng.normal() * 10
        for lv, shift in (("kf", 0.0), ("none", effect)):
            rows.append({"claim": "align", "scenario": "street", "duration_s": 10.0, "imu": "online",
                         "alignment": lv, "variant": "ins", "seed": s, "status": "ok", "key": f"{lv}{s}",
                         "ape_rmse_m": 20 + common + shift + rng.normal() * 0.1})  # fmt: skip
    return pd.DataFrame(rows)


@pytest.mark.parametrize("effect, verdict", [(1.0, "supported"), (-1.0, "contradicted")])
def test_the_reports_explain_the_sign_they_print(
    tmp_path: Path, effect: float, verdict: str
) -> None:
    study = parse_study(STUDY)
    [res] = write_outputs(study, _rows(effect), tmp_path, "serial")
    assert res.verdict.startswith(verdict)
    md = (tmp_path / "report.md").read_text()
    assert md.startswith(READING[0])
    # the printed mean difference: worse minus better, so the claimed direction (kf better) is > 0
    assert np.sign(res.pairs[0].mean) == np.sign(effect)
    assert "positive is the claimed direction" in READING[1]
    html = (tmp_path / "report.html").read_text()
    assert all(x.replace("'", "&#x27;") in html for x in READING)


def test_every_verdict_and_count_is_explained() -> None:
    text = " ".join(READING)
    for verdict in ("supported", "partly supported", "contradicted", "no practical difference",
                    "not resolved"):  # fmt: skip
        assert f"{verdict} (" in text
    for count in ("run", "from the cache", "failed"):
        assert count in READING[0]
