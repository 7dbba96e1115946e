"""Jeffery's equation: exact single-fibre orbits and the exact isotropic-start a2."""
import numpy as np
import pytest
from scipy.optimize import brentq

from pyfold._jax import jnp
from pyfold.errors import InputError
from pyfold.kinematics import aspect_ratio_to_xi, simple_shear
from pyfold.models import Jeffery, FolgarTucker, jeffery_vectors


def test_single_fibre_period_in_shear_matches_jeffery_orbit_period():
    # T = (2 pi / gamma_dot)(beta + 1/beta), measured from the solution: successive
    # downward zero crossings of p_x (one full turn of p; pp repeats after T for an
    # out-of-plane orbit), each refined by Brent root finding on the exact solution.
    beta, gd = 5.0, 2.0
    xi = float(aspect_ratio_to_xi(beta))
    L = simple_shear(gd)
    p0 = np.array([[0.6, 0.0, 0.8]])
    T_exact = 2 * np.pi / gd * (beta + 1 / beta)

    def px(t):
        return float(jeffery_vectors(p0, L, np.array([0.0, t]), xi)[1, 0, 0])

    t = np.linspace(1e-3, 2.2 * T_exact, 63)
    p = np.asarray(jeffery_vectors(p0, L, np.concatenate([[0.0], t]), xi))[1:, 0, :]
    down = np.nonzero((p[:-1, 0] > 0) & (p[1:, 0] <= 0))[0]
    assert len(down) >= 2
    roots = [brentq(px, t[k], t[k + 1], xtol=1e-14, rtol=1e-15) for k in down[:2]]
    assert (roots[1] - roots[0]) / T_exact - 1.0 == pytest.approx(0.0, abs=1e-6)
    # |p| = 1 exactly and p itself returns after one period (not after T/2 off-plane)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), 1.0, atol=1e-14)
    back = np.asarray(jeffery_vectors(p0, L, np.array([0.0, T_exact / 2, T_exact]), xi))[:, 0]
    np.testing.assert_allclose(back[2], p0[0], atol=1e-10)
    assert back[1][2] == pytest.approx(p0[0, 2], abs=1e-10) and back[1][0] == pytest.approx(-p0[0, 0], abs=1e-10)


def test_time_dependent_gradient_follows_the_exact_propagator():
    # L(t) = cos(t) L0 has the exact propagator B = expm(sin(t) (W0 + xi D0)).
    L0 = simple_shear(1.0)
    xi = 0.8
    rng = np.random.default_rng(1)
    p0 = rng.normal(size=(7, 3))
    t = np.linspace(0.0, 4.0, 9)
    osc = jeffery_vectors(p0, lambda s: jnp.cos(s) * L0, t, xi)
    exact = np.stack([np.asarray(jeffery_vectors(p0, np.sin(s) * np.asarray(L0), [0.0, 1.0], xi)[1]) for s in t])
    np.testing.assert_allclose(osc, exact, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(osc, axis=-1), 1.0, atol=1e-14)


def sphere_quadrature(n_theta, n_phi):
    """Gauss-Legendre in cos(theta) x trapezoid in phi (spectral for smooth periodic data)."""
    mu, w_mu = np.polynomial.legendre.leggauss(n_theta)
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    s = np.sqrt(1 - mu**2)
    p = np.stack(np.broadcast_arrays(s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), mu[:, None] + 0 * phi), -1)
    w = np.broadcast_to(w_mu[:, None] / (2 * n_phi), p.shape[:2])
    return p.reshape(-1, 3), w.reshape(-1)


def test_jeffery_from_isotropy_matches_published_exact_a2():
    # docs/physics.md#exact-jeffery-solution-from-isotropy:
    # lambda = 1, shear, t = 10 -> a11 = 0.89963802, a12 = 0.08882965
    # (exact solution, sample free: the isotropic population is a sphere quadrature).
    # 640 x 1280 nodes: the quadrature is converged to ~2e-9 (1280 x 2560 differs by 1.7e-9)
    p0, w = sphere_quadrature(640, 1280)
    p = np.asarray(jeffery_vectors(p0, simple_shear(1.0), np.array([0.0, 10.0]), 1.0))[1]
    a2 = np.einsum("n,ni,nj->ij", w, p, p)
    assert a2[0, 0] == pytest.approx(0.89963802, abs=2e-8)
    assert a2[0, 1] == pytest.approx(0.08882965, abs=2e-8)
    assert np.trace(a2) == pytest.approx(1.0, abs=1e-13)


def test_jeffery_tensor_model_is_folgar_tucker_without_interaction():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(30, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    a2 = p.T @ p / len(p)
    L = np.asarray(simple_shear(1.0)) + np.diag([0.3, -0.1, -0.2])
    for closure in ("quadratic", "hybrid"):
        np.testing.assert_allclose(
            Jeffery(xi=0.9, closure=closure).rate(0.0, a2, L),
            FolgarTucker(ci=0.0, xi=0.9, closure=closure).rate(0.0, a2, L),
            atol=1e-16,
        )


def test_jeffery_vectors_validates_input():
    with pytest.raises(InputError, match="p0"):
        jeffery_vectors(np.zeros((2, 3)), simple_shear(1.0), [0.0, 1.0], 1.0)
    with pytest.raises(InputError, match="t_eval"):
        jeffery_vectors(np.ones((2, 3)), simple_shear(1.0), [1.0, 0.0], 1.0)
    with pytest.raises(InputError, match="xi"):
        jeffery_vectors(np.ones((2, 3)), simple_shear(1.0), [0.0, 1.0], 1.5)
