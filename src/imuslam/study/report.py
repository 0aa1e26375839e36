"""What a study's numbers say about each claim: means with 95 % confidence intervals over seeds, paired
differences between the levels the claim orders, a verdict per pair, and the figures; written as
report.html (figures inline) and report.md (the tables, for a README), beside results.parquet,
results.csv and the effective study.yaml.

Statistics: for a level, the mean of the metric over seeds and its 95 % interval
``mean +- t_{0.975, n-1} s / sqrt(n)`` (Student t). For a pair (better, worse) of the claimed order,
the per-seed difference ``d = worse - better`` (``better - worse`` when higher is better) between cells
that differ only in the compared factor, so ``d > 0`` is the claimed direction; its mean and 95 %
interval, and how many seeds agree. Verdict: 'holds' when the interval lies above 0, 'reversed' when it
lies below, 'not resolved' otherwise (more seeds, or no real difference).
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


def analyse(claim: ClaimSpec, df: pd.DataFrame) -> ClaimResult:
    """Level means and paired differences of one claim (see the module docstring)."""
    col = FACTOR_COLUMN[claim.compare]
    d = df[df["claim"] == claim.name]
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
            diff = (sign * (by_seed[worse] - by_seed[better])).dropna().to_numpy(float)
            m, lo, hi = mean_ci(diff)
            verdict = (
                ("holds" if lo > 0 else "reversed" if hi < 0 else "not resolved")
                if len(diff) >= 2
                else "too few seeds"
            )
            pairs.append(
                PairRow(name, better, worse, len(diff), m, lo, hi, int((diff > 0).sum()), verdict)
            )
    vs = [p.verdict for p in pairs]
    if not claim.expect:
        overall = "comparison (no order claimed)"
    elif vs and all(v == "holds" for v in vs):
        overall = "supported"
    elif any(v == "reversed" for v in vs):
        overall = "contradicted (at least one pair reversed)"
    else:
        overall = "partly supported" if any(v == "holds" for v in vs) else "not resolved"
    return ClaimResult(claim, levels, pairs, overall, d)


def _fmt(x: float) -> str:
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
            f"| {r.context} | {r.level} | {r.n} | {_fmt(r.mean)} | [{_fmt(r.lo)}, {_fmt(r.hi)}] | {_fmt(r.median)} | {r.failed} |"
        )
    lines += ["", "| context | better | than | seeds | mean difference | 95 % CI | seeds agreeing | verdict |",
              "|---|---|---|---:|---:|---|---:|---|"]  # fmt: skip
    for p in res.pairs:
        lines.append(
            f"| {p.context} | {p.better} | {p.worse} | {p.n} | {_fmt(p.mean)} | [{_fmt(p.lo)}, {_fmt(p.hi)}] | {p.agree}/{p.n} | {p.verdict} |"
        )
    return "\n".join(lines) + "\n"


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


def _md_table_html(md: str) -> str:
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
    results = [analyse(c, df) for c in study.claims]
    md = "\n".join(markdown(r) for r in results)
    failed = df[df["status"] != "ok"]
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    write_atomic(out / "results.parquet", buf.getvalue())
    write_atomic(out / "results.csv", df.to_csv(index=False))
    write_atomic(out / "study.yaml", dump_study(study))
    write_atomic(out / "report.md", md)
    parts = [f"<h1>Study {html.escape(study.name)}</h1>",
             f"<p>{len(df)} cells ({df['key'].nunique()} distinct), {len(failed)} failed; seeds {study.seeds}; "
             f"run on {html.escape(backend)}. Means with 95 % Student-t intervals over seeds; differences paired by seed.</p>"]  # fmt: skip
    for r in results:
        png = base64.b64encode(figure_png(r)).decode()
        parts.append(_md_table_html(markdown(r)))
        parts.append(f'<img alt="{html.escape(r.claim.name)}" src="data:image/png;base64,{png}">')
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
