"""Symmetric quadratic closure SQC (Karl, Gatti, Frohnapfel & Böhlke 2021, J. Rheol. 65:999)."""
from __future__ import annotations

from pyfold._jax import jax, jnp
from pyfold.closures._basis import sym_product


def sqc(a2: jax.Array) -> jax.Array:
    """Symmetric quadratic closure.

    ``a4 = (a_ij a_kl + a_ik a_jl + a_il a_jk) / (1 + 2 a:a)``
    (Karl, Gatti, Frohnapfel & Böhlke 2021, J. Rheol. 65(5):999-1022): the full index
    symmetrisation of the quadratic closure, normalised so that ``a4_iijj = 1``.

    Fully symmetric and exact for aligned fibres and at isotropy (in 3-D and, as the
    formula is dimension-free, in 2-D), but it does *not* satisfy ``a4_ijkk = a2_ij``
    in general: the contraction is ``(a + 2 a.a) / (1 + 2 a:a)``.
    """
    aa = jnp.einsum("...ij,...ij->...", a2, a2)
    return 3.0 * sym_product(a2, a2) / (1.0 + 2.0 * aa)[..., None, None, None, None]
