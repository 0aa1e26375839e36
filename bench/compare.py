"""Compare a table of headline ratios (bench/table.py's results.json) with the committed reference.

For each row in both files, and each clock the row holds (its ratio ours / anchor; for a row without an
anchor, ours' own median time; for the Allan rows also the CPU-time ratio), the relative change
``new / reference - 1`` is set against the noise of the two medians: a row's spread s is the robust
relative standard deviation of its per-round ratios, the standard error of a median of R rounds is about
1.2533 s / sqrt(R) (a median of normal draws, asymptotically), and a change counts as a slip when it
exceeds twice the standard error of the difference of the two medians, and 5 %. Rows whose goal is
missed in the new table are marked, and each row shows how its anchor's own median time changed (the
anchors' times show how differently loaded the machine was in the two runs). Exit status 1 when a row slipped (``--no-fail``: always 0), so
``make bench`` notices; ``--strict`` also fails on a missed goal.

Run: python bench/compare.py [RESULTS] [--reference FILE] [--no-fail]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
FLOOR = 0.05  # the smallest change reported as a slip, whatever the spreads say
Z = 2.0  # standard errors of the difference of two medians


def _clocks(row: dict[str, Any]) -> dict[str, tuple[float, float, float | None]]:
    """clock name -> (value, spread, the anchor's median time on that clock or None) of one row."""
    same_run = row.get("anchor_kind") == "same run"
    out: dict[str, tuple[float, float, float | None]] = {}
    if row.get("ratio") is not None:
        out[f"{row['clock']} ratio"] = (
            row["ratio"],
            row["spread"],
            row["anchor_s"] if same_run else None,
        )
    else:
        out[f"{row['clock']} time"] = (row["ours_s"], row["spread"], None)
    if row.get("cpu_ratio") is not None:
        out["cpu ratio"] = (
            row["cpu_ratio"],
            row["cpu_spread"],
            statistics.median(row["anchor_cpu_times"]),
        )
    return out


def threshold(s_new: float, r_new: int, s_ref: float, r_ref: int) -> float:
    """The relative change beyond which a row counts as slipped."""
    se = 1.2533 * math.sqrt(s_new**2 / max(r_new, 1) + s_ref**2 / max(r_ref, 1))
    return max(Z * se, FLOOR)


def compare(new: dict[str, Any], ref: dict[str, Any]) -> tuple[list[list[str]], int, int]:
    """(table rows, slips, missed goals)."""
    ref_rows = {r["name"]: r for r in ref["rows"]}
    lines, slips, missed = [], 0, 0
    for row in new["rows"]:
        old = ref_rows.get(row["name"])
        goal = _goal(row)
        missed += goal.endswith("MISSED")
        if old is None:
            lines.append([row["name"], "-", "-", "-", "-", "-", "not in the reference", goal])
            continue
        old_clocks = _clocks(old)
        for clock, (v, s, a) in _clocks(row).items():
            if clock not in old_clocks:
                continue
            v0, s0, a0 = old_clocks[clock]
            # the anchor's own median time against the reference's: how differently loaded the machine was
            drift = f"{100 * (a / a0 - 1):+.0f} %" if a and a0 else "-"
            change = v / v0 - 1.0
            lim = threshold(s, row["rounds"], s0, old["rounds"])
            slipped = change > lim
            slips += slipped
            verdict = "SLIPPED" if slipped else ("faster" if change < -lim else "within noise")
            on_goal = clock.startswith(row["clock"] + " ")  # the goal is set on the row's own clock
            lines.append([row["name"], clock, f"{v0:.4g}", f"{v:.4g}", f"{100 * change:+.0f} %",
                          drift, f"{verdict} (limit {100 * lim:.0f} %)",
                          goal if on_goal else "-"])  # fmt: skip
    return lines, slips, missed


def _goal(row: dict[str, Any]) -> str:
    if row["goal_kind"] == "ratio" and row["ratio"] is not None:
        return f"<= {row['goal']}: " + ("met" if row["ratio"] <= row["goal"] else "MISSED")
    if row["goal_kind"] == "seconds":
        return f"<= {row['goal']} s: " + ("met" if row["ours_s"] <= row["goal"] else "MISSED")
    return "-"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("results", nargs="?", type=Path, default=BENCH / "results.json")
    ap.add_argument("--reference", type=Path, default=BENCH / "reference.json")
    ap.add_argument("--no-fail", action="store_true")
    ap.add_argument("--strict", action="store_true", help="fail on a missed goal too")
    a = ap.parse_args()
    new, ref = json.loads(a.results.read_text()), json.loads(a.reference.read_text())
    from rich.console import Console
    from rich.table import Table

    lines, slips, missed = compare(new, ref)
    t = Table(
        title=f"{a.results.name} ({new['date']}, load {new['load_start']}-{new['load_end']}, numba "
        f"{new['env']['numba']} {new['env']['threading_layer']}) against {a.reference.name} "
        f"({ref['date']}, load {ref['load_start']}-{ref['load_end']}, numba {ref['env']['numba']} "
        f"{ref['env']['threading_layer']})"
    )
    for c in ("row", "clock", "reference", "now", "change", "anchor's time", "verdict", "goal now"):
        t.add_column(c, justify="left" if c in ("row", "verdict", "goal now") else "right")
    for line in lines:
        t.add_row(*line)
    Console(width=200).print(t)
    for key in ("numpy", "numba", "llvmlite", "threading_layer", "num_threads"):
        if new["env"].get(key) != ref["env"].get(key):
            print(f"{key}: {ref['env'].get(key)} in the reference, {new['env'].get(key)} now")
    print(f"{slips} slipped, {missed} goals missed")
    if (slips or (a.strict and missed)) and not a.no_fail:
        sys.exit(1)


if __name__ == "__main__":
    main()
