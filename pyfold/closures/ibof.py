"""Invariant-based optimal fitting closure IBOF (Chung & Kwon 2002, J. Rheol. 46:169)."""
from __future__ import annotations

import numpy as np

from pyfold._jax import jax, jnp
from pyfold.closures._basis import identity_like, sym_product
from pyfold.closures import _coefficients as K
from pyfold.tensors import invariants

_COEFFS = np.asarray([K.IBOF_BETA3, K.IBOF_BETA4, K.IBOF_BETA6], dtype=np.float64)


def ibof(a2: jax.Array) -> jax.Array:
    """IBOF closure, 5th-order polynomial version (3-D only).

    ``a4 = b1 S(d d) + b2 S(d a) + b3 S(a a) + b4 S(d a.a) + b5 S(a a.a) + b6 S(a.a a.a)``
    with ``S`` the full symmetrisation (Chung & Kwon 2002, J. Rheol. 46(1):169-194).
    ``b3``, ``b4``, ``b6`` are 5th-order polynomials in ``II`` (sum of principal 2x2
    minors) and ``III = det a`` with the paper's 63 coefficients
    (:mod:`pyfold.closures._coefficients`); ``b1``, ``b2``, ``b5`` follow from the
    normalisation and trace conditions (their eq. 26):

        b1 = 3/5 [-1/7 + b3/5 (1/7 + 4/7 II + 8/3 III) - b4 (1/5 - 8/15 II - 14/15 III)
                  - b6 (1/35 - 24/105 III - 4/35 II + 16/15 II III + 8/35 II^2)]
        b2 = 6/7 [1 - b3/5 (1 + 4 II) + 7/5 b4 (1/6 - II) - b6 (-1/5 + 2/3 III + 4/5 II - 8/5 II^2)]
        b5 = -4/5 b3 - 7/5 b4 - 6/5 b6 (1 - 4/3 II)

    Fully symmetric and trace-exact (to round-off, by construction of b1, b2, b5);
    aligned and isotropic states are reproduced only to the fit's accuracy.
    """
    if a2.shape[-1] != 3:
        raise ValueError("IBOF is defined in 3-D only; a2 must be (..., 3, 3)")
    _, ii, iii = invariants(a2)
    # integer powers (not float ones): d(x**0)/dx would be 0 * x**-1 = NaN at III = 0
    mono = jnp.stack([ii**int(p) * iii**int(q) for p, q in K.IBOF_MONOMIALS], axis=-1)
    b3, b4, b6 = (jnp.einsum("...m,m->...", mono, jnp.asarray(c)) for c in _COEFFS)
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
    eye = identity_like(a2)
    aa = jnp.einsum("...ik,...kj->...ij", a2, a2)
    terms = (
        sym_product(eye, eye),
        sym_product(eye, a2),
        sym_product(a2, a2),
        sym_product(eye, aa),
        sym_product(a2, aa),
        sym_product(aa, aa),
    )
    out = 0.0
    for beta, term in zip((b1, b2, b3, b4, b5, b6), terms):
        out = out + beta[..., None, None, None, None] * term
    return out
