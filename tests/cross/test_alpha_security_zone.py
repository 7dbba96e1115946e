"""The security-zone study (studies/alpha_influence/alpha_influence.py): its scenes and its trend statistics.

Checks that the study's scenes change only alpha (fixed series) or alpha and dt together
by the rule dt = alpha/(rate L) (rule series), that the scene schema accepts every
alpha/d of the study and refuses alpha above the fibre radius, and that the trend
estimators reproduce textbook least squares.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from pyfold.errors import InputError
from pyfold.scene import parse_scene
from pyfold.scene.sheared_fibres import sheared_fibres

from study_import import import_study  # helper module next to this file

#: Round-off bound of a 2x2 normal-equation solve on O(1) data: a few hundred ulps.
RTOL = 1e3 * np.finfo(float).eps


@pytest.fixture(scope="module")
def study():
    return import_study("alpha_influence", "alpha_influence")


def test_fixed_series_changes_only_alpha_and_rule_series_couples_dt(study):
    form = study.SMALL
    d = 1.0 / study.BETA
    fixed = [study.scene_of("fixed_dt", a, 1, form, 1.0) for a in form.alphas_over_d]
    rule = [study.scene_of("rule_dt", a, 1, form, 1.0) for a in form.alphas_over_d]
    assert {s.dt for s in fixed} == {study.fixed_dt(form)}
    # the fixed dt obeys the tip rule (tip moves rate L dt / 2 <= alpha / 2) for the smallest alpha, hence all
    assert study.fixed_dt(form) <= min(form.alphas_over_d) * d * (1 + RTOL)
    for a, f, r in zip(form.alphas_over_d, fixed, rule):
        assert f.alpha == pytest.approx(a * d, rel=RTOL)
        assert r.dt == pytest.approx(a * d, rel=RTOL)
        # everything but alpha and dt is the same scene
        assert (f.count, f.side, f.seed) == (r.count, r.side, r.seed) == (fixed[0].count, fixed[0].side, 1)


def test_stokes_twin_keeps_cell_and_fibre_count_across_alpha(study):
    # sheared_fibres sizes the cell from the interaction range, which grows with alpha
    # (beta = 5: side 2.7 at alpha/d = 0.05, 2.8 at 0.2); the study fixes the largest side
    form = study.SMALL
    scenes = [study.stokes_scene_of(a, 1, form) for a in form.stokes_alphas_over_d]
    assert len({(s.side, s.count, s.dt) for s in scenes}) == 1
    assert sheared_fibres(study.STOKES_BETA, study.STOKES_N_L3, 1, 1.0, alpha_over_d=0.05).side < scenes[0].side


def test_schema_accepts_the_study_alphas_and_refuses_alpha_above_the_radius(study):
    form = study.SMALL
    for a in (min(form.alphas_over_d), max(form.alphas_over_d)):
        resolved = parse_scene(study.scene_of("fixed_dt", a, 1, form, 1.0).toml)
        assert resolved.alpha == pytest.approx(a / study.BETA, rel=RTOL)
    # normalise: 0 <= alpha <= smallest radius, i.e. alpha/d <= 0.5
    with pytest.raises(InputError, match="model.alpha"):
        parse_scene(sheared_fibres(study.BETA, study.N_L3, 1, 1.0, alpha_over_d=0.6).toml)


def test_weighted_slope_with_equal_errors_is_ordinary_least_squares(study):
    # With equal weights and chi^2/dof >= 1 the scaled WLS covariance is the OLS one,
    # so slope, s.e. and p equal scipy.stats.linregress's (same algebra, round-off only).
    rng = np.random.default_rng(7)
    x = np.array([0.01, 0.02, 0.05, 0.1, 0.2])
    y = 3e-3 - 2e-3 * x + 1e-3 * rng.standard_normal(x.size)
    ref = stats.linregress(x, y)
    got = study.wls_slope(x, y, np.full(x.size, 1e-5))  # tiny errors: chi^2/dof >> 1, scaled to the residuals
    assert got["chi2_dof"] > 1
    np.testing.assert_allclose([got["slope"], got["slope_se"], got["p"]], [ref.slope, ref.stderr, ref.pvalue],
                               rtol=1e6 * np.finfo(float).eps)


def test_weighted_slope_is_exact_on_a_line_and_honours_the_given_errors(study):
    # Exact line: residual 0, so chi^2/dof < 1 and the covariance is the given errors' own:
    # s.e. of the slope = sigma / sqrt(sum (x - xbar)^2) for equal sigma.
    x = np.array([0.01, 0.02, 0.05, 0.1, 0.2])
    sigma = 1e-4
    got = study.wls_slope(x, 1.0 + 0.5 * x, np.full(x.size, sigma))
    assert got["slope"] == pytest.approx(0.5, rel=RTOL)
    assert got["slope_se"] == pytest.approx(sigma / np.sqrt(np.sum((x - x.mean()) ** 2)), rel=RTOL)
    # two-sided Student t with n - 2 = 3 dof
    assert got["p"] == pytest.approx(2 * stats.t.sf(got["slope"] / got["slope_se"], x.size - 2), rel=RTOL)


def test_paired_slope_is_the_mean_of_per_seed_slopes(study):
    x = np.array([0.01, 0.02, 0.05, 0.1, 0.2])
    slopes = np.array([1.0, 2.0, 4.0])
    per_seed = slopes[:, None] * x[None, :] + np.array([0.1, -0.3, 0.2])[:, None]
    got = study.paired_slope(x, per_seed)
    assert got["slope"] == pytest.approx(slopes.mean(), rel=RTOL)
    assert got["slope_se"] == pytest.approx(slopes.std(ddof=1) / np.sqrt(3), rel=1e4 * np.finfo(float).eps)
    # minimum detectable slope: (t_0.975 + t_0.8) s.e. with n - 1 dof
    assert got["mde"] == pytest.approx((stats.t.ppf(0.975, 2) + stats.t.ppf(0.8, 2)) * got["slope_se"], rel=RTOL)
