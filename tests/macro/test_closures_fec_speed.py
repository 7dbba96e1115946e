"""The shortcuts of pyfold/closures/exact.py against the plain forms they replace.

FEC is evaluated in the principal frame of a2 with the Jacobian of the principal
residual written out, a4 from the principal values plus the first-order off-diagonal
part, and a Gauss-Newton iteration that stops once the next step is below round-off.
Each is compared here with the generic formulation (forward-mode Jacobian, the
adjugate kernel of ``acg_a4`` at a full ``C``, all NEWTON_STEPS steps); values and first
derivatives must agree to round-off. The agreement with an independent reference
and with central differences is tested in tests/macro/test_closures*.py.
"""
from __future__ import annotations

import numpy as np
import pytest

from pyfold._jax import jax, jnp
from pyfold.closures import exact as E

from _closure_batches import random_a2

EPS = np.finfo(np.float64).eps
#: The quadrature has 129 nodes: two orderings of the same sums differ by at most
#: ~129 eps times the sum of the absolute terms (<= a few for these O(1) integrals);
#: 1024 eps covers it with the cancellation of the Jacobian's two terms.
SUM_TOL = 1024 * EPS


def _sym(rng, d=3):
    x = rng.normal(size=(d, d))
    return 0.5 * (x + x.T)


@pytest.mark.parametrize("m", [(0.6, 0.3, 0.1), (0.98, 0.015, 0.005), (1 / 3, 1 / 3, 1 / 3), (0.5, 0.5, 0.0)])
def test_principal_jacobian_matches_forward_mode(m):
    m = jnp.asarray(m)
    a, j = E._principal_jacobian(m)
    a_ref = E._acg_a2_principal(m * m)
    j_ref = jax.jacfwd(lambda x: E._acg_a2_principal(x * x))(m)
    np.testing.assert_allclose(a, a_ref, rtol=0, atol=SUM_TOL)
    np.testing.assert_allclose(j, j_ref, rtol=0, atol=SUM_TOL * max(1.0, float(jnp.abs(j_ref).max())))


@pytest.mark.parametrize("m", [(0.6, 0.3, 0.1), (0.98, 0.015, 0.005), (0.7, 0.3, 0.0)])
def test_a4_in_the_frame_matches_the_full_kernel_to_first_order(m):
    # M diagonal in value with a full symmetric derivative, as _solve_m returns it:
    # value and jvp of _a4_frame against acg_a4(M^2) by the adjugate kernel.
    rng = np.random.default_rng(3)
    dm = jnp.asarray(_sym(rng))
    m0 = jnp.diag(jnp.asarray(m))
    val, tan = jax.jvp(E._a4_frame, (m0,), (dm,))
    val_ref, tan_ref = jax.jvp(lambda x: E.acg_a4(x @ x), (m0,), (dm,))
    np.testing.assert_allclose(val, val_ref, rtol=0, atol=SUM_TOL)
    np.testing.assert_allclose(tan, tan_ref, rtol=0, atol=SUM_TOL * float(jnp.abs(tan_ref).max()))
    # the tangent is not trivially diagonal: the off-diagonal part of dm matters
    tan_diag = jax.jvp(lambda x: E.acg_a4(x @ x), (m0,), (jnp.diag(jnp.diag(dm)),))[1]
    assert float(jnp.abs(tan_ref - tan_diag).max()) > 1e-3


def test_stopped_gauss_newton_matches_all_steps(monkeypatch):
    # Stopping early must not change the value nor the derivative (evaluated at the
    # iterate the loop returns): a stop one step too early leaves an error ~ sqrt(eps)
    # in m and ~1e-9 in the derivative, far above the tolerance.
    a2 = jnp.asarray(random_a2(3, 40, seed=11))
    da = jnp.asarray(random_a2(3, 40, seed=12) - random_a2(3, 40, seed=13))

    def evaluate():
        return jax.jit(jax.vmap(lambda a, t: jax.jvp(E.fec, (a,), (t,))))(a2, da)

    val, tan = evaluate()
    monkeypatch.setattr(E, "STOP_ULPS", -1.0)  # never met: all NEWTON_STEPS steps
    val_all, tan_all = evaluate()
    np.testing.assert_allclose(val, val_all, rtol=0, atol=SUM_TOL)
    np.testing.assert_allclose(tan, tan_all, rtol=0, atol=SUM_TOL * float(jnp.abs(tan_all).max()))


def test_gauss_newton_stops_before_the_cap_and_at_round_off():
    # The stopping rule is what makes FEC cheap: on interior states it must end the
    # iteration before NEWTON_STEPS, at a root of the principal residual to round-off.
    a2 = random_a2(3, 40, seed=21)
    t = jnp.asarray(np.linalg.eigvalsh(a2))
    m, k = jax.jit(jax.vmap(E._gauss_newton))(t)
    assert int(k.max()) < E.NEWTON_STEPS and int(k.min()) >= 2
    residual = jax.vmap(lambda x: E._acg_a2_principal(x * x))(m) - t
    np.testing.assert_allclose(residual, 0.0, rtol=0, atol=SUM_TOL)
    np.testing.assert_allclose(m.sum(-1), 1.0, rtol=0, atol=8 * EPS)
