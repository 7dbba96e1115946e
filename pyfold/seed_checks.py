"""Per-seed fits that must not hide in an average, and closure rankings with effect sizes.

:func:`flag_fits`: a fitted C_I on its parameter bound is not a measurement, only
a bound (the optimum lies at or beyond it), so it is excluded from the ensemble mean
and listed; a seed whose value lies outside the prediction interval of the other
seeds (they disagree beyond their scatter) is kept and listed with its value.

:func:`equivalence`: a ranking of closures by a paired test says whether two errors
differ, not by how much; with a few seeds a difference of 0.05 % of the error can be
"significant". Beside the p-value the report gives the paired difference (the effect
size, also relative to the better closure's error and standardised, d_z = mean / sd)
and an equivalence verdict by two one-sided tests (Schuirmann 1987): the (1 - 2 level)
confidence interval of the difference inside +-:data:`EQUIVALENCE_MARGIN` = equivalent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: Equivalence margin of two closures' a4:D errors (the relative error
#: ||(closure(a2) - a4):D|| / ||a4:D||, so 0.01 is 1 % of ||a4:D||). The closure enters
#: Folgar-Tucker only through the term 2 xi a4:D, so two closures whose errors differ by
#: less than 1 % of ||a4:D|| give flow terms within 1 % of each other: below the a2 RMS
#: misfit of every trajectory fit of C_I the reports show (2-7 % in the default scene) and
#: below what the fitted C_I can resolve, so choosing between them cannot matter.
EQUIVALENCE_MARGIN = 0.01

#: Flag values of :func:`flag_fits` (also the ``..._flag`` variables of results.nc).
FLAG_OK, FLAG_LOWER_BOUND, FLAG_UPPER_BOUND, FLAG_OUTLIER, FLAG_FAILED = 0, 1, 2, 3, 4
FLAG_MEANINGS = "0 kept, 1 on the lower bound (excluded), 2 on the upper bound (excluded), 3 outside the other seeds' " \
                "95 % prediction interval (kept, listed), 4 no value: the fit failed (excluded)"


@dataclass(frozen=True)
class SeedFlags:
    """Verdict on per-seed fitted values."""

    values: tuple[float, ...]
    flags: tuple[int, ...]

    @property
    def kept(self) -> list[float]:
        return [v for v, f in zip(self.values, self.flags) if f in (FLAG_OK, FLAG_OUTLIER)]

    def describe(self, seeds: Sequence[int], bounds: tuple[float, float]) -> list[str]:
        """One text per flagged seed."""
        words = {FLAG_LOWER_BOUND: f"on the bound C_I = {bounds[0]:g} (excluded from the mean)",
                 FLAG_UPPER_BOUND: f"on the bound C_I = {bounds[1]:g} (excluded from the mean)",
                 FLAG_OUTLIER: "outside the other seeds' 95 % prediction interval (kept)",
                 FLAG_FAILED: "the fit failed (excluded from the mean)"}
        return [f"seed {s}: {v:.3g} {words[f]}" for s, v, f in zip(seeds, self.values, self.flags) if f != FLAG_OK]


def flag_fits(values: Sequence[float], lower: float, upper: float, lower_tol: float, upper_tol: float,
              level: float = 0.05) -> SeedFlags:
    """Flag per-seed fitted values: within ``lower_tol`` of ``lower`` or ``upper_tol`` of
    ``upper`` (the optimiser's resolution there), and, among the others when at least
    three remain, a value outside the ``1 - level`` prediction interval of the remaining
    ones, ``mean +- t_{m-2} s sqrt(1 + 1/(m-1))`` (m values, leave-one-out). A
    non-finite value (a failed fit reports NaN) is flagged failed."""
    from scipy import stats

    v = np.asarray(values, dtype=float)
    flags = np.full(v.size, FLAG_OK, dtype=int)
    flags[v <= lower + lower_tol] = FLAG_LOWER_BOUND
    flags[v >= upper - upper_tol] = FLAG_UPPER_BOUND
    flags[~np.isfinite(v)] = FLAG_FAILED
    inside = np.flatnonzero(flags == FLAG_OK)
    m = inside.size
    if m >= 3:
        q = float(stats.t.ppf(1.0 - level / 2.0, m - 2))
        for k in inside:
            others = v[[i for i in inside if i != k]]
            s = float(np.std(others, ddof=1))
            if s > 0.0 and abs(v[k] - float(np.mean(others))) > q * s * math.sqrt(1.0 + 1.0 / (m - 1)):
                flags[k] = FLAG_OUTLIER
    return SeedFlags(values=tuple(float(x) for x in v), flags=tuple(int(f) for f in flags))


@dataclass(frozen=True)
class Equivalence:
    """Paired difference ``b - a`` of two closures' errors, with its equivalence verdict."""

    difference: float  # mean of b - a (a ranked before b)
    low: float  # (1 - 2 level) confidence interval of the difference
    high: float
    relative: float  # difference / error of a
    d_z: float  # standardised effect size: mean / sd of the paired differences (NaN for one run)
    margin: float
    verdict: str  # "equivalent", "different", "inconclusive"

    def text(self) -> str:
        dz = f", d_z = {self.d_z:.2g}" if math.isfinite(self.d_z) else ""
        return (f"difference {self.difference:.1e} ({100.0 * self.relative:.2g} % of the error{dz}; "
                f"{self.low:.1e} to {self.high:.1e}): "
                + {"equivalent": f"equivalent within +-{self.margin:g}",
                   "different": f"different beyond +-{self.margin:g}"}.get(self.verdict,
                                                                          f"inconclusive at +-{self.margin:g}"))


def equivalence(mean_a: float, differences: Sequence[float] | None = None, stderr: float | None = None,
                mean_difference: float | None = None, margin: float = EQUIVALENCE_MARGIN,
                level: float = 0.05) -> Equivalence:
    """Two one-sided tests of ``|difference| < margin``.

    Either ``differences`` (the paired per-seed differences: t with n - 1 degrees of
    freedom) or ``mean_difference`` and its ``stderr`` (one run: normal approximation).
    Verdict: ``equivalent`` when the (1 - 2 level) interval lies inside +-margin,
    ``different`` when it lies wholly outside, ``inconclusive`` otherwise.
    """
    from scipy import stats

    if differences is not None:
        d = np.asarray(differences, dtype=float)
        n = d.size
        mean = float(np.mean(d))
        sd = float(np.std(d, ddof=1)) if n > 1 else math.nan
        se = sd / math.sqrt(n) if n > 1 else math.nan
        q = float(stats.t.ppf(1.0 - level, n - 1)) if n > 1 else math.nan
        d_z = mean / sd if n > 1 and sd > 0.0 else math.nan
    else:
        mean, se, d_z = float(mean_difference), float(stderr), math.nan
        q = float(stats.norm.ppf(1.0 - level))
    low, high = (mean - q * se, mean + q * se) if math.isfinite(se) else (math.nan, math.nan)
    if not math.isfinite(low):
        verdict = "inconclusive"
    elif -margin < low and high < margin:
        verdict = "equivalent"
    elif low >= margin or high <= -margin:
        verdict = "different"
    else:
        verdict = "inconclusive"
    relative = mean / mean_a if mean_a else math.nan
    return Equivalence(difference=mean, low=low, high=high, relative=relative, d_z=d_z, margin=margin,
                       verdict=verdict)


@dataclass(frozen=True)
class Consistency:
    """Whether per-seed values agree within their own standard errors."""

    chi2: float  # sum ((x_k - weighted mean) / se_k)^2
    dof: int
    p: float

    @property
    def disagree(self) -> bool:
        return math.isfinite(self.p) and self.p < 0.05


def consistency(values: Sequence[float], stderrs: Sequence[float]) -> Consistency:
    """Chi-square test of per-seed values ``x_k +- se_k`` against one common value (their
    inverse-variance weighted mean), ``n - 1`` degrees of freedom; NaN for fewer than two
    seeds or a standard error that is not positive and finite."""
    from scipy import stats

    x = np.asarray(values, dtype=float)
    se = np.asarray(stderrs, dtype=float)
    if x.size < 2 or not np.all(np.isfinite(se) & (se > 0.0)) or not np.all(np.isfinite(x)):
        return Consistency(math.nan, max(x.size - 1, 0), math.nan)
    w = 1.0 / se**2
    mean = float(np.sum(w * x) / np.sum(w))
    chi2 = float(np.sum(((x - mean) / se) ** 2))
    return Consistency(chi2, x.size - 1, float(stats.chi2.sf(chi2, x.size - 1)))
