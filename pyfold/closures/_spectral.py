"""Isotropic matrix functions ``F(A) = V diag(f(l_i)) V^T`` with an exact derivative at
repeated eigenvalues.

JAX's ``eigh`` derivative divides by eigenvalue gaps and returns NaN when ``A`` has a
repeated eigenvalue (an isotropic ``a2`` is exactly that). For a matrix function
the derivative is nevertheless well defined (Daleckii & Krein 1965; Higham 2008,
*Functions of Matrices*, Thm 3.11): in the eigenbasis,

    dF_ij = f[l_i, l_j] (V^T dA V)_ij,   f[l_i, l_j] = (f_i - f_j)/(l_i - l_j)  or  f'(l_i) if l_i = l_j,

which is what :func:`spectral_function` implements as a custom JVP.
"""
from __future__ import annotations

from functools import partial
from typing import Callable

from pyfold._jax import jax, jnp

#: Eigenvalue gap below which the divided difference is replaced by the mean
#: derivative; the error of that switch is O(f''' gap^2) ~ 1e-12 for smooth f.
DIVIDED_DIFFERENCE_GAP = 1e-6


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def spectral_function(f: Callable, a: jax.Array, params) -> jax.Array:
    """``V diag(f(l, params)) V^T`` for symmetric ``a = V diag(l) V^T``.

    ``f(l, params)`` must act elementwise on the eigenvalue array ``l`` (..., d);
    ``params`` is any pytree of arrays that ``f`` also depends on (its derivative
    is propagated too). Works on batches (..., d, d).
    """
    vals, vecs = jnp.linalg.eigh(a)
    fv = f(vals, params)
    return jnp.einsum("...ik,...k,...jk->...ij", vecs, fv, vecs)


@spectral_function.defjvp
def _spectral_function_jvp(f, primals, tangents):
    a, params = primals
    da, dparams = tangents
    vals, vecs = jnp.linalg.eigh(a)
    fv, dfv_params = jax.jvp(lambda p: f(vals, p), (params,), (dparams,))
    _, fprime = jax.jvp(lambda l: f(l, params), (vals,), (jnp.ones_like(vals),))
    gap = vals[..., :, None] - vals[..., None, :]
    close = jnp.abs(gap) < DIVIDED_DIFFERENCE_GAP
    safe_gap = jnp.where(close, 1.0, gap)
    divided = jnp.where(
        close,
        0.5 * (fprime[..., :, None] + fprime[..., None, :]),
        (fv[..., :, None] - fv[..., None, :]) / safe_gap,
    )
    da = 0.5 * (da + jnp.swapaxes(da, -1, -2))
    x = jnp.einsum("...ki,...kl,...lj->...ij", vecs, da, vecs)
    inner = divided * x + jnp.einsum("...i,ij->...ij", dfv_params, jnp.eye(vals.shape[-1]))
    out = jnp.einsum("...ik,...k,...jk->...ij", vecs, fv, vecs)
    dout = jnp.einsum("...ik,...kl,...jl->...ij", vecs, inner, vecs)
    return out, dout
