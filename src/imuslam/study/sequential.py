"""Enough evidence per claim, decided before the run: a paired difference is looked at after each batch
of seeds until its interval settles the pair, or the claim's seed budget ends.

A claim states the smallest difference of its metric that matters in practice (``practical_bound``
B, in the metric's units, with its reason) and a budget (``max_seeds``). Its seeds are a fixed
schedule: the claim's first seeds, then the next unused integers, ``seed_batch`` at a time, up to
``max_seeds``; so the looks are the schedule's prefixes of sizes ``n_0, n_0 + b, ..., max_seeds``
(K looks, known before the run). At each look the paired differences ``d`` (signed: ``d > 0`` is the
claimed direction) give an interval ``mean +- t_{1 - alpha / (2K), n - 1} s / sqrt(n)``, and:

- ``no practical difference`` when it lies inside ``(-B, B)`` (two one-sided tests, TOST, Schuirmann
  1987: the difference is smaller than anything that matters, whichever its sign);
- else ``holds`` when it lies above 0, ``reversed`` when below;
- else ``not resolved``: more seeds, if the budget has any.

The first look that decides a pair is its verdict, with the seeds it took. The level ``1 - alpha / K``
of each look (Bonferroni over the K planned looks) makes the intervals of all looks cover the true mean
difference together with probability at least ``1 - alpha``, and every verdict above is true whenever
its interval covers the truth: the chance that a pair's sequential verdict is wrong (a 'holds' or
'reversed' of a zero difference, a 'no practical difference' of a difference of B or more) is at most
alpha, however many looks are taken. A pair the budget leaves unresolved is reported with the power its
last look had: the probability that a true difference of B in the claimed direction would have been
found ('holds') with that many seeds and the spread seen.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy import stats

ALPHA = 0.05  # of the whole sequence of looks, per pair
HOLDS, REVERSED, NO_DIFF, OPEN, FEW = (
    "holds",
    "reversed",
    "no practical difference",
    "not resolved",
    "too few seeds",
)


def schedule(first: list[int], max_seeds: int) -> list[int]:
    """The claim's seeds in the order they are run: ``first``, then the smallest unused non-negative
    integers, ``max_seeds`` in all (``first`` itself when it is as long)."""
    out = list(dict.fromkeys(first))
    used = set(out)
    k = 0
    while len(out) < max_seeds:
        if k not in used:
            out.append(k)
            used.add(k)
        k += 1
    return out


def look_sizes(n_first: int, max_seeds: int, batch: int) -> list[int]:
    """Seeds at each look: ``n_first``, then ``batch`` more each time, the last one ``max_seeds``."""
    sizes = [min(n_first, max_seeds)]
    while sizes[-1] < max_seeds:
        sizes.append(min(sizes[-1] + batch, max_seeds))
    return sizes


@dataclass
class Decision:
    """A pair's verdict, the seeds it took (paired differences used), the mean difference and its
    interval at that look, the look (1-based) of how many planned, and the power at the bound."""

    verdict: str
    n: int
    mean: float
    lo: float
    hi: float
    look: int
    looks: int
    level: float
    power: float


@lru_cache(maxsize=4096)
def t_quantile(q: float, dof: int) -> float:
    """Student t quantile (cached: the same few are asked for at every look)."""
    return float(stats.t.ppf(q, dof))


def interval(d: NDArray[np.float64], level: float) -> tuple[float, float, float]:
    """Mean and the two-sided Student-t interval of confidence ``level`` of ``d`` (n >= 2)."""
    m = float(np.mean(d))
    h = t_quantile(0.5 + level / 2, len(d) - 1) * float(np.std(d, ddof=1)) / np.sqrt(len(d))
    return m, m - h, m + h


def verdict_of(lo: float, hi: float, bound: float) -> str:
    """The verdict of one look's interval (see the module docstring)."""
    if -bound < lo and hi < bound:
        return NO_DIFF
    if lo > 0:
        return HOLDS
    if hi < 0:
        return REVERSED
    return OPEN


def power(n: int, sd: float, level: float, bound: float) -> float:
    """Probability that an interval of confidence ``level`` over ``n`` paired differences of spread
    ``sd`` lies above 0 when the true difference is ``bound`` (noncentral t)."""
    if sd == 0.0:
        return 1.0
    t_crit = t_quantile(0.5 + level / 2, n - 1)
    return float(stats.nct.sf(t_crit, n - 1, bound / (sd / np.sqrt(n))))


def power_at_bound(d: NDArray[np.float64], level: float, bound: float) -> float:
    """:func:`power` with the seeds and the spread of ``d``."""
    return power(len(d), float(np.std(d, ddof=1)), level, bound)


def decide(
    d_by_seed: NDArray[np.float64],
    sizes: list[int],
    bound: float,
    alpha: float = ALPHA,
) -> Decision:
    """The sequential verdict of one pair. ``d_by_seed``: the signed paired differences in the schedule's
    order, NaN where a seed has no pair (a failed cell) or has not run; ``sizes``: the planned looks
    (:func:`look_sizes`). Looks beyond the seeds run so far are not taken."""
    d_all = np.asarray(d_by_seed, dtype=float)
    K = len(sizes)
    level = 1.0 - alpha / K
    last: Decision | None = None
    last_d = d_all[:0]
    for k, n_k in enumerate(sizes):
        if n_k > len(d_all):
            break
        d = d_all[:n_k]
        d = d[np.isfinite(d)]
        if len(d) < 2:
            m = float(d[0]) if len(d) else float("nan")
            last = Decision(FEW, len(d), m, float("nan"), float("nan"), k + 1, K, level, 0.0)
            continue
        m, lo, hi = interval(d, level)
        v = verdict_of(lo, hi, bound)
        last = Decision(v, len(d), m, lo, hi, k + 1, K, level, float("nan"))
        last_d = d
        if v != OPEN:
            break
    if last is None:
        return Decision(FEW, 0, float("nan"), float("nan"), float("nan"), 0, K, level, 0.0)
    if last.verdict != FEW:
        last.power = power_at_bound(last_d, level, bound)
    return last
