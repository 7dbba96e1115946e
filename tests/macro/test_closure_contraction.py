"""Closed-form contractions a4:B (pyfold.closures.CONTRACTIONS) equal the contracted a4."""
import numpy as np
import pytest

from pyfold._jax import jax, jnp
from pyfold.closures import CONTRACTIONS, TabulatedA4, get_closure, resolve_contraction
from pyfold.tensors import isotropic_a4


def random_states(n, dim, seed):
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(n, dim, dim))
    a = np.einsum("nij,nkj->nik", m, m)
    a = a / np.trace(a, axis1=1, axis2=2)[:, None, None]
    # include the exactly isotropic and the exactly aligned states
    a[0] = np.eye(dim) / dim
    a[1] = 0.0
    a[1, 0, 0] = 1.0
    return jnp.asarray(a)


@pytest.mark.parametrize("name, dim", [(n, d) for n, impl in CONTRACTIONS.items() for d in impl])
def test_closed_form_contraction_equals_contracted_a4(name, dim):
    a2 = random_states(16, dim, seed=dim)
    rng = np.random.default_rng(5)
    B = rng.normal(size=(dim, dim))
    B = B + B.T
    fast = jax.jit(jax.vmap(lambda a: resolve_contraction(name)(a, jnp.asarray(B))))(a2)
    slow = np.einsum("nijkl,kl->nij", np.asarray(jax.vmap(get_closure(name, dim))(a2)), B)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-13)


def test_contraction_of_tabulated_and_plain_callables_uses_the_a4():
    B = jnp.diag(jnp.array([1.0, -0.5, -0.5]))
    table = TabulatedA4(jnp.array([0.0, 1.0]), jnp.stack([isotropic_a4(3), isotropic_a4(3)]))
    expected = np.einsum("ijkl,kl->ij", np.asarray(isotropic_a4(3)), np.asarray(B))
    np.testing.assert_allclose(resolve_contraction(table)(jnp.eye(3) / 3, B, 0.5), expected, atol=1e-15)
    np.testing.assert_allclose(resolve_contraction(lambda a: isotropic_a4(3))(jnp.eye(3) / 3, B), expected, atol=1e-15)
