"""bench/compare.py's verdict on synthetic tables: a row 20 % slower than the reference beyond the
spread its rounds measured is flagged, a row changed within that spread is not."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"
ROUNDS = 7
# per-round deviations whose median absolute value is 1: a row built on them has the spread
# 1.4826 * s exactly (bench/table.py's robust relative standard deviation)
Z = (-1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5)


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def bench() -> tuple[ModuleType, ModuleType]:
    return _load("table"), _load("compare")


def _row(table: ModuleType, name: str, s: float, slow: float) -> dict[str, Any]:
    """A row whose per-round ratio is 0.5 (1 + s z) times ``slow``, against an anchor of 1 s a round."""
    ours = [0.5 * slow * (1.0 + s * z) for z in Z]
    return dict(table.make_row(name, ours, [1.0] * ROUNDS, None, "", "cmd", "wall", "anchor"))


def _tables(table: ModuleType, rows: list[tuple[str, float, float]]) -> tuple[dict, dict]:
    ref = {"rows": [_row(table, n, s, 1.0) for n, s, _ in rows]}
    new = {"rows": [_row(table, n, s, slow) for n, s, slow in rows]}
    return new, ref


def test_twenty_percent_beyond_the_spread_is_flagged_within_it_is_not(bench: Any) -> None:
    table, compare = bench
    new, ref = _tables(
        table,
        [
            (
                "tight, 20 % slower",
                0.02,
                1.2,
            ),  # spread 3 %: limit max(2 x 1.2533 x 0.03 x sqrt(2/7), 5 %)
            ("tight, unchanged", 0.02, 1.0),
            (
                "wide, 20 % slower",
                0.3,
                1.2,
            ),  # spread 44 %: limit 2 x 1.2533 x 0.44 x sqrt(2/7) = 60 %
        ],
    )
    assert new["rows"][2]["spread"] == pytest.approx(1.4826 * 0.3)
    lines, slips, missed = compare.compare(new, ref)
    verdicts = {line[0]: line[6] for line in lines}
    assert slips == 1 and missed == 0
    assert verdicts["tight, 20 % slower"].startswith("SLIPPED (limit 5 %)")
    assert verdicts["tight, unchanged"].startswith("within noise")
    assert verdicts["wide, 20 % slower"].startswith("within noise (limit 60 %)")
    assert [line[4] for line in lines] == ["+20 %", "+0 %", "+20 %"]


def test_a_change_under_the_floor_is_not_flagged_even_without_spread(bench: Any) -> None:
    """Rounds without any scatter give a zero standard error; the 5 % floor still applies."""
    table, compare = bench
    new, ref = _tables(
        table, [("no spread, 4 % slower", 0.0, 1.04), ("no spread, 6 % slower", 0.0, 1.06)]
    )
    lines, slips, _ = compare.compare(new, ref)
    assert slips == 1
    assert [line[6].split(" (")[0] for line in lines] == ["within noise", "SLIPPED"]
