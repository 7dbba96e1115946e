"""Ensemble statistics (pyfold.ensemble), the C_I correlations (pyfold.correlations) and the
contacts-only scene builder (pyfold.scene.sheared_fibres), against independent computations."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from pyfold.correlations import (
    CORRELATIONS, FOLGAR_TUCKER_1984, PUBLISHED_RANGE, bay_1991, correlations_at, n_l2d, phan_thien_2002,
    phi_beta, volume_fraction,
)
from pyfold.ensemble import ensemble_mean, holm, paired_difference, rank_paired
from pyfold.errors import InputError
from pyfold.scene import parse_scene
from pyfold.scene.registry import DEFAULT_ALPHA_OVER_RADIUS
from pyfold.scene.shapes import interaction_range
from pyfold.scene.sheared_fibres import sheared_fibres

EPS = np.finfo(float).eps


def test_ensemble_mean_matches_its_definition():
    rng = np.random.default_rng(3)
    v, s = rng.normal(size=7), rng.uniform(0.1, 0.2, size=7)
    m = ensemble_mean(v, s)
    assert m.n == 7
    assert m.mean == pytest.approx(np.sum(v) / 7, rel=16 * EPS, abs=16 * EPS)
    assert m.stderr_across == pytest.approx(np.sqrt(np.sum((v - v.mean()) ** 2) / 6 / 7), rel=1e-13)
    assert m.stderr_pooled == pytest.approx(np.sqrt(np.sum(s ** 2)) / 7, rel=1e-13)
    assert m.error == max(m.stderr_across, m.stderr_pooled)


def test_ensemble_mean_of_one_seed_quotes_the_within_run_error():
    m = ensemble_mean([2.0], [0.3])
    assert math.isnan(m.stderr_across) and m.error == 0.3


def test_ensemble_mean_refuses_bad_input():
    with pytest.raises(InputError, match="values"):
        ensemble_mean([1.0, math.nan])
    with pytest.raises(InputError, match="empty"):
        ensemble_mean([])
    with pytest.raises(InputError, match="stderrs"):
        ensemble_mean([1.0, 2.0], [0.1])


def test_paired_difference_is_scipys_paired_t_test():
    rng = np.random.default_rng(5)
    a = rng.normal(size=6)
    b = a + 0.3 + 0.2 * rng.normal(size=6)
    d = paired_difference(a, b)
    ref = stats.ttest_rel(a, b)
    assert d.t == pytest.approx(ref.statistic, rel=1e-12)
    assert d.p == pytest.approx(ref.pvalue, rel=1e-9)
    assert d.mean == pytest.approx(np.mean(a - b), rel=1e-14)


def test_holm_step_down():
    # Holm (1979): sort p, multiply the k-th smallest by (m - k), keep monotone, cap at 1.
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])
    out = holm([0.02, math.nan, 0.01])
    assert out[0] == pytest.approx(0.02) and math.isnan(out[1]) and out[2] == pytest.approx(0.02)


def test_rank_paired_orders_and_separates_only_what_the_seeds_support():
    rng = np.random.default_rng(11)
    base = rng.normal(size=8)
    per_seed = {
        "good": 1.0 + 0.01 * base,
        "bad": 2.0 + 0.01 * base + 0.01 * rng.normal(size=8),  # far worse, paired noise small
        "as_bad": 2.0 + 0.01 * base + 0.01 * rng.normal(size=8),  # same law as "bad"
    }
    rows = rank_paired(per_seed)
    assert [r.name for r in rows][0] == "good"
    assert rows[0].better_than_next and rows[0].p_next < 1e-6
    assert not rows[1].better_than_next  # two draws of one law: no significant difference expected
    assert math.isnan(rows[2].p_next)
    with pytest.raises(InputError, match="same seeds"):
        rank_paired({"a": [1.0, 2.0], "b": [1.0]})


def test_correlations_as_published():
    # Values at phi beta = 0 and far away follow from the formulas' constants.
    assert bay_1991(0.0) == pytest.approx(0.0184)
    assert phan_thien_2002(0.0) == 0.0
    assert phan_thien_2002(1e3) == pytest.approx(0.03)
    # docs/physics.md#c_i-correlations: the two cross near phi beta = 1.27, C_I = 0.0074.
    x = np.linspace(1.0, 1.6, 60001)
    cross = x[np.argmin(np.abs(bay_1991(x) - phan_thien_2002(x)))]
    assert cross == pytest.approx(1.27, abs=0.01)
    assert bay_1991(cross) == pytest.approx(0.0074, abs=1e-4)
    assert set(correlations_at(1.0)) == set(CORRELATIONS)
    lo, hi = PUBLISHED_RANGE
    assert all(lo <= p.ci <= hi for p in FOLGAR_TUCKER_1984)


def test_concentration_measures_of_a_fibre_population():
    beta, count, side, length = 10.0, 320, 2.4, 1.0
    d = length / beta
    n_l3 = count / side ** 3
    phi = count * math.pi * d * d / 4.0 * length / side ** 3  # cylinders, counted directly
    assert volume_fraction(n_l3, beta) == pytest.approx(phi, rel=1e-14)
    assert phi_beta(n_l3, beta) == pytest.approx(phi * beta, rel=1e-14)
    assert n_l2d(n_l3, beta) == pytest.approx(count * length ** 2 * d / side ** 3, rel=1e-14)


@pytest.mark.parametrize("beta,n_l3", [(5.0, 15.0), (10.0, 30.0), (20.0, 60.0), (10.0, 1.0)])
def test_sheared_fibres_scene_is_valid_and_sized_by_its_rules(beta, n_l3):
    s = sheared_fibres(beta, n_l3, seed=3, t_end=2.0)
    resolved = parse_scene(s.toml, source="sheared_fibres")
    assert resolved.hydrodynamics == "jeffery" and resolved.collisions == "strategy"
    fam = resolved.families[0]
    assert fam.count == s.count
    assert s.n_l3 == pytest.approx(s.count / s.side ** 3, rel=1e-14)
    assert abs(s.n_l3 - n_l3) <= 0.5 / s.side ** 3 + 1e-12  # rounding to a whole fibre
    rc = interaction_range([("fibre", 0.5 / beta, 1.0)], s.alpha)
    assert s.side > 2 * rc and (s.side - 0.1 <= 2 * rc or s.side == pytest.approx(2.2))  # smallest 0.1 step
    # the scene default of model.alpha (a tenth of the radius, pyfold/scene/registry.py) in diameters
    assert s.alpha == pytest.approx(DEFAULT_ALPHA_OVER_RADIUS * 0.5 / beta, rel=1e-12)
    assert 0.5 * 1.0 * s.dt <= 0.5 * s.alpha * (1 + 1e-12)  # a tip moves at most alpha/2 per step
    assert resolved.t_end == pytest.approx(2.0)


def test_sheared_fibres_refuses_bad_arguments():
    with pytest.raises(InputError, match="beta"):
        sheared_fibres(0.5, 1.0, 1, 1.0)
    with pytest.raises(InputError, match="collisions"):
        sheared_fibres(10, 1.0, 1, 1.0, collisions="maybe")
