"""Fortran orientation moments (fold_orientation_stats) against numpy and exact values."""
import itertools

import numpy as np
import pytest

from pyfold.errors import InputError
from pyfold.native.stats import orientation_moments, orientation_moments_series


def random_unit_vectors(n, dim, seed):
    p = np.random.default_rng(seed).normal(size=(n, dim))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def icosahedron_axes():
    """The 6 axes of the icosahedron: a spherical 5-design, so averages of any
    polynomial of degree <= 5 over them equal the isotropic sphere average."""
    g = (1 + np.sqrt(5)) / 2
    v = np.array([[0, 1, g], [0, -1, g], [1, g, 0], [-1, g, 0], [g, 0, 1], [-g, 0, 1]], float)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def isotropic_a4(dim):
    delta = np.eye(dim)
    a4 = (np.einsum("ij,kl->ijkl", delta, delta) + np.einsum("ik,jl->ijkl", delta, delta)
          + np.einsum("il,jk->ijkl", delta, delta))
    return a4 / (dim * (dim + 2))


@pytest.mark.parametrize("dim", [2, 3])
def test_moments_match_einsum_on_random_weighted_population(dim):
    p = random_unit_vectors(500, dim, seed=dim)
    w = np.random.default_rng(7).uniform(0.5, 2.0, size=500)
    a2, a4 = orientation_moments(p, w)
    np.testing.assert_allclose(a2, np.einsum("n,ni,nj->ij", w, p, p) / w.sum(), atol=1e-14)
    np.testing.assert_allclose(a4, np.einsum("n,ni,nj,nk,nl->ijkl", w, p, p, p, p) / w.sum(), atol=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_a4_is_fully_symmetric_and_contracts_to_a2(dim):
    p = random_unit_vectors(200, dim, seed=11)
    a2, a4 = orientation_moments(p)
    for perm in itertools.permutations(range(4)):
        assert np.array_equal(a4, np.transpose(a4, perm))
    np.testing.assert_allclose(np.einsum("ijkk->ij", a4), a2, atol=1e-14)
    assert np.trace(a2) == pytest.approx(1.0, abs=1e-14)
    assert np.einsum("iijj->", a4) == pytest.approx(1.0, abs=1e-14)


def test_isotropic_values_are_exact_for_a_spherical_design():
    a2, a4 = orientation_moments(icosahedron_axes())
    np.testing.assert_allclose(a2, np.eye(3) / 3, atol=1e-15)
    np.testing.assert_allclose(a4, isotropic_a4(3), atol=1e-15)


def test_planar_isotropic_values_are_exact_for_equally_spaced_angles():
    theta = np.pi * np.arange(5) / 5
    a2, a4 = orientation_moments(np.column_stack([np.cos(theta), np.sin(theta)]))
    np.testing.assert_allclose(a2, np.eye(2) / 2, atol=1e-15)
    np.testing.assert_allclose(a4, isotropic_a4(2), atol=1e-15)


def test_series_equals_snapshot_by_snapshot():
    p = np.stack([random_unit_vectors(64, 3, seed=s) for s in range(4)])
    a2s, a4s = orientation_moments_series(p)
    for t in range(4):
        a2, a4 = orientation_moments(p[t])
        np.testing.assert_array_equal(a2s[t], a2)
        np.testing.assert_array_equal(a4s[t], a4)


@pytest.mark.parametrize(
    "p, weights, fragment",
    [
        (np.zeros((0, 3)), None, "p: expected shape"),
        (np.zeros((3, 4)), None, "p: expected shape"),
        (np.ones((3, 3)), [1.0, -1.0, 1.0], "weights must be >= 0"),
        (np.ones((3, 3)), [0.0, 0.0, 0.0], "sum of weights must be > 0"),
        (np.ones((3, 3)), [1.0, 1.0], "weights: expected shape"),
        (np.full((2, 3), np.nan), None, "NaN"),
    ],
)
def test_bad_input_raises_input_error_with_reason(p, weights, fragment):
    with pytest.raises(Exception, match=fragment) as info:
        orientation_moments(p, weights)
    assert isinstance(info.value, (InputError, ArithmeticError))
