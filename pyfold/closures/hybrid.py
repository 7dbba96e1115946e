"""Hybrid closure (Advani & Tucker 1987, J. Rheol. 31:751; 1990, J. Rheol. 34:367)."""
from __future__ import annotations

from pyfold._jax import jax, jnp
from pyfold.tensors import det
from pyfold.closures.linear import linear
from pyfold.closures.quadratic import quadratic


def hybrid_weight(a2: jax.Array) -> jax.Array:
    """Scalar orientation measure ``f`` of the hybrid closure.

    ``f = 1 - 27 det(a2)`` in 3-D and ``f = 1 - 4 det(a2)`` in 2-D: 0 at isotropy,
    1 for any a2 with a zero eigenvalue (in 3-D) / for aligned fibres.
    """
    d = a2.shape[-1]
    return 1.0 - d**d * det(a2)


def hybrid(a2: jax.Array) -> jax.Array:
    """Hybrid closure ``a4 = (1 - f) a4_linear + f a4_quadratic``, ``f`` from :func:`hybrid_weight`.

    Reference: Advani & Tucker (1987, 1990). Exact for aligned fibres (f = 1) and at
    isotropy (f = 0). Being a convex blend of two closures that both satisfy
    ``a4_ijkk = a2_ij``, it satisfies that contraction too, but it inherits the
    missing full index symmetry of the quadratic part. Known to over-predict
    alignment in shear.
    """
    f = hybrid_weight(a2)[..., None, None, None, None]
    return (1.0 - f) * linear(a2) + f * quadratic(a2)
