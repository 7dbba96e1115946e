"""Orientation tensors: moments of populations, symmetry, invariants, frames, validation."""
from __future__ import annotations

import numpy as np
import pytest

from pyfold._jax import jax, jnp
from pyfold import tensors as T
from pyfold.errors import InputError


def _unit_vectors(n, d, seed):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, d))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


@pytest.mark.parametrize("d", [2, 3])
def test_moments_of_a_population_are_symmetric_unit_trace_and_consistent(d):
    p = _unit_vectors(200, d, seed=1)
    a2 = np.asarray(T.a2_from_vectors(p))
    a4 = np.asarray(T.a4_from_vectors(p))
    np.testing.assert_allclose(a2, np.einsum("ni,nj->ij", p, p) / len(p), atol=1e-15)
    np.testing.assert_allclose(np.trace(a2), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.einsum("ijkk->ij", a4), a2, atol=1e-14)
    np.testing.assert_allclose(np.asarray(T.symmetrize4(a4)), a4, atol=1e-15)
    T.check_orientation_tensor(a2)


def test_weights_are_normalised_and_equal_weights_reproduce_the_mean():
    p = _unit_vectors(10, 3, seed=2)
    w = np.arange(1.0, 11.0)
    expected = np.einsum("n,ni,nj->ij", w, p, p) / w.sum()
    np.testing.assert_allclose(T.a2_from_vectors(p, w), expected, atol=1e-15)
    np.testing.assert_allclose(T.a4_from_vectors(p, 3.0 * np.ones(10)), T.a4_from_vectors(p), atol=1e-15)
    # batched populations (leading axis) give per-member tensors
    pb = np.stack([p, p[::-1]])
    np.testing.assert_allclose(T.a2_from_vectors(pb)[1], T.a2_from_vectors(p), atol=1e-15)
    with pytest.raises(InputError, match="weights"):
        T.a2_from_vectors(p, np.ones(9))


def test_symmetrize4_is_a_projection_onto_fully_symmetric_tensors():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(3, 3, 3, 3))
    s = np.asarray(T.symmetrize4(x))
    np.testing.assert_allclose(T.symmetrize4(s), s, atol=1e-15)
    for perm in [(1, 0, 2, 3), (2, 1, 0, 3), (0, 1, 3, 2), (3, 2, 1, 0)]:
        np.testing.assert_allclose(np.transpose(s, perm), s, atol=1e-15)
    # a p p p p tensor is already symmetric; a_ij a_kl is not
    a = np.diag([0.5, 0.3, 0.2])
    q = np.einsum("ij,kl->ijkl", a, a)
    assert np.abs(np.asarray(T.symmetrize4(q)) - q).max() > 1e-3


def test_contract4_with_isotropic_a4_gives_the_known_result():
    # a4_iso : D = (2 D + tr(D) I) / 15 in 3-D, (2 D + tr(D) I) / 8 in 2-D
    rng = np.random.default_rng(4)
    for d, den in [(3, 15.0), (2, 8.0)]:
        D = rng.normal(size=(d, d))
        D = D + D.T
        expected = (2 * D + np.trace(D) * np.eye(d)) / den
        np.testing.assert_allclose(T.contract4(T.isotropic_a4(d), D), expected, atol=1e-14)


@pytest.mark.parametrize("d", [2, 3])
def test_isotropic_tensors_equal_the_moments_of_uniform_quadrature(d):
    if d == 2:
        th = 2 * np.pi * np.arange(64) / 64
        p = np.stack([np.cos(th), np.sin(th)], axis=1)
        w = None
    else:
        # Lebedev-free exact rule: Gauss-Legendre in cos(theta) x uniform phi is exact
        # for polynomials of degree 4 with 3 x 5 points.
        x, wx = np.polynomial.legendre.leggauss(3)
        phi = 2 * np.pi * np.arange(5) / 5
        ct, ph = np.meshgrid(x, phi, indexing="ij")
        st = np.sqrt(1 - ct**2)
        p = np.stack([st * np.cos(ph), st * np.sin(ph), ct], axis=-1).reshape(-1, 3)
        w = np.repeat(wx, 5)
    np.testing.assert_allclose(T.a2_from_vectors(p, w), T.isotropic_a2(d), atol=1e-14)
    np.testing.assert_allclose(T.a4_from_vectors(p, w), T.isotropic_a4(d), atol=1e-14)


def test_invariants_match_eigenvalue_formulas():
    a = np.array([[0.5, 0.1, 0.05], [0.1, 0.3, 0.0], [0.05, 0.0, 0.2]])
    lam = np.linalg.eigvalsh(a)
    I, II, III = T.invariants(a)
    np.testing.assert_allclose(I, lam.sum(), atol=1e-15)
    np.testing.assert_allclose(II, lam[0] * lam[1] + lam[1] * lam[2] + lam[0] * lam[2], atol=1e-15)
    np.testing.assert_allclose(III, lam.prod(), atol=1e-15)
    # isotropy: II = 1/3, III = 1/27 (3-D); II = 1/4 (2-D)
    np.testing.assert_allclose(T.invariants(T.isotropic_a2(3))[1:], (1 / 3, 1 / 27), atol=1e-15)
    np.testing.assert_allclose(T.invariants(T.isotropic_a2(2))[1], 0.25, atol=1e-15)


def test_eigen_frame_is_sorted_descending_and_reconstructs_a2():
    a = np.array([[0.2, 0.1, 0.0], [0.1, 0.5, 0.05], [0.0, 0.05, 0.3]])
    vals, vecs = T.eigen_frame(a)
    assert np.all(np.diff(np.asarray(vals)) <= 0)
    np.testing.assert_allclose(vecs @ np.diag(vals) @ vecs.T, a, atol=1e-14)
    np.testing.assert_allclose(vecs.T @ vecs, np.eye(3), atol=1e-14)


def test_eigen_frame_gradient_is_exact_for_distinct_and_finite_for_repeated_eigenvalues():
    a = jnp.array([[0.2, 0.1, 0.0], [0.1, 0.5, 0.05], [0.0, 0.05, 0.3]])

    def f(x):  # depends on the axes, not only the eigenvalues
        vals, vecs = T.eigen_frame(x)
        return jnp.sum(vecs[:, 0] ** 4) + vals[0]

    g = jax.grad(f)(a)
    h = 1e-6
    fd = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            e = np.zeros((3, 3))
            e[i, j] = h
            fd[i, j] = (f(a + e) - f(a - e)) / (2 * h)
    # eigen_frame symmetrises the tangent, so compare symmetric parts
    np.testing.assert_allclose(0.5 * (g + g.T), 0.5 * (fd + fd.T), atol=1e-7)
    for iso in (T.isotropic_a2(3), jnp.diag(jnp.array([0.5, 0.25, 0.25]))):
        assert np.all(np.isfinite(jax.grad(f)(iso)))


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.eye(3), "trace must be 1"),
        (np.array([[0.5, 0.1, 0], [0.0, 0.3, 0], [0, 0, 0.2]]), "symmetric"),
        (np.diag([1.2, -0.1, -0.1]), "positive semi-definite"),
        (np.ones((4, 4)) / 4, "shape"),
        (np.full((3, 3), np.nan), "NaN"),
    ],
)
def test_check_orientation_tensor_names_the_violated_property(bad, match):
    with pytest.raises(InputError, match=match):
        T.check_orientation_tensor(bad, name="a2_0")
    with pytest.raises(InputError, match="a2_0"):
        T.check_orientation_tensor(bad, name="a2_0")


def test_aligned_is_p_p_normalised_and_isotropic_rejects_bad_dim():
    a2 = T.aligned(jnp.array([3.0, 4.0, 0.0]))
    np.testing.assert_allclose(a2, np.outer([0.6, 0.8, 0], [0.6, 0.8, 0]), atol=1e-15)
    np.testing.assert_allclose(np.einsum("ijkk->ij", T.aligned_a4(jnp.array([1.0, 2.0]))), T.aligned(jnp.array([1.0, 2.0])), atol=1e-15)
    with pytest.raises(InputError, match="dim"):
        T.isotropic_a4(4)
