"""What a study's numbers say about each claim: means with 95 % confidence intervals over seeds, paired
differences between the levels the claim orders, a verdict per pair, and the figures; written as
report.html (figures inline) and report.md (the tables, for a README), beside results.parquet,
results.csv and the effective study.yaml.

Statistics: for a level, the mean of the metric over seeds and its 95 % interval
``mean +- t_{0.975, n-1} s / sqrt(n)`` (Student t). For a pair (better, worse) of the claimed order,
the per-seed difference ``d = worse - better`` (``better - worse`` when higher is better) between cells
that differ only in the compared factor, so ``d > 0`` is the claimed direction. Its verdict is the
sequential one of :mod:`imuslam.study.sequential`: looked at after each batch of seeds of the claim's
schedule, 'no practical difference' when the interval lies inside +-practical_bound, else 'holds' when
it lies above 0, 'reversed' when below, 'not resolved' when the budget ended first (with the power it
had); reported with the seeds it took, its mean and interval at that look, and how many seeds agree.
"""

from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from imuslam.io.atomic import write_atomic
from imuslam.study.config import ClaimSpec, StudyConfig, dump_study
from imuslam.study.sequential import (
    FEW,
    HOLDS,
    NO_DIFF,
    OPEN,
    REVERSED,
    decide,
    look_sizes,
    schedule,
)

FACTOR_COLUMN = {
    "scenario": "scenario",
    "imu": "imu",
    "alignment": "alignment",
    "estimator": "variant",
}
CONTEXT = ("scenario", "duration_s", "imu", "alignment", "variant")


def mean_ci(x: np.ndarray) -> tuple[float, float, float]:
    """Mean and 95 % Student-t interval (lo, hi) of ``x``; the interval is nan with fewer than 2 values."""
    x = np.asarray(x, float)
    if len(x) == 0:
        return float("nan"), float("nan"), float("nan")
    m = float(np.mean(x))
    if len(x) < 2:
        return m, float("nan"), float("nan")
    h = float(stats.t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / np.sqrt(len(x)))
    return m, m - h, m + h


@dataclass
class LevelRow:
    context: str
    level: str
    n: int
    failed: int
    mean: float
    lo: float
    hi: float
    median: float


@dataclass
class PairRow:
    context: str
    better: str
    worse: str
    n: int
    mean: float
    lo: float
    hi: float
    agree: int
    verdict: str
    bound: float = float("nan")
    budget: int = 0
    look: int = 0
    looks: int = 0
    level: float = float("nan")
    power: float = float("nan")
    scheduled: int = 0  # seeds of the schedule up to the deciding (or last) look
    diffs: tuple[
        float, ...
    ] = ()  # the per-seed differences the verdict took, in the schedule's order


@dataclass
class ClaimResult:
    claim: ClaimSpec
    levels: list[LevelRow]
    pairs: list[PairRow]
    verdict: str
    frame: pd.DataFrame


def _context_name(keys: tuple[Any, ...], cols: list[str]) -> str:
    parts = []
    for c, v in zip(cols, keys, strict=True):
        parts.append(f"{v:g} s" if c == "duration_s" else str(v))
    return ", ".join(parts)


def seed_plan(claim: ClaimSpec, study_seeds: list[int]) -> tuple[list[int], list[int]]:
    """The claim's seeds in the order they run, and the seeds at each planned look."""
    first = claim.first_seeds(study_seeds)
    budget = claim.max_seeds or len(first)
    return schedule(first, budget), look_sizes(len(first), budget, claim.batch(study_seeds))


def analyse(
    claim: ClaimSpec, df: pd.DataFrame, study_seeds: list[int] | None = None
) -> ClaimResult:
    """Level means and paired differences of one claim (see the module docstring). ``study_seeds``: the
    study's seeds (the claim's first seeds when it has none of its own); default: the seeds in ``df``."""
    col = FACTOR_COLUMN[claim.compare]
    d = df[df["claim"] == claim.name]
    if study_seeds is None:
        study_seeds = sorted(int(x) for x in d["seed"].unique())
    order_seeds, sizes = seed_plan(claim, study_seeds)
    bound = float(claim.practical_bound or 0.0)
    ctx_cols = [c for c in CONTEXT if c != col and d[c].nunique() > 1] or ["scenario"]
    order = claim.expect or claim.levels()
    rest = [lv for lv in claim.levels() if lv not in order]
    levels, pairs = [], []
    sign = 1.0 if claim.lower_is_better else -1.0
    for keys, g in d.groupby(ctx_cols, sort=False):
        keys = keys if isinstance(keys, tuple) else (keys,)
        name = _context_name(keys, ctx_cols)
        ok = g[g["status"] == "ok"]
        for lv in order + rest:
            x = (
                ok.loc[ok[col] == lv, claim.metric].to_numpy(float)
                if claim.metric in ok
                else np.zeros(0)
            )
            m, lo, hi = mean_ci(x)
            nf = int(((g[col] == lv) & (g["status"] != "ok")).sum())
            levels.append(
                LevelRow(
                    name, lv, len(x), nf, m, lo, hi, float(np.median(x)) if len(x) else float("nan")
                )
            )
        if claim.metric not in ok:
            continue
        by_seed = ok.pivot_table(index="seed", columns=col, values=claim.metric, aggfunc="first")
        # the claimed order: each level against the next; no order claimed: each against the first
        pair_list = (
            list(zip(order[:-1], order[1:], strict=True))
            if claim.expect
            else [(order[0], lv) for lv in order[1:]]
        )
        for better, worse in pair_list:
            if better not in by_seed or worse not in by_seed:
                pairs.append(PairRow(name, better, worse, 0, *(float("nan"),) * 3, 0, "no data"))
                continue
            diff = sign * (by_seed[worse] - by_seed[better])
            # the schedule's seeds that have run (their cells may have failed: NaN), in order
            run = set(int(x) for x in d["seed"].unique())
            n_run = next((i for i, sd in enumerate(order_seeds) if sd not in run), len(order_seeds))
            d_seq = diff.reindex(order_seeds[:n_run]).to_numpy(float)
            dec = decide(d_seq, sizes, bound)
            used = d_seq[: sizes[dec.look - 1] if dec.look else 0]
            agree = int((used[np.isfinite(used)] > 0).sum())
            pairs.append(
                PairRow(name, better, worse, dec.n, dec.mean, dec.lo, dec.hi, agree, dec.verdict,
                        bound, sizes[-1], dec.look, dec.looks, dec.level, dec.power,
                        sizes[dec.look - 1] if dec.look else 0, tuple(float(x) for x in used))
            )  # fmt: skip
    return ClaimResult(claim, levels, pairs, overall_verdict(claim, [p.verdict for p in pairs]), d)


# How to read a study's output, printed by the command and written at the head of both reports.
READING = (
    "A cell is one run of an estimator: one claim, scenario, IMU, alignment, variant and seed. "
    "'N cells: M run, C from the cache, F failed' counts the cells of the plan, those computed by this "
    "invocation, those read from the cells/ cache an earlier run left, and those (of either) that "
    "failed, listed with their error.",
    "Mean difference: per seed, the metric of the claimed-worse level minus the claimed-better one "
    "(better minus worse when higher is better), in the metric's unit: positive is the claimed "
    "direction, negative the reverse; its interval decides the pair's verdict against the practical "
    "bound.",
    "Verdicts of a claim: supported (every pair holds); partly supported (at least one pair holds, none "
    "reversed, the others show no practical difference or are not resolved within the seed budget); "
    "contradicted (a pair reversed); no practical difference (every pair within the bound); not "
    "resolved (the budget ended first).",
)


def overall_verdict(claim: ClaimSpec, vs: list[str]) -> str:
    """The claim's verdict from its pairs' (in the claimed order)."""
    if not claim.expect:
        return "comparison (no order claimed)"
    if not vs:
        return "no data"
    if all(v == HOLDS for v in vs):
        return "supported"
    if any(v == REVERSED for v in vs):
        return "contradicted (at least one pair reversed)"
    if all(v == NO_DIFF for v in vs):
        return "no practical difference"
    if HOLDS in vs and not any(v in (OPEN, FEW) for v in vs):
        return "partly supported (the other pairs: no practical difference)"
    return "partly supported" if HOLDS in vs else "not resolved"


def fmt_number(x: float) -> str:
    if not np.isfinite(x):
        return "-"
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:,.0f}"


def markdown(res: ClaimResult) -> str:
    c = res.claim
    seed = f" (seed {c.seed_doc})" if c.seed_doc else ""
    lines = [f"#### {c.name}{seed}: {c.statement}".rstrip(": "), "",
             f"Metric `{c.metric}` ({'lower' if c.lower_is_better else 'higher'} is better), by `{c.compare}`. "
             f"Verdict: **{res.verdict}**.", "",
             "| context | level | seeds | mean | 95 % CI | median | failed |", "|---|---|---:|---:|---|---:|---:|"]  # fmt: skip
    for r in res.levels:
        lines.append(
            f"| {r.context} | {r.level} | {r.n} | {fmt_number(r.mean)} | [{fmt_number(r.lo)}, {fmt_number(r.hi)}] | {fmt_number(r.median)} | {r.failed} |"
        )
    if c.practical_bound is not None:
        lines += ["", f"Practical bound: {fmt_number(c.practical_bound)} ({c.metric}): {c.reason.strip()}. "
                  f"Seed budget: {c.max_seeds}."]  # fmt: skip
    lines += ["", "| context | better | than | seeds (look) | mean difference | interval | seeds agreeing | verdict |",
              "|---|---|---|---:|---:|---|---:|---|"]  # fmt: skip
    for p in res.pairs:
        lines.append(
            f"| {p.context} | {p.better} | {p.worse} | {pair_seeds(p)} | {fmt_number(p.mean)} | {pair_interval(p)} | {p.agree}/{p.n} | {pair_verdict(p)} |"
        )
    return "\n".join(lines) + "\n"


PAIR_COLUMNS = ("claim", "context", "pair", "difference", "interval", "bound", "verdict", "seeds")


def pair_table_rows(res: ClaimResult) -> list[list[str]]:
    """One row per pair for the terminal (:data:`PAIR_COLUMNS`): the effect with its interval, the
    verdict and the seeds it took."""
    return [
        [res.claim.name, p.context, f"{p.better} > {p.worse}", fmt_number(p.mean), pair_interval(p),
         fmt_number(p.bound), pair_verdict(p), pair_seeds(p)]
        for p in res.pairs
    ]  # fmt: skip


def pair_seeds(p: PairRow) -> str:
    """'6 (look 2 of 4)': the paired seeds the verdict took and at which planned look."""
    return f"{p.n} (look {p.look} of {p.looks})" if p.looks else str(p.n)


def pair_interval(p: PairRow) -> str:
    """'[lo, hi] 98.8 %': the interval of the deciding look and its confidence."""
    level = f" {100 * p.level:.4g} %" if np.isfinite(p.level) else ""
    return f"[{fmt_number(p.lo)}, {fmt_number(p.hi)}]{level}"


def pair_verdict(p: PairRow) -> str:
    """The verdict; an unresolved one with the power it had to find a difference of one bound."""
    if p.verdict == OPEN and np.isfinite(p.power):
        when = (
            f"budget {p.budget} spent" if p.scheduled >= p.budget else f"look {p.look} of {p.looks}"
        )
        return f"{p.verdict} (power {p.power:.2f} at the bound, {when})"
    return p.verdict


def figure_png(res: ClaimResult) -> bytes:
    """Per context: the metric per level (seeds as dots, mean with its 95 % interval)."""
    from matplotlib.figure import Figure

    ctxs = list(dict.fromkeys(r.context for r in res.levels))
    fig = Figure(figsize=(min(4.0 + 2.2 * len(ctxs), 16), 3.6))
    col = FACTOR_COLUMN[res.claim.compare]
    ok = res.frame[res.frame["status"] == "ok"]
    ctx_cols = [c for c in CONTEXT if c != col and res.frame[c].nunique() > 1] or ["scenario"]
    for i, ctx in enumerate(ctxs):
        ax = fig.add_subplot(1, len(ctxs), i + 1)
        rows = [r for r in res.levels if r.context == ctx]
        sel = ok[
            [_context_name(tuple(v), ctx_cols) == ctx for v in ok[ctx_cols].itertuples(index=False)]
        ]
        for j, r in enumerate(rows):
            y = (
                sel.loc[sel[col] == r.level, res.claim.metric].to_numpy(float)
                if res.claim.metric in sel
                else []
            )
            ax.plot(
                np.full(len(y), j) + np.linspace(-0.12, 0.12, len(y)), y, ".", color="0.6", ms=4
            )
            if np.isfinite(r.mean):
                err = [[r.mean - r.lo], [r.hi - r.mean]] if np.isfinite(r.lo) else None
                ax.errorbar([j], [r.mean], yerr=err, fmt="o", color="C0", capsize=4)
        ax.set_xticks(range(len(rows)), [r.level for r in rows], rotation=30, ha="right")
        ax.set_title(ctx, fontsize=9)
        vals = [r.mean for r in rows if np.isfinite(r.mean) and r.mean > 0]
        if vals and max(vals) / min(vals) > 30:
            ax.set_yscale("log")
        if i == 0:
            ax.set_ylabel(res.claim.metric)
        ax.grid(alpha=0.3)
    fig.suptitle(res.claim.name, fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def differences_figure(res: ClaimResult) -> Any:
    """Per pair: the paired differences per seed (dots), their mean with the verdict's interval, and the
    practical bound (shaded, +-bound): the picture of each verdict. None when no pair has data."""
    from matplotlib.figure import Figure

    pairs = [p for p in res.pairs if p.diffs]
    if not pairs:
        return None
    fig = Figure(figsize=(min(1.0 + 3.0 * len(pairs), 16), 3.6))
    for i, p in enumerate(pairs):
        ax = fig.add_subplot(1, len(pairs), i + 1)
        d = np.asarray(p.diffs, float)
        ax.plot(
            np.linspace(-0.15, 0.15, len(d)), d, ".", color="0.5", ms=5, label=f"seeds ({len(d)})"
        )
        if np.isfinite(p.mean) and np.isfinite(p.lo):
            ax.errorbar([0.4], [p.mean], yerr=[[p.mean - p.lo], [p.hi - p.mean]], fmt="o",
                        color="C0", capsize=4, label="mean, interval")  # fmt: skip
        if np.isfinite(p.bound) and p.bound > 0:
            ax.axhspan(-p.bound, p.bound, color="C2", alpha=0.15, label=f"bound +-{p.bound:g}")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xlim(-0.5, 0.8)
        ax.set_xticks([])
        ax.set_title(f"{p.better} > {p.worse}\n{p.verdict}", fontsize=8)
        if i == 0:
            ax.set_ylabel(f"difference, {res.claim.metric}")
        ax.legend(fontsize=6, loc="best")
        ax.grid(alpha=0.3)
    fig.suptitle(f"{res.claim.name}: paired differences (positive: as claimed)", fontsize=10)
    fig.tight_layout()
    return fig


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return base64.b64encode(buf.getvalue()).decode()


def md_table_html(md: str) -> str:
    """The markdown tables of :func:`markdown` as HTML tables (the rest as paragraphs)."""
    out: list[str] = []
    rows: list[list[str]] = []

    def flush() -> None:
        if rows:
            head, body = rows[0], rows[2:]
            out.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
                       + "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in body)
                       + "</table>")  # fmt: skip
            rows.clear()

    for line in md.splitlines():
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip("|").split("|")])
            continue
        flush()
        if line.startswith("#### "):
            out.append(f"<h3>{html.escape(line[5:])}</h3>")
        elif line.strip():
            out.append(f"<p>{html.escape(line).replace('**', '')}</p>")
    flush()
    return "\n".join(out)


def write_outputs(
    study: StudyConfig, df: pd.DataFrame, out: Path, backend: str
) -> list[ClaimResult]:
    """results.parquet, results.csv, study.yaml, report.md and report.html in ``out`` (each atomic)."""
    results = [analyse(c, df, study.seeds) for c in study.claims]
    md = "\n\n".join(READING) + "\n\n" + "\n".join(markdown(r) for r in results)
    failed = df[df["status"] != "ok"]
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    write_atomic(out / "results.parquet", buf.getvalue())
    write_atomic(out / "results.csv", df.to_csv(index=False))
    write_atomic(out / "study.yaml", dump_study(study))
    write_atomic(out / "report.md", md)
    parts = [f"<h1>Study {html.escape(study.name)}</h1>",
             f"<p>{len(df)} cells ({df['key'].nunique()} distinct), {len(failed)} failed; seeds {study.seeds}; "
             f"run on {html.escape(backend)}. Means with 95 % Student-t intervals over seeds; differences paired by seed, "
             f"looked at after each batch of seeds, each look's interval at 1 - 0.05 / (planned looks).</p>",
             *(f"<p>{html.escape(x)}</p>" for x in READING)]  # fmt: skip
    for r in results:
        png = base64.b64encode(figure_png(r)).decode()
        parts.append(md_table_html(markdown(r)))
        parts.append(f'<img alt="{html.escape(r.claim.name)}" src="data:image/png;base64,{png}">')
        diff_fig = differences_figure(r)
        if diff_fig is not None:
            parts.append(f'<img alt="{html.escape(r.claim.name)}: paired differences" '
                         f'src="data:image/png;base64,{_png(diff_fig)}">')  # fmt: skip
    if len(failed):
        cols = ["claim", "scenario", "imu", "alignment", "variant", "seed", "error"]
        parts.append("<h2>Failed cells</h2>" + failed[cols].to_html(index=False, escape=True))
    tcols = [c for c in df.columns if c.startswith("t_") and c.endswith("_s")]
    if tcols:
        tt = df[df["status"] == "ok"].groupby("variant")[tcols].mean()
        parts.append(
            "<h2>Mean time per stage, s</h2>" + tt.to_html(float_format=lambda x: f"{x:.3f}")
        )
    parts.append("<h2>Study</h2><pre>" + html.escape(dump_study(study)) + "</pre>")
    style = ("body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse;margin:8px 0}"
             "td,th{border:1px solid #ccc;padding:2px 6px;font-size:13px}img{max-width:100%}")  # fmt: skip
    write_atomic(out / "report.html", f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(study.name)}</title>"
                 f"<style>{style}</style></head><body>{''.join(parts)}</body></html>\n")  # fmt: skip
    return results
