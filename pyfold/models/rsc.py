"""Reduced-strain-closure (RSC) model and the principal-frame slow-down it rests on."""
from __future__ import annotations

from typing import ClassVar

from pyfold._jax import jax
from pyfold.models._base import ClosureModel, parameter
from pyfold.models._terms import (
    flow_parts,
    isotropic_diffusion,
    principal_projection,
    rotation_term,
    stretching_term,
)


def reduce_principal_rate(a2: jax.Array, x: jax.Array, kappa) -> jax.Array:
    """RSC slow-down of a rate ``x``: ``x - (1 - kappa) M4 : x``.

    Only the part of ``x`` that changes the eigenvalues of ``a2`` is scaled by
    ``kappa``; the rotation of the principal axes is untouched (Wang, O'Gara &
    Tucker 2008, J. Rheol. 52:1179). With ``M4:x`` written as the principal
    projection this is algebraically identical to their
    ``a4 -> a4 + (1-kappa)(L4 - M4:a4)`` and ``2 kappa C_I gamma_dot (I - 3a)``
    (because ``M4:(D.a + a.D) = 2 L4:D`` and ``M4:(I - 3a) = I - 3a``), and it is
    well defined at repeated eigenvalues (see :mod:`pyfold.models._terms`).
    """
    return x - (1.0 - kappa) * principal_projection(a2, x)


class RSC(ClosureModel):
    """Reduced strain closure model (Wang, O'Gara & Tucker 2008, J. Rheol. 52:1179).

    ``Da/Dt = W.a - a.W + xi (D.a + a.D - 2 [a4 + (1-kappa)(L4 - M4:a4)]:D)
    + 2 kappa C_I gamma_dot (I - d a)``

    with ``L4 = sum_i l_i e_i e_i e_i e_i`` and ``M4 = sum_i e_i e_i e_i e_i`` built
    on the eigenvalues ``l_i`` and axes ``e_i`` of ``a2``. ``kappa = 1`` is exactly
    Folgar-Tucker; ``kappa < 1`` slows the eigenvalue kinetics by ``kappa``
    without changing the axes' rotation (objective, unlike the SRF slip factor).

    At repeated eigenvalues (isotropic start) the principal projection keeps the
    whole degenerate block, so at ``a2 = I/d`` the rate is ``kappa`` times the FT
    rate — finite, basis-independent and with finite derivatives.

    Parameters
    ----------
    ci : float
        Interaction coefficient ``C_I >= 0``.
    kappa : float
        Strain reduction factor in (0, 1].
    xi, closure, dim
        As in :class:`~pyfold.models.FolgarTucker`.

    Notes
    -----
    **Eigenvalue crossings (ill-posedness).** The model is ill-posed where two
    eigenvalues ``l_i, l_j`` of ``a2`` cross. Take the ``(i, j)`` block in the principal frame, with gap ``g = l_i - l_j``
    and unreduced eigenvalue rates ``f_i, f_j``. RSC scales the eigenvalue rates,
    so ``dg/dt = kappa (f_i - f_j)``, but not the rotation of the axes: an
    off-diagonal perturbation ``eps`` tilts the axes by ``eps/g``, and the
    subtracted part ``(1 - kappa) M4:(...)`` evaluated in the tilted frame feeds
    back ``(1 - kappa)(f_j - f_i) eps/g`` into ``deps/dt``. Closing the gap
    (``f_i < f_j``) therefore gives ``d ln eps / d ln g = -(1 - kappa)/kappa``,
    i.e. ``eps ~ |g|^-(1-kappa)/kappa``: any perturbation, round-off included,
    grows without bound as the eigenvalues meet (``kappa = 0.1``: as ``g^-9``),
    and round-off decides the path taken after the crossing. (pyfold's principal
    projection averages eigenvalues closer than ``GAP_WIDTH = 1e-6``, which keeps
    the rate finite but not the sensitivity.) ``kappa = 1`` (FT) is well-posed.

    **What pyfold does.** The model has ``uses_eigenvectors = True``;
    :func:`~pyfold.models.solve_orientation` and :func:`~pyfold.models.solve_batch`
    follow the eigenvectors through the saved states, and when two eigenvalues
    cross they record the (interpolated) time in
    ``OrientationSolution.crossing_time`` and emit a
    :class:`pyfold.errors.EigenvalueCrossingWarning` stating it. A degeneracy
    already present at the initial time (isotropic or transversely isotropic
    start) that only splits is not a crossing and is not reported.
    """

    uses_eigenvectors: ClassVar[bool] = True

    ci: jax.Array = parameter(0.01, low=0.0)
    kappa: jax.Array = parameter(0.1, low=0.0, high=1.0)

    def _rate(self, t, a2, L):
        D, W, gamma_dot = flow_parts(L)
        a4 = self.a4(a2, t)
        principal = stretching_term(a2, a4, D, self.xi) + isotropic_diffusion(a2, self.ci, gamma_dot)
        return rotation_term(a2, W) + reduce_principal_rate(a2, principal, self.kappa)
