"""Enough evidence per claim: the sequential decision (seeds added in batches until the paired interval
excludes zero, lies inside +-practical_bound, or the budget ends) against known distributions, on
synthetic rows (no simulation), and the study runner's looks with a stand-in cell."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from imuslam.study import runner as study_runner
from imuslam.study.cells import Cell
from imuslam.study.config import parse_study
from imuslam.study.report import analyse, pair_verdict
from imuslam.study.runner import next_seeds, run_study
from imuslam.study.sequential import (
    FEW,
    HOLDS,
    NO_DIFF,
    OPEN,
    REVERSED,
    decide,
    look_sizes,
    power,
    schedule,
)

SIZES = look_sizes(3, 15, 3)  # looks at 3, 6, 9, 12, 15 seeds


def test_schedule_and_looks() -> None:
    assert schedule([4, 0, 7], 7) == [4, 0, 7, 1, 2, 3, 5]
    assert schedule([0, 1, 2], 3) == [0, 1, 2]
    assert look_sizes(3, 8, 3) == [3, 6, 8]
    assert look_sizes(5, 5, 5) == [5]
    assert SIZES == [3, 6, 9, 12, 15]


def _verdicts(true: float, sd: float, bound: float, n_runs: int, seed: int) -> pd.DataFrame:
    """``n_runs`` sequences of paired differences ~ N(true, sd), each decided over SIZES."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(n_runs):
        dec = decide(rng.normal(true, sd, SIZES[-1]), SIZES, bound)
        rows.append({"verdict": dec.verdict, "n": dec.n, "lo": dec.lo, "hi": dec.hi})
    return pd.DataFrame(rows)


def _at_most(frac: float, p: float, n: int) -> bool:
    """``frac`` of ``n`` runs is at most ``p`` plus 3 binomial sigmas."""
    return frac <= p + 3 * np.sqrt(p * (1 - p) / n)


def test_no_difference_is_never_claimed_beyond_alpha() -> None:
    """True difference 0, spread 1, bound 0.2 (too small to be shown with 15 seeds): the five looks
    together call a 'holds' or 'reversed' in at most 5 % of the sequences (Bonferroni over the looks;
    looking five times at 95 % intervals calls one in about 15 %); the rest end 'not resolved'
    with the whole budget."""
    n = 1000
    v = _verdicts(0.0, 1.0, 0.2, n, 0)
    wrong = v.verdict.isin([HOLDS, REVERSED]).mean()
    assert _at_most(wrong, 0.05, n), wrong
    assert (v.verdict == NO_DIFF).mean() == 0.0  # a 0.2 bound needs far more than 15 seeds
    # the same looks at plain 95 % intervals call a winner far more often (about 15 %)
    rng = np.random.default_rng(6)
    plain = [decide(rng.normal(0.0, 1.0, 15), SIZES, 0.2, alpha=0.25).verdict for _ in range(n)]
    assert np.isin(plain, [HOLDS, REVERSED]).mean() > 0.1
    assert (v[v.verdict == OPEN].n == 15).all()


def test_a_difference_at_the_bound_is_never_called_equivalent_beyond_alpha() -> None:
    """True difference exactly one bound (0.5, spread 0.5): 'no practical difference' would be wrong;
    it is called in at most 5 % of the sequences. A difference of a tenth of the bound with a small
    spread is called 'no practical difference' in at least 90 %, within the first two looks."""
    n = 1000
    v = _verdicts(0.5, 0.5, 0.5, n, 1)
    assert _at_most((v.verdict == NO_DIFF).mean(), 0.05, n)
    v = _verdicts(0.05, 0.1, 0.5, 400, 2)
    assert (v.verdict == NO_DIFF).mean() >= 0.9
    assert (v.n <= 6).all()
    assert ((v.lo > -0.5) & (v.hi < 0.5))[v.verdict == NO_DIFF].all()


def test_a_large_difference_holds_early_and_the_wrong_way_is_reversed() -> None:
    """Three bounds of difference (1.5, spread 0.5, bound 0.5): 'holds' in 99 % of the sequences, mostly
    within six seeds; the same difference the other way is 'reversed'."""
    v = _verdicts(1.5, 0.5, 0.5, 400, 3)
    assert (v.verdict == HOLDS).mean() >= 0.99
    assert v.n.median() <= 6
    v = _verdicts(-1.5, 0.5, 0.5, 400, 4)
    assert (v.verdict == REVERSED).mean() >= 0.99


def test_power_is_the_rate_a_true_bound_is_found() -> None:
    """The power reported with an unresolved pair: with 6 seeds, spread 1 and the five-look level, the
    rate at which a true difference of one bound gives an interval above 0 (4000 draws) equals the
    noncentral-t power to 3 binomial sigmas."""
    rng = np.random.default_rng(5)
    level = 1 - 0.05 / 5
    n, sd, bound = 6, 1.0, 1.2
    t_crit = stats.t.ppf(0.5 + level / 2, n - 1)
    draws = rng.normal(bound, sd, (4000, n))
    lo = draws.mean(axis=1) - t_crit * draws.std(axis=1, ddof=1) / np.sqrt(n)
    p = power(n, sd, level, bound)
    assert 0.1 < p < 0.9  # a case where it tells something
    assert abs((lo > 0).mean() - p) < 3 * np.sqrt(p * (1 - p) / 4000)


def test_missing_pairs_and_too_few_seeds() -> None:
    """A failed cell (NaN) is left out of its look; one pair alone decides nothing."""
    d = np.array([1.0, np.nan, 1.1, 0.9, 1.0, 1.05])
    dec = decide(d, [3, 6], 0.1)
    assert dec.verdict == HOLDS and dec.n == 5 and dec.look == 2
    assert decide(np.array([1.0, np.nan, np.nan]), [3], 0.1).verdict == FEW


# ---------------------------------------------------------------------------------------------
# the report and the runner over synthetic rows


def _study(**over: Any) -> dict[str, Any]:
    claim = {
        "name": "align", "scenarios": [{"name": "street", "duration_s": 10.0}], "imu": ["online"],
        "alignment": ["none", "kf"], "estimators": [{"name": "ins"}], "compare": "alignment",
        "expect": ["kf", "none"], "eval_align": "none", "seeds": 3, "practical_bound": 0.5,
        "reason": "half a metre", "max_seeds": 12, "seed_batch": 3,
    }  # fmt: skip
    claim.update(over)
    return {"name": "t", "seeds": [0], "align": {"duration_s": 20.0}, "claims": [claim]}


def _rows(effect: float, noise: float, seeds: list[int]) -> pd.DataFrame:
    """Rows of both levels per seed: a common per-seed difficulty (spread 10, paired away) and the
    effect of 'none' over 'kf' with pair noise ``noise``; seeded by the seed, so a seed's rows do not
    depend on which other seeds exist."""
    rows = []
    for s in seeds:
        rng = np.random.default_rng(1000 + s)
        common = rng.normal() * 10
        for lv, shift in (("kf", 0.0), ("none", effect)):
            rows.append({"claim": "align", "scenario": "street", "duration_s": 10.0, "imu": "online",
                         "alignment": lv, "variant": "ins", "seed": s, "status": "ok",
                         "ape_rmse_m": 20 + common + shift + rng.normal() * noise})  # fmt: skip
    return pd.DataFrame(rows)


def test_report_gives_the_seeds_a_pair_took() -> None:
    """A clear effect (2 m, pair noise 0.1) is decided at the first look (3 seeds) even when the table
    holds 12; a null effect with a small spread is 'no practical difference'; with a large spread
    (noise 2 against a 0.5 bound) the budget ends 'not resolved' with its power."""
    study = parse_study(_study())
    claim = study.claims[0]
    p = analyse(claim, _rows(2.0, 0.1, list(range(12))), study.seeds).pairs[0]
    assert (p.verdict, p.n, p.look, p.looks, p.agree) == (HOLDS, 3, 1, 4, 3)
    p = analyse(claim, _rows(0.0, 0.05, list(range(12))), study.seeds).pairs[0]
    assert p.verdict == NO_DIFF and -0.5 < p.lo < p.hi < 0.5
    p = analyse(claim, _rows(0.3, 2.0, list(range(12))), study.seeds).pairs[0]
    assert p.verdict == OPEN and p.n == 12 and p.look == 4 and 0.0 < p.power < 0.8
    assert analyse(claim, _rows(0.0, 0.05, list(range(12))), study.seeds).verdict == (
        "no practical difference"
    )
    # mid-run (only the first look's seeds): the pair is open at look 1, not at the budget's end
    p = analyse(claim, _rows(0.3, 2.0, [0, 1, 2]), study.seeds).pairs[0]
    assert (p.verdict, p.n, p.look, p.scheduled) == (OPEN, 3, 1, 3)
    assert pair_verdict(p).endswith("look 1 of 4)")


def test_next_seeds_adds_a_batch_until_resolved_or_spent() -> None:
    study = parse_study(_study())
    unresolved = _rows(0.3, 2.0, [0, 1, 2])
    assert next_seeds(study, unresolved, {"align": [0, 1, 2]}) == {"align": [0, 1, 2, 3, 4, 5]}
    resolved = _rows(2.0, 0.1, [0, 1, 2])
    assert next_seeds(study, resolved, {"align": [0, 1, 2]}) == {}
    spent = _rows(0.3, 2.0, list(range(12)))
    assert next_seeds(study, spent, {"align": list(range(12))}) == {}


def _stand_in(effect: float, noise: float) -> Any:
    """A cell's row without simulation: the metric of :func:`_rows` for the cell's seed and level."""

    def run_cell(
        cell: Cell | dict[str, Any], calibration: Any = None, shared: Any = None
    ) -> dict[str, Any]:
        c = cell if isinstance(cell, Cell) else Cell.model_validate(cell)
        r = _rows(effect, noise, [c.seed])
        metric = float(r.loc[r.alignment == c.alignment, "ape_rmse_m"].iloc[0])
        return {"key": c.key, **c.label, "status": "ok", "error": "", "ape_rmse_m": metric}

    return run_cell


@pytest.mark.parametrize(
    ("effect", "noise", "verdict", "n_seeds"),
    [(2.0, 0.1, HOLDS, 3), (0.3, 2.0, OPEN, 12), (0.0, 0.1, NO_DIFF, 6)],
)
def test_runner_adds_seeds_until_the_pair_is_decided(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    effect: float,
    noise: float,
    verdict: str,
    n_seeds: int,
) -> None:
    """The study run with a stand-in cell: a clear effect stops at the first look's 3 seeds; an effect
    the budget cannot resolve runs all 12; a null effect stops when its interval fits inside the bound
    (here at the second look, 6 seeds). The report says the same and names the seeds it took."""
    monkeypatch.setattr(study_runner, "run_cell", _stand_in(effect, noise))
    monkeypatch.setattr(study_runner, "calibration_need", lambda c: None)
    monkeypatch.setattr(study_runner, "shared_need", lambda c: None)
    study = parse_study(_study())
    res = run_study(study, tmp_path / "out", serial=True, progress=False)
    seeds_run = sorted(res.table.seed.unique())
    p = analyse(study.claims[0], res.table, study.seeds).pairs[0]
    assert p.verdict == verdict
    assert len(seeds_run) == n_seeds
    assert p.n == len(seeds_run)  # the run stopped at the look that decided
    assert seeds_run == list(range(len(seeds_run)))
    md = (tmp_path / "out" / "report.md").read_text()
    claim_md = md[
        md.index("#### ") :
    ]  # after the notes on how to read it, which name every verdict
    assert f"{p.n} (look {p.look} of 4)" in claim_md and verdict in claim_md
