"""Natural closures: the planar closed form and pyfold's own 3-D fit of the natural form.

References for the form: Verleye & Dupret (1993), *Numerical prediction of fiber
orientation in complex injection molded parts*, ASME MD 49:264; Dupret & Verleye
(1999), in *Advances in the Flow and Rheology of Non-Newtonian Fluids*, Elsevier
(the form, not the coefficient tables, is reprinted in the Advani & Sims and the
Kennedy & Zheng textbooks); the trace conditions that leave three free coefficients:
Chung & Kwon (2002), J. Rheol. 46:169, eq. 26.
"""
from __future__ import annotations

import numpy as np

from pyfold._jax import jax, jnp
from pyfold.tensors import det
from pyfold.closures._basis import identity_like, sym_product
from pyfold.closures._invariant_form import invariant_form, invariant_form_contract, monomials
from pyfold.closures import _natural_fit as FIT


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
    The 3-D counterpart is :func:`natural_3d` (pyfold's own fit of the natural form).
    """
    if a2.shape[-1] != 2:
        raise ValueError("natural_2d is the planar closure; a2 must be (..., 2, 2)")
    eye = identity_like(a2)
    det_a = det(a2)[..., None, None, None, None]
    return 0.5 * det_a * sym_product(eye, eye) + sym_product(a2, a2)


def natural_form(a2: jax.Array, coefficients, exponents) -> jax.Array:
    """The 3-D natural form with polynomial coefficients given explicitly.

    ``b3``, ``b4``, ``b6`` (rows of ``coefficients``) are polynomials
    ``sum_m c_m II^p_m III^q_m`` over ``exponents = ((p_m, q_m), ...)``; ``b1``, ``b2``,
    ``b5`` follow from the trace conditions
    (:func:`pyfold.closures._invariant_form.invariant_form`). Affine in
    ``coefficients``, which is what the fit script exploits (linear least squares).

    Parameters
    ----------
    a2 : array (..., 3, 3)
    coefficients : array (3, n_monomials)
    exponents : sequence of (int, int), length n_monomials
    """
    return invariant_form(a2, *_natural_betas(a2, coefficients, exponents))


def _natural_betas(a2: jax.Array, coefficients, exponents):
    if a2.shape[-1] != 3:
        raise ValueError("the 3-D natural form needs a2 of shape (..., 3, 3)")
    mono = monomials(a2, exponents)
    return tuple(jnp.einsum("...m,m->...", mono, coefficients[k]) for k in range(3))


_COEFFICIENTS = np.asarray(FIT.COEFFICIENTS, dtype=np.float64)


def natural_3d(a2: jax.Array) -> jax.Array:
    """3-D natural closure with coefficients fitted by pyfold (not NAT1/NAT2's numbers).

    Form (Verleye & Dupret 1993; Dupret & Verleye 1999):

        a4 = b1 S(d d) + b2 S(d a) + b3 S(a a) + b4 S(d a.a) + b5 S(a a.a) + b6 S(a.a a.a)

    with ``S`` the full symmetrisation and the ``b``'s functions of the invariants
    ``II`` (sum of principal 2x2 minors) and ``III = det a``. The trace conditions fix
    ``b1``, ``b2``, ``b5`` (Chung & Kwon 2002, J. Rheol. 46:169, eq. 26); ``b3``, ``b4``,
    ``b6`` are here full quadratics in (II, III): ``1, II, III, II^2, II III, III^2``
    (18 coefficients).

    **The coefficients are pyfold's own least-squares fit**, made by
    ``studies/closures/fit_natural_closure.py`` and stored in
    :mod:`pyfold.closures._natural_fit` (with the fitting date and residuals), to the
    exact closure of Jeffery's equation (:func:`pyfold.closures.exact.fec`), which is
    what the published NAT1/NAT2 were fitted to (C_I = 0, infinite aspect ratio). The
    published NAT1/NAT2 coefficient tables could not be obtained, so this is *not*
    NAT1 or NAT2 and its numbers must not be quoted as theirs.

    Limits:

    * isotropy: exact, for any coefficients (trace conditions, see
      :func:`~pyfold.closures._invariant_form.invariant_form`);
    * aligned fibres (II = III = 0): exact, imposed in the fit as the linear
      condition ``b1(0, 0) = 0`` (with the trace conditions it also makes
      ``b2(0, 0) + b4(0, 0) = 0``, i.e. ``A_1122 = A_1133 = A_2233 = 0``);
    * planar states (III = 0): finite and smooth (the b's are polynomials), but not
      exact. Exactness on the whole planar edge requires ``b1 = b2 = b4 = 0``,
      ``b6 = 1/(2 II)``, ``b3 = 1 + b6`` there, unbounded as II -> 0 (towards aligned):
      no polynomial can meet it, and a rational fit that did would be singular near
      aligned planar states. The largest error of the fit is on that edge
      (``_natural_fit.FIT_MAX_ERROR``).

    Fully symmetric, trace-exact to round-off, rotation-equivariant and smooth
    everywhere (no eigen-decomposition), so its derivative is exact also at repeated
    eigenvalues.
    """
    return natural_form(a2, _COEFFICIENTS, FIT.EXPONENTS)


def natural_3d_contract(a2: jax.Array, D: jax.Array) -> jax.Array:
    """``natural_3d(a2) : D`` without forming a4 (same value to round-off)."""
    return invariant_form_contract(a2, *_natural_betas(a2, _COEFFICIENTS, FIT.EXPONENTS), D)
