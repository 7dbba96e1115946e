"""Quadratic closure (Doi 1981; Hinch & Leal 1976; Advani & Tucker 1987, J. Rheol. 31:751)."""
from __future__ import annotations

from pyfold._jax import jax, jnp


def quadratic(a2: jax.Array) -> jax.Array:
    """Quadratic closure ``a4_ijkl = a2_ij a2_kl``.

    Exact for perfectly aligned fibres (``a2 = p p``) and satisfies the trace
    identity ``a4_ijkk = a2_ij`` over the last pair. It has only the pair symmetries
    ``ij <-> ji``, ``kl <-> lk``, ``(ij) <-> (kl)``, *not* full index symmetry (e.g.
    ``a4_ikjk = (a2.a2)_ij`` differs from ``a2_ij``); it is kept unsymmetrised, as in
    the literature, because ``a4:D = a2 (a2:D)`` is the form in which the
    Folgar-Tucker closed-form steady states are published. Not exact at isotropy.
    """
    return jnp.einsum("...ij,...kl->...ijkl", a2, a2)
