"""Planar natural closure (Verleye & Dupret 1993; Dupret & Verleye 1999)."""
from __future__ import annotations

from pyfold._jax import jax, jnp
from pyfold.tensors import det
from pyfold.closures._basis import identity_like, sym_product


def natural_2d(a2: jax.Array) -> jax.Array:
    """Natural closure in 2-D (planar orientation), closed form.

    ``a4 = (det a / 6) (d_ij d_kl + d_ik d_jl + d_il d_jk) + (a_ij a_kl + a_ik a_jl + a_il a_jk) / 3``
    i.e. ``a4 = (det a / 2) S(d d) + S(a a)`` (Verleye & Dupret 1993, *Numerical
    prediction of fiber orientation in complex injection molded parts*, ASME MD 49:264;
    Dupret & Verleye 1999, in *Advances in the Flow and Rheology of Non-Newtonian
    Fluids*, Elsevier).

    In 2-D a fully symmetric a4 satisfying ``a4_ijkk = a2_ij`` has one free principal
    component, and this formula gives ``A_1122 = det(a)/2 = a_1 a_2 / 2``, which is
    the exact value for every planar orientation state produced by Jeffery's equation
    from isotropy (an angular central Gaussian, see :mod:`pyfold.closures.exact`).
    Hence it is exact there, at isotropy and for aligned fibres, and satisfies the
    trace identity exactly (``a.a = a - det(a) I`` in 2-D with ``tr a = 1``).
    The 3-D natural closures (NAT1/NAT2, polynomial coefficients in II and III) are not
    implemented: no verifiable source of their coefficients was available (asking for
    them raises an InputError that points to ``fec``, the exact closure they fit, and
    ``ore``, VerWeyst's orthotropic fit to it).
    """
    if a2.shape[-1] != 2:
        raise ValueError("natural_2d is the planar closure; a2 must be (..., 2, 2)")
    eye = identity_like(a2)
    det_a = det(a2)[..., None, None, None, None]
    return 0.5 * det_a * sym_product(eye, eye) + sym_product(a2, a2)
