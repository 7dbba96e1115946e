"""The invariant-based closure form shared by the natural and IBOF closures.

``a4 = b1 S(d d) + b2 S(d a) + b3 S(a a) + b4 S(d a.a) + b5 S(a a.a) + b6 S(a.a a.a)``
(``S``: full symmetrisation, :mod:`pyfold.closures._basis`), the most general fully
symmetric fourth-order isotropic function of a symmetric ``a`` in 3-D (Cayley-Hamilton
removes higher powers). Verleye & Dupret (1993) introduced it as the *natural*
closure; Chung & Kwon (2002, J. Rheol. 46:169, eq. 26) showed that the normalisation
and trace conditions ``a4_ijkk = a_ij`` fix ``b1``, ``b2``, ``b5`` in terms of the other
three for any ``tr a = 1``, so only ``b3``, ``b4``, ``b6`` are free.
"""
from __future__ import annotations

from pyfold._jax import jax, jnp
from pyfold.closures._basis import identity_like, sym_product, sym_product_contract
from pyfold.tensors import invariants


def monomials(a2: jax.Array, exponents) -> jax.Array:
    """``II^p III^q`` for each ``(p, q)`` in ``exponents``, stacked on a last axis.

    Integer powers (not float ones): d(x**0)/dx would be 0 * x**-1 = NaN at III = 0.
    """
    _, ii, iii = invariants(a2)
    return jnp.stack([ii ** int(p) * iii ** int(q) for p, q in exponents], axis=-1)


def invariant_form(a2: jax.Array, b3: jax.Array, b4: jax.Array, b6: jax.Array) -> jax.Array:
    """The six-term form above with ``b1``, ``b2``, ``b5`` from the trace conditions.

    Chung & Kwon (2002), eq. 26, with ``II``, ``III`` the second and third invariants:

        b1 = 3/5 [-1/7 + b3/5 (1/7 + 4/7 II + 8/3 III) - b4 (1/5 - 8/15 II - 14/15 III)
                  - b6 (1/35 - 24/105 III - 4/35 II + 16/15 II III + 8/35 II^2)]
        b2 = 6/7 [1 - b3/5 (1 + 4 II) + 7/5 b4 (1/6 - II) - b6 (-1/5 + 2/3 III + 4/5 II - 8/5 II^2)]
        b5 = -4/5 b3 - 7/5 b4 - 6/5 b6 (1 - 4/3 II)

    Whatever ``b3``, ``b4``, ``b6`` are, the result is fully symmetric, satisfies
    ``a4_ijkk = a2_ij`` to round-off and hence is exact at isotropy (where every term
    is a multiple of ``S(d d)`` and the trace fixes the multiple to 1/5).

    Parameters
    ----------
    a2 : array (..., 3, 3)
        Orientation tensor, ``tr a2 = 1``.
    b3, b4, b6 : arrays (...,)
        The three free coefficients at each state.
    """
    betas = _all_coefficients(a2, b3, b4, b6)
    eye = identity_like(a2)
    aa = jnp.einsum("...ik,...kj->...ij", a2, a2)
    out = 0.0
    for beta, (A, B) in zip(betas, _factor_pairs(eye, a2, aa)):
        out = out + beta[..., None, None, None, None] * sym_product(A, B)
    return out


def invariant_form_contract(a2: jax.Array, b3: jax.Array, b4: jax.Array, b6: jax.Array,
                            D: jax.Array) -> jax.Array:
    """``invariant_form(a2, b3, b4, b6) : D`` for a symmetric ``D``, without forming a4
    (:func:`pyfold.closures._basis.sym_product_contract`; same value to round-off)."""
    betas = _all_coefficients(a2, b3, b4, b6)
    eye = identity_like(a2)
    aa = jnp.einsum("...ik,...kj->...ij", a2, a2)
    out = 0.0
    for beta, (A, B) in zip(betas, _factor_pairs(eye, a2, aa)):
        out = out + beta[..., None, None] * sym_product_contract(A, B, D)
    return out


def _factor_pairs(eye, a2, aa):
    """The symmetric factors (A, B) of the six terms S(A B), in the order b1..b6."""
    return ((eye, eye), (eye, a2), (a2, a2), (eye, aa), (a2, aa), (aa, aa))


def _all_coefficients(a2, b3, b4, b6):
    """(b1, ..., b6): b1, b2, b5 from the trace conditions (Chung & Kwon 2002, eq. 26)."""
    _, ii, iii = invariants(a2)
    b1 = 0.6 * (
        -1.0 / 7.0
        + 0.2 * b3 * (1.0 / 7.0 + 4.0 / 7.0 * ii + 8.0 / 3.0 * iii)
        - b4 * (0.2 - 8.0 / 15.0 * ii - 14.0 / 15.0 * iii)
        - b6 * (1.0 / 35.0 - 24.0 / 105.0 * iii - 4.0 / 35.0 * ii + 16.0 / 15.0 * ii * iii + 8.0 / 35.0 * ii**2)
    )
    b2 = (6.0 / 7.0) * (
        1.0
        - 0.2 * b3 * (1.0 + 4.0 * ii)
        + 1.4 * b4 * (1.0 / 6.0 - ii)
        - b6 * (-0.2 + 2.0 / 3.0 * iii + 0.8 * ii - 1.6 * ii**2)
    )
    b5 = -0.8 * b3 - 1.4 * b4 - 1.2 * b6 * (1.0 - 4.0 / 3.0 * ii)
    return b1, b2, b3, b4, b5, b6
