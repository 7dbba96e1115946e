"""pyfold.seed_checks: per-seed fits on a bound or outside the others' scatter are flagged,
and the equivalence verdict of a paired difference follows two one-sided t tests."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from pyfold.fast_fit import fit_flags
from pyfold.seed_checks import (EQUIVALENCE_MARGIN, FLAG_FAILED, FLAG_LOWER_BOUND, FLAG_OK, FLAG_OUTLIER,
                                FLAG_UPPER_BOUND, equivalence, flag_fits)


def _fits(values, success=None):
    """Stand-ins for pyfold.fast_fit.FastFit: the fields fit_flags reads."""
    success = success or [True] * len(values)
    return [SimpleNamespace(ci=v, success=s) for v, s in zip(values, success)]


def test_a_fit_on_its_bound_is_excluded_and_named():
    """The hybrid closure of the default scene: 0.019, 0.025, 0.021 and one fit at C_I = 0."""
    flags = fit_flags(_fits([0.019, 0.025, 0.021, 0.0]))
    assert flags.flags == (FLAG_OK, FLAG_OK, FLAG_OK, FLAG_LOWER_BOUND)
    assert flags.kept == [0.019, 0.025, 0.021]
    text = flags.describe([1, 2, 3, 4], (0.0, math.inf))
    assert text == ["seed 4: 0 on the bound C_I = 0 (excluded from the mean)"]


def test_only_the_projected_bound_is_a_bound_and_a_failed_fit_is_excluded():
    """fit_ci_rk4 projects its steps onto C_I >= 0, so on the bound it returns exactly 0: any
    positive value, however small, is a measurement; there is no upper bound. A fit that did
    not succeed (NaN, or not converged) is flagged failed and excluded."""
    flags = fit_flags(_fits([0.0, 1e-12, 1e3, math.nan, 2e-3], success=[True, True, True, False, False]))
    assert flags.flags[:3] == (FLAG_LOWER_BOUND, FLAG_OK, FLAG_OK)
    assert flags.flags[3:] == (FLAG_FAILED, FLAG_FAILED)
    assert flags.kept == [1e-12, 1e3]
    assert flags.describe([1, 2, 3, 4, 5], (0.0, math.inf))[1:] == [
        "seed 4: nan the fit failed (excluded from the mean)", "seed 5: nan the fit failed (excluded from the mean)"]
    assert FLAG_UPPER_BOUND not in flags.flags


def test_a_seed_outside_the_others_prediction_interval_is_flagged_and_kept():
    values = [1.0, 1.1, 0.9, 1.05, 5.0]
    flags = flag_fits(values, 0.0, 100.0, 0.0, 0.0)
    assert flags.flags == (FLAG_OK,) * 4 + (FLAG_OUTLIER,)
    assert flags.kept == values  # shown, not dropped
    # the interval itself: the others' mean +- t_{m-2} s sqrt(1 + 1/(m-1)), m = 5
    others = np.array(values[:4])
    half = stats.t.ppf(0.975, 3) * others.std(ddof=1) * math.sqrt(1 + 1 / 4)
    inside = others.mean() + 0.99 * half
    assert flag_fits([*values[:4], inside], 0.0, 100.0, 0.0, 0.0).flags[-1] == FLAG_OK
    assert flag_fits([*values[:4], others.mean() + 1.01 * half], 0.0, 100.0, 0.0, 0.0).flags[-1] == FLAG_OUTLIER


def test_tost_interval_and_verdicts():
    """d = a -+ delta alternating (n = 4): mean a, sd = delta sqrt(4/3), the 90 % interval
    a -+ t_{0.95,3} sd / 2."""
    a, delta = 4.2e-4, 2e-4
    d = [a - delta, a + delta, a - delta, a + delta]
    eq = equivalence(0.205, d)
    half = stats.t.ppf(0.95, 3) * delta * math.sqrt(4 / 3) / 2
    assert eq.difference == pytest.approx(a, rel=1e-12)
    assert eq.low == pytest.approx(a - half, rel=1e-12) and eq.high == pytest.approx(a + half, rel=1e-12)
    assert eq.d_z == pytest.approx(a / (delta * math.sqrt(4 / 3)), rel=1e-12)
    assert eq.relative == pytest.approx(a / 0.205, rel=1e-12)
    assert eq.verdict == "equivalent" and eq.margin == EQUIVALENCE_MARGIN
    far = [0.08 - 0.01, 0.08 + 0.01, 0.08 - 0.01, 0.08 + 0.01]
    assert equivalence(0.205, far).verdict == "different"
    near = [EQUIVALENCE_MARGIN - 0.02, EQUIVALENCE_MARGIN + 0.02] * 2
    assert equivalence(0.205, near).verdict == "inconclusive"
    # one run: normal quantile with the given standard error
    one = equivalence(0.2, mean_difference=1e-3, stderr=1e-3)
    assert one.low == pytest.approx(1e-3 - stats.norm.ppf(0.95) * 1e-3, rel=1e-12) and one.verdict == "equivalent"


def test_consistency_is_a_chi_square_about_the_weighted_mean():
    from pyfold.seed_checks import consistency

    x, se = [1.0, 2.0, 3.0], [1.0, 1.0, 2.0]
    w = np.array([1.0, 1.0, 0.25])
    mean = float(np.sum(w * x) / np.sum(w))
    chi2 = float(np.sum(w * (np.array(x) - mean) ** 2))
    got = consistency(x, se)
    assert got.chi2 == pytest.approx(chi2, rel=1e-12) and got.dof == 2
    assert got.p == pytest.approx(stats.chi2.sf(chi2, 2), rel=1e-12) and not got.disagree
    assert consistency([0.0, 10.0], [1.0, 1.0]).disagree  # 7 standard errors apart
    assert math.isnan(consistency([1.0], [0.1]).p)
