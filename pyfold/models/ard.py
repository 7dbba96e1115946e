"""Anisotropic rotary diffusion models: ARD-RSC, iARD, iARD-RPR, pARD, pARD-RPR.

All share the ARD term of Phelps & Tucker (2009) with a model-specific
dimensionless diffusivity tensor ``C`` (``D_r = gamma_dot C``), see
:func:`pyfold.models._terms.ard_diffusion`; they differ in ``C`` and in the
principal-frame kinetics (RSC: Wang et al. 2008; RPR: Tseng et al. 2013).
"""
from __future__ import annotations

import abc

from typing import ClassVar

from pyfold._jax import jax, jnp
from pyfold.errors import InputError
from pyfold.models._base import ClosureModel, parameter
from pyfold.models._terms import (
    ard_diffusion,
    flow_parts,
    mat,
    principal_projection,
    principal_tensor,
    rotation_term,
    stretching_term,
)
from pyfold.models.rsc import reduce_principal_rate


def _safe_inverse(gamma_dot):
    # 1/gamma_dot where the flow is at rest would be inf; the ARD term is multiplied
    # by gamma_dot and D = 0 there, so any finite stand-in gives the exact 0.
    positive = gamma_dot > 0.0
    return jnp.where(positive, 1.0 / jnp.where(positive, gamma_dot, 1.0), 0.0)


def rpr_correction(a2: jax.Array, x: jax.Array, alpha, beta) -> jax.Array:
    """Retarding-principal-rate term ``R . diag(IOK) . R^T`` subtracted from the rate.

    Tseng, Chang & Hsu (2013, J. Rheol. 57:1597): with ``y_i`` the rates of the
    eigenvalues of ``a2`` (diagonal of the rate ``x`` in the principal frame),
    ``IOK_i = alpha [y_i - beta (y_i^2 + 2 y_j y_k)]`` ({i, j, k} a permutation of
    {1, 2, 3}). With ``Y = M4 : x`` (the principal projection) the same thing in
    matrix form is ``alpha [Y - beta (3 Y^2 - 2 tr(Y) Y + (tr(Y)^2 - tr(Y^2)) I)]``
    (component ``3y_i^2 - 2 s y_i + s^2 - sum y^2 = y_i^2 + 2 y_j y_k``), which is
    basis independent at repeated eigenvalues. The ``beta`` term has no planar
    analogue and is 3-D only.
    """
    y = principal_projection(a2, x)
    if a2.shape[-1] == 2:
        return alpha * y
    eye = jnp.eye(3)
    tr = jnp.trace(y, axis1=-2, axis2=-1)[..., None, None]
    tr_sq = jnp.einsum("...ij,...ji->...", y, y)[..., None, None]
    quadratic = 3.0 * mat(y, y) - 2.0 * tr * y + (tr**2 - tr_sq) * eye
    return alpha * (y - beta * quadratic)


class _ARDBase(ClosureModel):
    """Hydrodynamic + ARD term for the subclass's ``diffusivity(a2, D, gamma_dot)``."""

    @abc.abstractmethod
    def diffusivity(self, a2, D, gamma_dot):
        """The ARD diffusion tensor ``C`` of the subclass's model."""

    def _principal_and_rotation(self, t, a2, L):
        D, W, gamma_dot = flow_parts(L)
        a4 = self.a4(a2, t)
        C = self.diffusivity(a2, D, gamma_dot)
        principal = stretching_term(a2, a4, D, self.xi) + ard_diffusion(a2, a4, C, gamma_dot)
        return principal, rotation_term(a2, W)

    def _rate(self, t, a2, L):
        principal, rotation = self._principal_and_rotation(t, a2, L)
        return rotation + principal


class ARDRSC(_ARDBase):
    """ARD-RSC model (Phelps & Tucker 2009, J. Non-Newt. Fluid Mech. 156:165).

    ``C = b1 I + b2 a + b3 a.a + (b4/gamma_dot) D + (b5/gamma_dot^2) D.D``,

    ``Da/Dt = W.a - a.W + xi (D.a + a.D - 2 a4_rsc:D)
    + gamma_dot [2 (C - (1-kappa) M4:C) - 2 kappa tr(C) a - 5 (C.a + a.C) + 10 a4_rsc:C]``

    with ``a4_rsc = a4 + (1-kappa)(L4 - M4:a4)``, i.e. the RSC slow-down
    (:func:`~pyfold.models.rsc.reduce_principal_rate`) applied to the hydrodynamic
    stretching + ARD terms; in 2-D the ARD coefficients are ``d + 2 = 4`` and
    ``2(d + 2) = 8``. ``b = (C_I, 0, 0, 0, 0)`` with ``kappa = 1`` is Folgar-Tucker.

    The ``b4`` term is ``b4 D / gamma_dot`` as in the paper. (Tucker's
    Fiber-Orientation-Tools ``Adot2.m`` codes ``b4 D.D / gamma_dot``, which is not
    dimensionless; we follow the paper.) Defaults are Phelps & Tucker's fit for
    long-glass-fibre polypropylene: b1 = 1.924e-4, b2 = 5.839e-3, b3 = 0.04,
    b4 = 1.168e-5, b5 = 0, kappa = 1/30.

    Eigenvalue crossings: the RSC slow-down makes the model ill-posed where two
    eigenvalues of ``a2`` cross (a perturbation of the axes grows like
    ``|gap|^-(1-kappa)/kappa``, see :class:`~pyfold.models.RSC`); the solvers
    detect crossings and warn (``uses_eigenvectors = True``).
    """

    uses_eigenvectors: ClassVar[bool] = True

    b1: jax.Array = parameter(1.924e-4)
    b2: jax.Array = parameter(5.839e-3)
    b3: jax.Array = parameter(0.04)
    b4: jax.Array = parameter(1.168e-5)
    b5: jax.Array = parameter(0.0)
    kappa: jax.Array = parameter(1.0 / 30.0, low=0.0, high=1.0)

    def diffusivity(self, a2, D, gamma_dot):
        inv = _safe_inverse(gamma_dot)
        eye = jnp.eye(a2.shape[-1])
        return (
            self.b1 * eye
            + self.b2 * a2
            + self.b3 * mat(a2, a2)
            + self.b4 * inv * D
            + self.b5 * inv**2 * mat(D, D)
        )

    def _rate(self, t, a2, L):
        principal, rotation = self._principal_and_rotation(t, a2, L)
        return rotation + reduce_principal_rate(a2, principal, self.kappa)


def _iard_diffusivity(ci, cm, D, gamma_dot):
    # Tseng, Chang & Hsu 2016: C = C_I (I - C_M D.D / ||D.D||), ||X|| = sqrt(X:X / 2).
    # For a traceless D (incompressible flow, d = 2 or 3) the Newton identity
    # tr(D^4) = tr(D^2)^2 / 2 gives ||D.D|| = gamma_dot^2 / 4, the form used here and
    # in Tucker's Fiber-Orientation-Tools (C_I (I - 4 C_M D.D / gamma_dot^2)).
    inv = _safe_inverse(gamma_dot)
    d = D.shape[-1]
    return ci * (jnp.eye(d) - 4.0 * cm * inv**2 * mat(D, D))


class IARD(_ARDBase):
    """Improved ARD model, iARD (Tseng, Chang & Hsu 2016, J. Rheol. 60:215).

    ARD term (:func:`~pyfold.models._terms.ard_diffusion`) with
    ``C = C_I (I - C_M D.D/||D.D||) = C_I (I - 4 C_M D.D / gamma_dot^2)``
    (equal for incompressible flow). ``C_M = 0`` is exactly Folgar-Tucker with the
    same ``C_I``. In 2-D, ``D.D = (gamma_dot^2/4) I`` for any planar traceless ``D``
    (Cayley-Hamilton), so planar iARD is FT with ``C_I (1 - C_M)``.

    Defaults: Tucker (2022, *Fundamentals of Fiber Orientation*, Table 5.3) fit
    ``C_I = 0.0627, C_M = 0.9908``.
    """

    ci: jax.Array = parameter(0.0627, low=0.0)
    cm: jax.Array = parameter(0.9908, low=0.0, high=1.0)

    def diffusivity(self, a2, D, gamma_dot):
        return _iard_diffusivity(self.ci, self.cm, D, gamma_dot)


def _check_beta_dim(beta, dim: int) -> None:
    if dim == 2 and not isinstance(beta, jax.core.Tracer) and float(jnp.max(jnp.abs(beta))) != 0.0:
        raise InputError("beta: the RPR beta term (y_i^2 + 2 y_j y_k) is defined in 3-D only; use beta = 0 with dim = 2")


class IARDRPR(_ARDBase):
    """iARD with retarding principal rate, iARD-RPR (Tseng, Chang & Hsu 2013,
    J. Rheol. 57:1597; 2016, J. Rheol. 60:215).

    ``Da/Dt = (iARD rate) - R diag(IOK) R^T``, ``IOK`` from :func:`rpr_correction`
    applied to the iARD rate without its rotation term (whose principal part is
    zero). ``alpha = 0`` is iARD. Parameters ``ci, cm`` as in :class:`IARD`;
    ``alpha`` in [0, 1); ``beta`` (3-D only) the nonlinear retardance of the RPR
    paper, 0 by default.

    Eigenvalue crossings: the RPR term retards the eigenvalue rates only, like the
    RSC slow-down with ``kappa = 1 - alpha`` (``beta = 0``), so the model is
    ill-posed where two eigenvalues of ``a2`` cross (perturbations of the axes
    grow like ``|gap|^-alpha/(1-alpha)``, see :class:`~pyfold.models.RSC`); the
    solvers detect crossings and warn (``uses_eigenvectors = True``, also for
    ``alpha = 0``, where the model is iARD and the warning is only a caution).
    """

    uses_eigenvectors: ClassVar[bool] = True

    ci: jax.Array = parameter(0.0627, low=0.0)
    cm: jax.Array = parameter(0.9908, low=0.0, high=1.0)
    alpha: jax.Array = parameter(0.0, low=0.0, high=1.0)
    beta: jax.Array = parameter(0.0)

    def __check_init__(self):
        _check_beta_dim(self.beta, self.dim)

    def diffusivity(self, a2, D, gamma_dot):
        return _iard_diffusivity(self.ci, self.cm, D, gamma_dot)

    def _rate(self, t, a2, L):
        principal, rotation = self._principal_and_rotation(t, a2, L)
        return rotation + principal - rpr_correction(a2, principal, self.alpha, self.beta)


def _pard_coefficients(omega, dim: int):
    # Tseng, Chang & Hsu 2018: diag(1, Omega, 1 - Omega) in the principal frame of a2
    # (descending eigenvalues). Planar: the in-plane block diag(1, Omega) of the 3-D
    # tensor when the out-of-plane axis is the third principal axis.
    if dim == 3:
        return jnp.stack([jnp.ones_like(omega), omega, 1.0 - omega])
    return jnp.stack([jnp.ones_like(omega), omega])


class PARD(_ARDBase):
    """Principal ARD model, pARD (Tseng, Chang & Hsu, J. Rheol. 62:313, 2018,
    online 2017: "The use of principal spatial tensor to predict anisotropic fiber
    orientation in concentrated fiber suspensions").

    ARD term with ``C = C_I R diag(1, Omega, 1 - Omega) R^T``, ``R`` the principal
    axes of ``a2`` in descending order of eigenvalue. Planar (``dim = 2``):
    ``C = C_I R diag(1, Omega) R^T`` (the in-plane block of the 3-D tensor), so
    ``Omega = 1`` is exactly 2-D Folgar-Tucker. In 3-D no ``Omega`` gives FT
    (``tr C = 2 C_I`` always); ``Omega = 1`` makes pARD the MRD model with
    ``(D1, D2, D3) = (1, 1, 0)``.

    Repeated eigenvalues: coefficients of a degenerate cluster are averaged
    (:func:`~pyfold.models._terms.principal_tensor`), so at isotropy
    ``C = (2/3) C_I I`` in 3-D, the only isotropic choice with the published trace.

    Defaults: Tucker (2022) Table 5.3 fit ``C_I = 0.0218, Omega = 0.9673``.

    Eigenvalue crossings: the coefficients ``(1, Omega, 1 - Omega)`` are attached
    to the eigenvalues by their *order*, so ``C`` jumps where two eigenvalues of
    ``a2`` cross (pyfold smooths the jump over a gap of ``GAP_WIDTH = 1e-6``, see
    :mod:`pyfold.models._terms`); a tilt ``eps/gap`` of the axes changes ``C`` by
    ``(c_i - c_j) eps/gap``, so near a crossing the rate is as sensitive to the
    axes as RSC's (:class:`~pyfold.models.RSC`) and round-off decides the path.
    The solvers detect crossings and warn (``uses_eigenvectors = True``).
    """

    uses_eigenvectors: ClassVar[bool] = True

    ci: jax.Array = parameter(0.0218, low=0.0)
    omega: jax.Array = parameter(0.9673, low=0.0, high=1.0)

    def diffusivity(self, a2, D, gamma_dot):
        return self.ci * principal_tensor(a2, _pard_coefficients(self.omega, a2.shape[-1]))


class PARDRPR(PARD):
    """pARD with retarding principal rate, pARD-RPR (Tseng, Chang & Hsu 2018, as
    for :class:`PARD`; RPR of Tseng et al. 2013).

    ``Da/Dt = (pARD rate) - alpha R diag(y) R^T`` with ``y`` the eigenvalue rates
    of the pARD rate (the linear RPR, ``beta = 0``, as in fiberoripy's
    ``pardrpr_ode`` and Tucker's ``Adot2.m`` with ``kappa = 1 - alpha``).

    Eigenvalue crossings: ill-posed there for both reasons of :class:`PARD` and
    :class:`~pyfold.models.RSC` (``kappa = 1 - alpha``); detected and warned
    about by the solvers (``uses_eigenvectors = True``, inherited).
    """

    alpha: jax.Array = parameter(0.0, low=0.0, high=1.0)

    def _rate(self, t, a2, L):
        principal, rotation = self._principal_and_rotation(t, a2, L)
        return rotation + principal - rpr_correction(a2, principal, self.alpha, 0.0)
