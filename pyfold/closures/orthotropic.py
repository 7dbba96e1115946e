"""Orthotropic fitted closures ORS, ORF, ORL (Cintra & Tucker 1995), ORE (VerWeyst 1998)
and ORW, ORW3 (Chung & Kwon 2001).

An orthotropic closure assumes the principal axes of a4 are those of a2. In that
frame a fully symmetric a4 has six distinct components; with contracted notation
``A_11 = A_1111``, ``A_22 = A_2222``, ``A_33 = A_3333``, ``A_44 = A_2233``,
``A_55 = A_1133``, ``A_66 = A_1122``. The fitted closures give ``A_11, A_22, A_33`` as
polynomials of the two largest eigenvalues ``a1 >= a2`` (coefficients in
:mod:`pyfold.closures._coefficients`); the trace identity ``A_mmkk = a_m`` then fixes

    A_66 = (a1 + a2 - a3 - A_11 - A_22 + A_33) / 2,
    A_55 = (a1 - a2 + a3 - A_11 + A_22 - A_33) / 2,
    A_44 = (-a1 + a2 + a3 + A_11 - A_22 - A_33) / 2,

and the tensor is rotated back with the eigenvectors. The results are fully
symmetric and satisfy ``a4_ijkk = a2_ij`` exactly; aligned and isotropic states are
reproduced only to the accuracy of the fit.

Repeated eigenvalues. The fits are polynomials in the *sorted* eigenvalues and are
not symmetric under ``a1 <-> a2``: where two eigenvalues coincide, the fitted principal
values differ slightly, so a4 depends on which axes LAPACK returns inside the
degenerate plane (a discontinuity of the size of the fit asymmetry, measured in the
tests). Gradients stay finite there because :func:`pyfold.tensors.eigen_frame`
regularises the eigenvector derivative.
"""
from __future__ import annotations

import numpy as np

from pyfold._jax import jax, jnp
from pyfold.closures import _coefficients as K
from pyfold.closures._basis import from_principal
from pyfold.tensors import eigen_frame


def _basis3(a1, a2):
    return jnp.stack([jnp.ones_like(a1), a1, a2], axis=-1)


def _basis15(a1, a2):
    # VerWeyst's monomial order (see _coefficients.ORE)
    return jnp.stack(
        [
            jnp.ones_like(a1), a1, a2, a1 * a2, a1**2, a2**2, a1**2 * a2, a1 * a2**2,
            a1**3, a2**3, a1**2 * a2**2, a1**3 * a2, a1 * a2**3, a1**4, a2**4,
        ],
        axis=-1,
    )


def _basis6(a1, a2):
    return jnp.stack([jnp.ones_like(a1), a1, a1**2, a2, a2**2, a1 * a2], axis=-1)


def _basis10(a1, a2):
    return jnp.stack(
        [jnp.ones_like(a1), a1, a1**2, a2, a2**2, a1 * a2, a1**2 * a2, a1 * a2**2, a1**3, a2**3],
        axis=-1,
    )


def orthotropic_from_diagonal(a2: jax.Array, diagonal_fn) -> jax.Array:
    """Build an orthotropic closure from a function ``(a1, a2) -> (A_11, A_22, A_33)``."""
    if a2.shape[-1] != 3:
        raise ValueError("orthotropic fitted closures are defined in 3-D; a2 must be (..., 3, 3)")
    vals, vecs = eigen_frame(a2)
    l1, l2, l3 = vals[..., 0], vals[..., 1], vals[..., 2]
    p11, p22, p33 = diagonal_fn(l1, l2)
    p12 = 0.5 * (l1 + l2 - l3 - p11 - p22 + p33)
    p13 = 0.5 * (l1 - l2 + l3 - p11 + p22 - p33)
    p23 = 0.5 * (-l1 + l2 + l3 + p11 - p22 - p33)
    principal = jnp.stack(
        [
            jnp.stack([p11, p12, p13], axis=-1),
            jnp.stack([p12, p22, p23], axis=-1),
            jnp.stack([p13, p23, p33], axis=-1),
        ],
        axis=-2,
    )
    return from_principal(principal, vecs)


def _fitted(table, basis):
    coeffs = np.asarray(table, dtype=np.float64)

    def diagonal(a1, a2):
        w = basis(a1, a2)
        out = jnp.einsum("...k,mk->...m", w, jnp.asarray(coeffs))
        return out[..., 0], out[..., 1], out[..., 2]

    return diagonal


_ORS = _fitted(K.ORS, _basis3)
_ORE = _fitted(K.ORE, _basis15)
_ORF = _fitted(K.ORF, _basis6)
_ORL = _fitted(K.ORL, _basis6)
_ORW = _fitted(K.ORW, _basis6)
_ORW3 = _fitted(K.ORW3, _basis10)


def ors(a2: jax.Array) -> jax.Array:
    """Smooth orthotropic closure ORS (Cintra & Tucker 1995, J. Rheol. 39(6):1095-1122).

    ``A_11 = -0.15 + 1.15 a1 - 0.10 a2``, ``A_22 = -0.15 + 0.15 a1 + 0.90 a2``,
    ``A_33 = 0.60 - 0.60 a1 - 0.60 a2``: linear in the eigenvalues. Exact for aligned
    fibres and at isotropy, and (unlike the higher-order fits) symmetric under
    exchange of equal eigenvalues, hence continuous at repeated eigenvalues; a crude
    approximation in between (Cintra & Tucker used it to show that the orthotropic
    form alone removes the hybrid closure's over-prediction of alignment).
    """
    return orthotropic_from_diagonal(a2, _ORS)


def ore(a2: jax.Array) -> jax.Array:
    """Orthotropic fit to the natural (exact) closure, ORE (VerWeyst 1998, PhD thesis,
    University of Illinois, p. 47; VerWeyst, Tucker, Foss & O'Gara 1999, Int. Polym.
    Process. 14:409).

    ``A_mm`` are quartic polynomials in ``a1, a2`` (15 coefficients each, in
    :mod:`pyfold.closures._coefficients`), fitted to the closure that is exact for
    Jeffery's equation from isotropy (the 3-D natural closure of Verleye & Dupret,
    which :func:`pyfold.closures.fec` evaluates exactly). Tucker's toolbox calls it
    ORN ("orthotropic equivalent of the natural closure") and recommends it (Tucker
    2022, *Fundamentals of Fiber Orientation*, ch. 5).
    """
    return orthotropic_from_diagonal(a2, _ORE)


def orf(a2: jax.Array) -> jax.Array:
    """Orthotropic fitted closure ORF (Cintra & Tucker 1995, J. Rheol. 39(6):1095-1122).

    ``A_mm = C_m1 + C_m2 a1 + C_m3 a1^2 + C_m4 a2 + C_m5 a2^2 + C_m6 a1 a2`` (m = 1..3),
    fitted to Folgar-Tucker solutions; see the module docstring for the rest.
    """
    return orthotropic_from_diagonal(a2, _ORF)


def orl(a2: jax.Array) -> jax.Array:
    """Orthotropic fitted closure for low interaction, ORL (Cintra & Tucker 1995,
    J. Rheol. 39(6):1095), same quadratic form as :func:`orf`, fitted to low C_I."""
    return orthotropic_from_diagonal(a2, _ORL)


def orw(a2: jax.Array) -> jax.Array:
    """Orthotropic closure for a wide interaction range, ORW (Chung & Kwon 2001,
    Polym. Compos. 22(5):636-649), same quadratic form as :func:`orf`."""
    return orthotropic_from_diagonal(a2, _ORW)


def orw3(a2: jax.Array) -> jax.Array:
    """Third-order orthotropic closure ORW3 (Chung & Kwon 2001, Polym. Compos. 22(5):636).

    ``A_mm = sum_k C_mk w_k`` with the cubic basis
    ``w = (1, a1, a1^2, a2, a2^2, a1 a2, a1^2 a2, a1 a2^2, a1^3, a2^3)``.
    """
    return orthotropic_from_diagonal(a2, _ORW3)
