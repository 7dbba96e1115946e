"""Statistics over an ensemble of independent realisations (seeds) of one scene.

A quantity estimated once per seed (``C_I``, a closure's error, a stationary mean)
is summarised by its ensemble mean and two standard errors:

* across seeds, ``s / sqrt(n)`` with the sample standard deviation ``s`` (ddof 1):
  contains every source of scatter between independent runs;
* pooled, ``sqrt(sum_k se_k^2) / n`` from the per-seed standard errors (time
  averages within a run).

The quoted ``error`` is the larger of the two (with one seed, the pooled one).

Differences between two quantities measured on the *same* seeds (two closures
judged on the same runs) are tested pairwise: ``t = mean(d) / (s_d / sqrt(n))``
with Student's t distribution of ``n - 1`` degrees of freedom (a paired t-test),
and a ranking of several quantities adjusts the p-values of the neighbour
comparisons by Holm's (1979) step-down rule.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Mapping, Sequence

import numpy as np
from scipy import stats

from pyfold.errors import InputError


@dataclasses.dataclass(frozen=True)
class EnsembleMean:
    """Ensemble mean of a per-seed estimate, with its standard errors."""

    mean: float
    stderr_across: float  # s / sqrt(n); NaN with one seed
    stderr_pooled: float  # sqrt(sum se_k^2) / n; NaN without per-seed errors
    n: int

    @property
    def error(self) -> float:
        """The standard error to quote: the larger available of the two."""
        values = [v for v in (self.stderr_across, self.stderr_pooled) if math.isfinite(v)]
        return max(values) if values else math.nan


def ensemble_mean(values: Sequence[float], stderrs: Sequence[float] | None = None) -> EnsembleMean:
    """Mean over seeds of ``values`` (non-finite entries are an error), see the module docstring."""
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0:
        raise InputError("values: empty ensemble")
    if not np.all(np.isfinite(v)):
        raise InputError(f"values: non-finite per-seed estimate in {v.tolist()}")
    n = int(v.size)
    across = float(np.std(v, ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    pooled = math.nan
    if stderrs is not None:
        s = np.asarray(stderrs, dtype=float).ravel()
        if s.shape != v.shape:
            raise InputError(f"stderrs: {s.size} values for {n} estimates")
        if np.all(np.isfinite(s)):
            pooled = float(math.sqrt(float(np.sum(s * s))) / n)
    return EnsembleMean(mean=float(np.mean(v)), stderr_across=across, stderr_pooled=pooled, n=n)


@dataclasses.dataclass(frozen=True)
class PairedDifference:
    """``mean(a - b)`` over seeds, its standard error, t statistic and two-sided p-value."""

    mean: float
    stderr: float
    t: float
    p: float
    n: int


def paired_difference(a: Sequence[float], b: Sequence[float]) -> PairedDifference:
    """Paired t-test of ``a - b`` over the same seeds (two-sided)."""
    x, y = np.asarray(a, dtype=float).ravel(), np.asarray(b, dtype=float).ravel()
    if x.shape != y.shape:
        raise InputError(f"paired_difference: {x.size} and {y.size} values; the same seeds are needed")
    d = x - y
    n = int(d.size)
    if n < 2:
        return PairedDifference(float(d.mean()) if n else math.nan, math.nan, math.nan, math.nan, n)
    se = float(np.std(d, ddof=1) / math.sqrt(n))
    mean = float(d.mean())
    if se == 0.0:
        t = math.inf if mean != 0.0 else 0.0
        p = 0.0 if mean != 0.0 else 1.0
    else:
        t = mean / se
        p = float(2.0 * stats.t.sf(abs(t), df=n - 1))
    return PairedDifference(mean, se, t, p, n)


@dataclasses.dataclass(frozen=True)
class RankedEntry:
    """One row of a ranking: smaller ``mean`` ranks first."""

    rank: int
    name: str
    mean: float
    error: float
    n: int
    #: Holm-adjusted p of the paired test against the next entry (NaN for the last).
    p_next: float
    #: True when this entry is better than the next one at the chosen level.
    better_than_next: bool


def rank_paired(per_seed: Mapping[str, Sequence[float]], level: float = 0.05) -> list[RankedEntry]:
    """Rank quantities measured on the same seeds (smaller is better).

    Neighbours in the ranking are compared by paired t-tests; their p-values are
    adjusted together by Holm's step-down rule, and an entry is "better than next"
    when its adjusted p is below ``level``.
    """
    if not per_seed:
        raise InputError("per_seed: nothing to rank")
    if not 0.0 < level < 1.0:
        raise InputError(f"level: must lie in (0, 1), got {level}")
    sizes = {len(np.ravel(v)) for v in per_seed.values()}
    if len(sizes) != 1:
        raise InputError(f"per_seed: every entry needs the same seeds, got sizes {sorted(sizes)}")
    means = {k: ensemble_mean(v) for k, v in per_seed.items()}
    order = sorted(per_seed, key=lambda k: means[k].mean)
    raw = [paired_difference(per_seed[order[i + 1]], per_seed[order[i]]).p for i in range(len(order) - 1)]
    adjusted = holm(raw)
    rows = []
    for i, name in enumerate(order):
        p = adjusted[i] if i < len(adjusted) else math.nan
        rows.append(RankedEntry(rank=i + 1, name=name, mean=means[name].mean, error=means[name].error,
                                n=means[name].n, p_next=p, better_than_next=bool(math.isfinite(p) and p < level)))
    return rows


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm (1979) step-down adjusted p-values (NaN entries stay NaN and are not counted)."""
    p = np.asarray(p_values, dtype=float)
    out = np.full(p.shape, math.nan)
    finite = np.flatnonzero(np.isfinite(p))
    m = finite.size
    running = 0.0
    for rank, idx in enumerate(finite[np.argsort(p[finite], kind="stable")]):
        running = max(running, min(1.0, (m - rank) * p[idx]))
        out[idx] = running
    return out.tolist()
