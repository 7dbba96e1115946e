"""Moldflow rotational diffusion (MRD) model."""
from __future__ import annotations

from typing import ClassVar

from pyfold._jax import jax, jnp
from pyfold.models._base import parameter
from pyfold.models._terms import principal_tensor
from pyfold.models.ard import _ARDBase


class MRD(_ARDBase):
    """Moldflow rotational diffusion model (Bakharev, Yu, Speight & Wang 2018,
    ANTEC, Orlando).

    **Definition used: the ARD-operator form** of Tucker's Fiber-Orientation-Tools
    (``Adot2.m``), fiberoripy (``mrd_ode``) and Favaloro & Tucker (2019,
    Composites A 126:105605): the Phelps-Tucker ARD term
    (:func:`~pyfold.models._terms.ard_diffusion`) with

    ``C = C_I R diag(D1, D2, D3) R^T``

    (``R`` the principal axes of ``a2``, eigenvalues descending). The other form in
    circulation, ``2 C_I gamma_dot (D_r - tr(D_r) a)``, is *not* implemented.
    ``D1 = D2 = D3 = 1`` is exactly Folgar-Tucker. Planar: ``diag(D1, D2)``.
    Repeated eigenvalues are handled as in :class:`~pyfold.models.PARD`.

    Defaults ``D1, D2, D3 = 1, 0.8, 0.15`` (fiberoripy's defaults).

    Eigenvalue crossings: ``D1, D2, D3`` are attached to the eigenvalues by their
    order, so, as for :class:`~pyfold.models.PARD`, the model is ill-posed where
    two eigenvalues of ``a2`` cross (a tilt of the axes by ``eps/gap`` changes
    ``C`` by ``C_I (D_i - D_j) eps/gap``); the solvers detect crossings and warn
    (``uses_eigenvectors = True``).
    """

    uses_eigenvectors: ClassVar[bool] = True

    ci: jax.Array = parameter(0.01, low=0.0)
    d1: jax.Array = parameter(1.0, low=0.0)
    d2: jax.Array = parameter(0.8, low=0.0)
    d3: jax.Array = parameter(0.15, low=0.0)

    def diffusivity(self, a2, D, gamma_dot):
        coeffs = [self.d1, self.d2, self.d3][: a2.shape[-1]]
        return self.ci * principal_tensor(a2, jnp.stack(coeffs))
