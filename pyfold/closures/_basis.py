"""Tensor building blocks shared by the closures (isotropic bases, symmetrised products).

Notation used in every closure docstring: ``S(A B)`` is the full index
symmetrisation (mean over the 24 permutations) of ``A_ij B_kl``; for symmetric
``A``, ``B`` it is the mean of the six distinct pairings,
``S(A B) = (A_ij B_kl + A_ik B_jl + A_il B_jk + A_kl B_ij + A_jl B_ik + A_jk B_il) / 6``.
"""
from __future__ import annotations

from pyfold._jax import jax, jnp


def identity_like(a2: jax.Array) -> jax.Array:
    """Identity of the spatial dimension of ``a2``, broadcastable against it."""
    return jnp.eye(a2.shape[-1], dtype=a2.dtype)


def sym_product(A: jax.Array, B: jax.Array) -> jax.Array:
    """``S(A B)``: fully symmetric part of ``A_ij B_kl`` for symmetric ``A``, ``B``.

    Either argument may be the identity of shape ``(d, d)``; leading axes broadcast.
    """
    terms = (
        jnp.einsum("...ij,...kl->...ijkl", A, B)
        + jnp.einsum("...ik,...jl->...ijkl", A, B)
        + jnp.einsum("...il,...jk->...ijkl", A, B)
        + jnp.einsum("...kl,...ij->...ijkl", A, B)
        + jnp.einsum("...jl,...ik->...ijkl", A, B)
        + jnp.einsum("...jk,...il->...ijkl", A, B)
    )
    return terms / 6.0


def from_principal(principal: jax.Array, vectors: jax.Array) -> jax.Array:
    """Rotate an orthotropic fourth-order tensor from its principal frame to the lab.

    Parameters
    ----------
    principal : array (..., d, d)
        Symmetric matrix ``P_mn = A_mmnn`` of the principal-frame components (all
        other principal-frame components of an orthotropic fully symmetric tensor
        with these symmetry planes vanish).
    vectors : array (..., d, d)
        Principal axes as columns.

    Returns
    -------
    a4 : array (..., d, d, d, d)
        The fully symmetric tensor whose principal-frame components are
        ``A_mmnn = A_mnmn = A_mnnm = P_mn`` (all others zero).
    """
    # Fully symmetric orthotropic tensor: a4 = sum_m P_mm e_m^4 + sum_{m != n} P_mn
    # (e_m e_m e_n e_n + e_m e_n e_m e_n + e_m e_n e_n e_m); the three pairings below
    # give each off-diagonal arrangement once per ordered (m, n) and the diagonal
    # three times, hence the 1/3 on the diagonal weight.
    e = vectors
    d = principal.shape[-1]
    eye = jnp.eye(d, dtype=principal.dtype)
    weight = principal * (1.0 - eye) + principal * eye / 3.0
    t1 = jnp.einsum("...mn,...im,...jm,...kn,...ln->...ijkl", weight, e, e, e, e)
    t2 = jnp.einsum("...mn,...im,...jn,...km,...ln->...ijkl", weight, e, e, e, e)
    t3 = jnp.einsum("...mn,...im,...jn,...kn,...lm->...ijkl", weight, e, e, e, e)
    return t1 + t2 + t3


def principal_from_offdiagonal(values: jax.Array, off: jax.Array) -> jax.Array:
    """Complete principal components from the off-diagonal ones via the trace identity.

    Given eigenvalues ``a_m`` and the symmetric matrix ``off`` whose off-diagonal
    entries are ``A_mmnn`` (m != n; its diagonal is ignored), return ``P`` with
    ``P_mm = a_m - sum_{n != m} A_mmnn``, so that ``A_mmkk = a_m`` exactly.
    """
    d = values.shape[-1]
    eye = jnp.eye(d, dtype=values.dtype)
    off = off * (1.0 - eye)
    diag = values - jnp.sum(off, axis=-1)
    return off + diag[..., :, None] * eye
