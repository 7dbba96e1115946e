"""Building blocks shared by the orientation models (pure, jit/vmap/grad-able).

Every model of this package is the Jeffery (1922) hydrodynamic term plus a
diffusion-like term, optionally filtered in the principal frame of ``a2``
(RSC/RPR). The terms are written for ``d = 3`` and ``d = 2`` (planar) at once.

Repeated eigenvalues
--------------------
RSC, ARD-RSC, RPR, pARD and MRD use the principal axes of ``a2``, which are not
unique when eigenvalues repeat (an isotropic start, or a transversely isotropic
state). Two objects are needed and both are made *basis independent* here by a
Gaussian weight over eigenvalue gaps, ``w_ij = exp(-((l_i - l_j) / GAP_WIDTH)^2)``:

* the principal projection ``P(X) = sum_ij w_ij E_i X E_j`` (``E_i`` the spectral
  projectors). For separated eigenvalues (gap >> GAP_WIDTH, the weight underflows
  to exactly 0) it is the published ``M4 : X = sum_i e_i e_i (e_i.X.e_i)``; inside
  a degenerate cluster it keeps the whole block of ``X``, which is what
  degenerate perturbation theory gives for eigenvalue rates (the eigenvectors that
  emerge from a degenerate state are those that diagonalise the rate). At exact
  isotropy ``P(X) = X``.
* a principal tensor ``sum_i c_i e_i e_i`` (pARD, MRD): each coefficient is
  replaced by its weighted mean over the cluster of (nearly) equal eigenvalues,
  so at isotropy the tensor is ``mean(c) I`` — the only isotropic tensor function
  of ``a2 = I/d`` with the published trace.

Both are smooth functions of ``a2``; derivatives of the axes come from
:func:`pyfold.tensors.eigen_frame`, whose regularised eigenvector derivative is
finite at degeneracy.
"""
from __future__ import annotations

from pyfold._jax import jax, jnp
from pyfold.kinematics import rate_of_strain, shear_rate, vorticity
from pyfold.tensors import contract4, eigen_frame

#: Eigenvalue gap [dimensionless; eigenvalues of a2 lie in [0, 1]] below which two
#: principal directions are treated as one degenerate cluster. Far above round-off
#: (1e-16) and the eigenvector-derivative regularisation of pyfold.tensors (1e-9),
#: far below any anisotropy a model or a measurement resolves. Beyond ~6 widths
#: the weight is exactly 0, i.e. the published formulas are used unchanged.
GAP_WIDTH = 1e-6


def mat(a: jax.Array, b: jax.Array) -> jax.Array:
    """Matrix product over the last two axes."""
    return jnp.einsum("...ik,...kj->...ij", a, b)


def symmetrise(x: jax.Array) -> jax.Array:
    """``(x + x^T) / 2`` over the last two axes."""
    return 0.5 * (x + jnp.swapaxes(x, -1, -2))


def flow_parts(L: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(D, W, gamma_dot)`` of a velocity gradient ``L_ij = du_i/dx_j``."""
    return rate_of_strain(L), vorticity(L), shear_rate(L)


def rotation_term(a2: jax.Array, W: jax.Array) -> jax.Array:
    """Co-rotation with the vorticity, ``W.a - a.W`` (Jeffery 1922)."""
    return mat(W, a2) - mat(a2, W)


def stretching_term(a2: jax.Array, a4: jax.Array, D: jax.Array, xi) -> jax.Array:
    """Alignment by the rate of strain, ``xi (D.a + a.D - 2 a4:D)`` (Jeffery 1922;
    moment form of Advani & Tucker 1987, J. Rheol. 31:751)."""
    return stretching_term_contracted(a2, contract4(a4, D), D, xi)


def stretching_term_contracted(a2: jax.Array, a4_D: jax.Array, D: jax.Array, xi) -> jax.Array:
    """:func:`stretching_term` given ``a4:D`` directly (models that need nothing else
    of a4 use the closure's cheaper contraction)."""
    return xi * (mat(D, a2) + mat(a2, D) - 2.0 * a4_D)


def isotropic_diffusion(a2: jax.Array, ci, gamma_dot) -> jax.Array:
    """Folgar & Tucker (1984) isotropic rotary diffusion ``2 C_I gamma_dot (I - d a)``.

    ``d`` is the dimension: the Laplace-Beltrami operator on the unit sphere (d = 3)
    or circle (d = 2) maps ``p_i p_j`` to ``2 delta_ij - 2 d p_i p_j``.
    """
    d = a2.shape[-1]
    return 2.0 * ci * gamma_dot * (jnp.eye(d) - d * a2)


def ard_diffusion(a2: jax.Array, a4: jax.Array, Dr: jax.Array, gamma_dot) -> jax.Array:
    """Anisotropic rotary diffusion term of the ``a2`` equation.

    ``gamma_dot [2 C - 2 tr(C) a - (d+2)(C.a + a.C) + 2(d+2) a4:C]`` for a
    dimensionless diffusivity tensor ``C`` (``D_r = gamma_dot C``). In 3-D this is
    the ARD term of Phelps & Tucker (2009, J. Non-Newt. Fluid Mech. 156:165),
    ``2C - 2 tr(C) a - 5(C.a + a.C) + 10 a4:C``. The general-``d`` coefficients
    come from averaging ``div_s((I-pp).C.(I-pp).grad_s(p_i p_j))`` over the unit
    sphere of R^d; ``C = C_I I`` gives back :func:`isotropic_diffusion`.
    """
    d = a2.shape[-1]
    tr = jnp.trace(Dr, axis1=-2, axis2=-1)[..., None, None]
    return gamma_dot * (
        2.0 * Dr
        - 2.0 * tr * a2
        - (d + 2.0) * (mat(Dr, a2) + mat(a2, Dr))
        + 2.0 * (d + 2.0) * contract4(a4, Dr)
    )


def _gap_weights(values: jax.Array) -> jax.Array:
    gap = values[..., :, None] - values[..., None, :]
    return jnp.exp(-((gap / GAP_WIDTH) ** 2))


def principal_projection(a2: jax.Array, x: jax.Array) -> jax.Array:
    """Part of ``x`` that changes the eigenvalues of ``a2``: ``M4 : x`` made basis-free.

    ``sum_i e_i e_i (e_i.x.e_i)`` with ``e_i`` the principal axes of ``a2`` (the
    ``M : x`` of Wang, O'Gara & Tucker 2008, J. Rheol. 52:1179), extended to
    repeated eigenvalues as explained in the module docstring.
    """
    values, vecs = eigen_frame(a2)
    x_principal = jnp.einsum("...ki,...kl,...lj->...ij", vecs, x, vecs)
    return jnp.einsum("...ik,...kl,...jl->...ij", vecs, _gap_weights(values) * x_principal, vecs)


def principal_tensor(a2: jax.Array, coefficients: jax.Array) -> jax.Array:
    """``sum_i c_i e_i e_i`` with ``e_i`` the principal axes of ``a2`` in descending
    order of eigenvalue; coefficients of (nearly) equal eigenvalues are averaged
    (module docstring), so the result is well defined at degeneracy."""
    values, vecs = eigen_frame(a2)
    w = _gap_weights(values)
    c = jnp.einsum("...ij,j->...i", w, coefficients) / jnp.sum(w, axis=-1)
    return jnp.einsum("...ik,...k,...jk->...ij", vecs, c, vecs)
