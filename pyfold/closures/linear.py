"""Linear closure (Hand 1962, J. Fluid Mech. 13:33; Advani & Tucker 1987, J. Rheol. 31:751)."""
from __future__ import annotations

from pyfold._jax import jax, jnp
from pyfold.closures._basis import identity_like, sym_product


def linear(a2: jax.Array) -> jax.Array:
    """Linear closure: the exact a4 of the distribution truncated after its quadratic term.

    ``a4 = -c1 (d_ij d_kl + d_ik d_jl + d_il d_jk) + c2 (a_ij d_kl + 5 other pairings)``
    with ``c2 = 1/(d+4)``, ``c1 = 1/((d+2)(d+4))``: in 3-D ``c1 = 1/35``, ``c2 = 1/7``
    (Hand 1962); in 2-D ``c1 = 1/24``, ``c2 = 1/6`` (Advani & Tucker 1987). The
    coefficients follow from the trace identity ``a4_ijkk = a2_ij`` and
    ``a4_iikk = 1``, which the closure satisfies exactly with full index symmetry.

    Exact for isotropic ``a2``; poor for aligned fibres (can give a4 that is not
    positive).
    """
    d = a2.shape[-1]
    eye = identity_like(a2)
    c2 = 1.0 / (d + 4)
    c1 = 1.0 / ((d + 2) * (d + 4))
    # sym_product averages over the six pairings, so the 3- and 6-term sums are 3x and 6x it.
    return -c1 * 3.0 * sym_product(eye, eye) + c2 * 6.0 * sym_product(a2, eye)
