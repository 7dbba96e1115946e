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
    # The six pairings are index permutations of the single outer product
    # T_ijkl = A_ij B_kl: A_ik B_jl = T_ikjl, A_il B_jk = T_iljk, A_kl B_ij = T_klij,
    # A_jl B_ik = T_jlik, A_jk B_il = T_jkil. One product and five transposes compile
    # and run far cheaper than six products.
    t = jnp.einsum("...ij,...kl->...ijkl", A, B)
    n = t.ndim - 4
    lead = tuple(range(n))

    def perm(*axes):  # out[i, j, k, l] = t[axes applied to (i, j, k, l)]
        return jnp.transpose(t, lead + tuple(n + a for a in axes))

    # out_ijkl = t_ikjl -> input axes (i, k, j, l) come from output axes (0, 2, 1, 3), etc.
    return (t + perm(0, 2, 1, 3) + perm(0, 2, 3, 1) + perm(2, 3, 0, 1) + perm(2, 0, 3, 1) + perm(2, 0, 1, 3)) / 6.0


def sym_product_contract(A: jax.Array, B: jax.Array, D: jax.Array) -> jax.Array:
    """``S(A B) : D`` without forming the fourth-order tensor.

    For symmetric ``A``, ``B``, ``D`` the six pairings of :func:`sym_product` contract to

        S(A B)_ijkl D_kl = [A_ij (B:D) + B_ij (A:D) + 2 (A.D.B)_ij + 2 (B.D.A)_ij] / 6,

    O(d^3) per state instead of O(d^4): the rate of an orientation model needs only
    ``a4:D``, and forming every ``S(..)`` term dominated its cost (measured: IBOF
    Folgar–Tucker right-hand side 5x the quadratic closure's).
    """
    ad = jnp.sum(A * D, axis=(-2, -1))
    bd = jnp.sum(B * D, axis=(-2, -1))
    adb = jnp.einsum("...ik,...kl,...lj->...ij", A, D, B)
    return (A * bd[..., None, None] + B * ad[..., None, None] + 2.0 * adb + 2.0 * jnp.swapaxes(adb, -1, -2)) / 6.0


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
    # t1 = sum_mn weight_mn (e_m e_m)(e_n e_n); the other two arrangements are its
    # index permutations t1_ikjl and t1_iljk (one product, two transposes).
    proj = jnp.einsum("...im,...jm->...mij", e, e)
    t1 = jnp.einsum("...mn,...mij,...nkl->...ijkl", weight, proj, proj)
    n = t1.ndim - 4
    lead = tuple(range(n))
    return t1 + jnp.transpose(t1, lead + (n, n + 2, n + 1, n + 3)) + jnp.transpose(t1, lead + (n, n + 2, n + 3, n + 1))


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
