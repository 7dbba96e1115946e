"""Orientation tensors of fibre populations: construction, symmetry, invariants, frames.

The second- and fourth-order orientation tensors of a population of unit vectors
``p`` (Advani & Tucker 1987, J. Rheol. 31:751) are the moments

    a2_ij = <p_i p_j>,        a4_ijkl = <p_i p_j p_k p_l>,

so ``a2`` is symmetric, positive semi-definite with unit trace and ``a4`` is fully
symmetric with ``a4_ijkk = a2_ij``. Arrays carry the spatial dimensions last,
``a2`` is ``(..., d, d)`` and ``a4`` is ``(..., d, d, d, d)``, with ``d = 3`` in
space and ``d = 2`` for planar orientation. Every function here except
:func:`check_orientation_tensor` is pure JAX (jit-, vmap- and grad-able).
"""
from __future__ import annotations

import itertools

import numpy as np

from pyfold._jax import jax, jnp
from pyfold.errors import InputError

__all__ = [
    "a2_from_vectors",
    "a4_from_vectors",
    "symmetrize4",
    "contract4",
    "invariants",
    "det",
    "eigen_frame",
    "check_orientation_tensor",
    "isotropic_a2",
    "isotropic_a4",
    "aligned",
    "aligned_a4",
    "EIGEN_GAP_REGULARISATION",
]

#: Eigenvalue gap [dimensionless] below which the derivative of the eigenvectors is
#: regularised in :func:`eigen_frame`. Orientation eigenvalues live in [0, 1], so
#: 1e-9 is far below any physically meaningful anisotropy and far above round-off.
EIGEN_GAP_REGULARISATION = 1e-9

_PERMUTATIONS_4 = tuple(itertools.permutations(range(4)))


def _check_dim(d: int) -> int:
    if d not in (2, 3):
        raise InputError(f"dim must be 2 (planar) or 3 (spatial), got {d!r}")
    return int(d)


def _normalised_weights(p: jax.Array, weights: jax.Array | None) -> jax.Array:
    n = p.shape[-2]
    if weights is None:
        return jnp.full(p.shape[:-1], 1.0 / n, dtype=p.dtype)
    w = jnp.asarray(weights, dtype=p.dtype)
    if w.shape[-1] != n:
        raise InputError(
            f"weights: last axis must match the number of vectors N = {n}, got shape {w.shape}"
        )
    return w / jnp.sum(w, axis=-1, keepdims=True)


def a2_from_vectors(p: jax.Array, weights: jax.Array | None = None) -> jax.Array:
    """Second-order orientation tensor of a population of unit vectors.

    ``a2_ij = sum_n w_n p_ni p_nj / sum_n w_n`` (Advani & Tucker 1987).

    Parameters
    ----------
    p : array (..., N, d)
        Fibre directions; they are used as given (normalise them first).
    weights : array (..., N), optional
        Non-negative weights (e.g. quadrature weights or fibre lengths); uniform
        when omitted. They are normalised to sum to one.

    Returns
    -------
    a2 : array (..., d, d)
    """
    p = jnp.asarray(p, dtype=jnp.float64)
    w = _normalised_weights(p, weights)
    return jnp.einsum("...n,...ni,...nj->...ij", w, p, p)


def a4_from_vectors(p: jax.Array, weights: jax.Array | None = None) -> jax.Array:
    """Fourth-order orientation tensor ``a4_ijkl = <p_i p_j p_k p_l>`` (weights as in
    :func:`a2_from_vectors`).

    Returns
    -------
    a4 : array (..., d, d, d, d)
    """
    p = jnp.asarray(p, dtype=jnp.float64)
    w = _normalised_weights(p, weights)
    return jnp.einsum("...n,...ni,...nj,...nk,...nl->...ijkl", w, p, p, p, p)


def symmetrize4(a4: jax.Array) -> jax.Array:
    """Full index symmetrisation: the mean of ``a4`` over all 24 index permutations."""
    a4 = jnp.asarray(a4)
    lead = tuple(range(a4.ndim - 4))
    acc = jnp.zeros_like(a4)
    for perm in _PERMUTATIONS_4:
        acc = acc + jnp.transpose(a4, lead + tuple(len(lead) + q for q in perm))
    return acc / len(_PERMUTATIONS_4)


def contract4(a4: jax.Array, D: jax.Array) -> jax.Array:
    """Double contraction ``(a4 : D)_ij = a4_ijkl D_kl`` (broadcasts over leading axes)."""
    return jnp.einsum("...ijkl,...kl->...ij", a4, D)


def invariants(a2: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Principal invariants of a second-order tensor.

    ``I = tr a``, ``II = (tr(a)^2 - tr(a.a)) / 2`` (sum of principal 2x2 minors),
    ``III = det a``. For an orientation tensor ``I = 1``; these are the ``II``,
    ``III`` of the natural and IBOF closures (Chung & Kwon 2002, J. Rheol. 46:169).
    In 2-D, ``III`` is returned as 0 (there is no third invariant).

    Returns
    -------
    (I, II, III) : arrays (...,)
    """
    a2 = jnp.asarray(a2)
    tr = jnp.trace(a2, axis1=-2, axis2=-1)
    tr2 = jnp.einsum("...ij,...ji->...", a2, a2)
    second = 0.5 * (tr**2 - tr2)
    if a2.shape[-1] == 3:
        third = det(a2)
    else:
        third = jnp.zeros_like(tr)
    return tr, second, third


def det(a: jax.Array) -> jax.Array:
    """Determinant of (..., 2, 2) or (..., 3, 3) arrays by cofactors.

    Written out (rather than ``jnp.linalg.det``, whose LU-based derivative is NaN for
    singular matrices) so that gradients stay finite for aligned fibres, where
    ``det a2 = 0``.
    """
    a = jnp.asarray(a)
    if a.shape[-1] == 2:
        return a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    if a.shape[-1] != 3:
        raise InputError(f"det: expected (..., 2, 2) or (..., 3, 3), got {a.shape}")
    return (
        a[..., 0, 0] * (a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1])
        - a[..., 0, 1] * (a[..., 1, 0] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 0])
        + a[..., 0, 2] * (a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0])
    )


@jax.custom_jvp
def _eigh_desc(a: jax.Array) -> tuple[jax.Array, jax.Array]:
    vals, vecs = jnp.linalg.eigh(a)
    return vals[..., ::-1], vecs[..., ::-1]


@_eigh_desc.defjvp
def _eigh_desc_jvp(primals, tangents):
    # Standard first-order perturbation theory (e.g. Magnus 1985), except that the
    # eigenvector coupling 1/(l_j - l_i) is replaced by (l_j - l_i)/((l_j - l_i)^2 + eps^2):
    # exact for separated eigenvalues, finite (zero coupling) at an exact degeneracy
    # such as an isotropic a2, where JAX's own eigh derivative returns NaN.
    (a,) = primals
    (da,) = tangents
    vals, vecs = _eigh_desc(a)
    da = 0.5 * (da + jnp.swapaxes(da, -1, -2))
    vt_da_v = jnp.einsum("...ki,...kl,...lj->...ij", vecs, da, vecs)
    dvals = jnp.diagonal(vt_da_v, axis1=-2, axis2=-1)
    gap = vals[..., None, :] - vals[..., :, None]  # l_j - l_i
    eps = EIGEN_GAP_REGULARISATION
    coupling = gap / (gap**2 + eps**2)
    dvecs = jnp.einsum("...ik,...kj->...ij", vecs, coupling * vt_da_v)
    return (vals, vecs), (dvals, dvecs)


def eigen_frame(a2: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Principal values and axes of a symmetric tensor, sorted in descending order.

    Returns
    -------
    values : array (..., d)
        Eigenvalues ``l_1 >= l_2 (>= l_3)``.
    vectors : array (..., d, d)
        Orthonormal eigenvectors as *columns*: ``a2 = V diag(values) V^T``.

    Notes
    -----
    Repeated eigenvalues (isotropic or transversely isotropic ``a2``) make the axes
    non-unique and their exact derivative singular. The forward values are those
    of LAPACK; the derivative of the axes uses a regularised gap
    (:data:`EIGEN_GAP_REGULARISATION`), so ``jax.grad`` of any function of the
    frame stays finite there. It is exact wherever the eigenvalues are separated by
    much more than that gap; *at* an exact degeneracy the rotation of the axes within
    the degenerate subspace is dropped, so a function of the frame loses that part of
    its derivative. Closures that need an exact derivative there avoid the frame:
    matrix functions use ``pyfold.closures._spectral.spectral_function``
    (Daleckii-Krein), the exact closure uses a fixed frame and rotation equivariance.
    """
    a2 = jnp.asarray(a2, dtype=jnp.float64)
    return _eigh_desc(a2)


def check_orientation_tensor(a2, name: str = "a2", tol: float = 1e-8) -> np.ndarray:
    """Validate a (batch of) second-order orientation tensor(s); not jit-able.

    Checks shape ``(..., d, d)`` with ``d`` in {2, 3}, finiteness, symmetry,
    unit trace and positive semi-definiteness, each to absolute tolerance ``tol``.

    Returns
    -------
    a2 : numpy.ndarray
        The input as a float64 array.

    Raises
    ------
    InputError
        Naming ``name``, the violated property, the worst value and the allowed range.
    """
    arr = np.asarray(a2, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-1] != arr.shape[-2] or arr.shape[-1] not in (2, 3):
        raise InputError(f"{name}: expected shape (..., d, d) with d in {{2, 3}}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinity")
    asym = np.max(np.abs(arr - np.swapaxes(arr, -1, -2)), initial=0.0)
    if asym > tol:
        raise InputError(f"{name}: must be symmetric; max |a_ij - a_ji| = {asym:.3e} > tol = {tol:.1e}")
    trace_err = np.max(np.abs(np.trace(arr, axis1=-2, axis2=-1) - 1.0), initial=0.0)
    if trace_err > tol:
        raise InputError(f"{name}: trace must be 1; max |tr - 1| = {trace_err:.3e} > tol = {tol:.1e}")
    lowest = np.min(np.linalg.eigvalsh(0.5 * (arr + np.swapaxes(arr, -1, -2))), initial=np.inf)
    if lowest < -tol:
        raise InputError(
            f"{name}: must be positive semi-definite (eigenvalues in [0, 1]); "
            f"smallest eigenvalue {lowest:.3e} < -tol = {-tol:.1e}"
        )
    return arr


def isotropic_a2(d: int = 3) -> jax.Array:
    """Isotropic second-order tensor ``I / d``."""
    d = _check_dim(d)
    return jnp.eye(d) / d


def isotropic_a4(d: int = 3) -> jax.Array:
    """Isotropic fourth-order orientation tensor.

    ``a4 = (d_ij d_kl + d_ik d_jl + d_il d_jk) / (d (d + 2))``: 1/15 in 3-D
    (uniform on the sphere), 1/8 in 2-D (uniform on the circle).
    """
    d = _check_dim(d)
    eye = jnp.eye(d)
    s = (
        jnp.einsum("ij,kl->ijkl", eye, eye)
        + jnp.einsum("ik,jl->ijkl", eye, eye)
        + jnp.einsum("il,jk->ijkl", eye, eye)
    )
    return s / (d * (d + 2))


def aligned(p: jax.Array) -> jax.Array:
    """``a2 = p p`` of perfectly aligned fibres along ``p`` (normalised here), shape (..., d, d)."""
    p = jnp.asarray(p, dtype=jnp.float64)
    p = p / jnp.linalg.norm(p, axis=-1, keepdims=True)
    return jnp.einsum("...i,...j->...ij", p, p)


def aligned_a4(p: jax.Array) -> jax.Array:
    """``a4 = p p p p`` of perfectly aligned fibres along ``p`` (normalised here)."""
    p = jnp.asarray(p, dtype=jnp.float64)
    p = p / jnp.linalg.norm(p, axis=-1, keepdims=True)
    return jnp.einsum("...i,...j,...k,...l->...ijkl", p, p, p, p)
