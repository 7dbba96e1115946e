"""Folgar-Tucker model and its Maier-Saupe extension (FTMS)."""
from __future__ import annotations

from pyfold._jax import jax
from pyfold.models._base import ClosureModel, parameter
from pyfold.models._terms import (
    flow_parts,
    isotropic_diffusion,
    mat,
    rotation_term,
    stretching_term_contracted,
)


def _folgar_tucker_rate(model: ClosureModel, t, a2, L):
    # Jeffery's rotation and stretching (a4:D from the model's closure) plus isotropic
    # rotary diffusion with the model's ci, xi: the Folgar-Tucker rate.
    D, W, gamma_dot = flow_parts(L)
    return (
        rotation_term(a2, W)
        + stretching_term_contracted(a2, model.a4_contract(a2, D, t), D, model.xi)
        + isotropic_diffusion(a2, model.ci, gamma_dot)  # type: ignore[attr-defined]
    )


class FolgarTucker(ClosureModel):
    """Folgar-Tucker model (Folgar & Tucker 1984, J. Reinf. Plast. Compos. 3:98).

    ``Da/Dt = W.a - a.W + xi (D.a + a.D - 2 a4:D) + 2 C_I gamma_dot (I - d a)``

    with ``a4`` from the closure, ``gamma_dot = sqrt(2 D:D)`` and ``d = 3`` (space) or
    ``d = 2`` (planar orientation). ``C_I = 0`` is Jeffery's equation.

    Parameters
    ----------
    ci : float
        Interaction coefficient ``C_I >= 0`` (typically 1e-4 ... 3e-2).
    xi : float
        Shape factor ``(beta^2 - 1)/(beta^2 + 1)`` in [-1, 1].
    closure : str | callable | TabulatedA4
        Closure for ``a4`` (see :func:`pyfold.closures.resolve`).
    dim : int
        3 or 2.
    """

    ci: jax.Array = parameter(0.01, low=0.0)

    def _rate(self, t, a2, L):
        return _folgar_tucker_rate(self, t, a2, L)


class FTMS(ClosureModel):
    """Folgar-Tucker model with a Maier-Saupe potential (FTMS).

    ``Da/Dt = W.a - a.W + xi (D.a + a.D - 2 a4:D)
    + 2 gamma_dot [C_I (I - d a) + U_0 (a.a - a4:a)]``

    This is the definition used by fiberoripy (``maier_saupe_ode``), taken from
    Latz, Strautins & Niedziela (2010, J. Non-Newt. Fluid Mech. 165:764); the
    excluded-volume potential ``-U_0 gamma_dot pp:a`` acting against rotary
    diffusion goes back to Maier & Saupe (1958) and its use for rod suspensions to
    Doi (1981) and Kuzuu & Doi (1983). The drift term ``a.a - a4:a`` has the same
    form in 2-D (it comes from the projected gradient of ``pp:a``, which carries
    no dimension factor); the diffusion term uses ``d``. ``U_0 = 0`` is exactly
    Folgar-Tucker.

    Parameters
    ----------
    ci : float
        Interaction coefficient ``C_I >= 0``.
    u0 : float
        Maier-Saupe potential strength ``U_0`` (dimensionless, >= 0).
    xi, closure, dim
        As in :class:`FolgarTucker`.
    """

    ci: jax.Array = parameter(0.01, low=0.0)
    u0: jax.Array = parameter(0.0, low=0.0)

    def _rate(self, t, a2, L):
        _, _, gamma_dot = flow_parts(L)
        potential = 2.0 * self.u0 * gamma_dot * (mat(a2, a2) - self.a4_contract(a2, a2, t))
        return _folgar_tucker_rate(self, t, a2, L) + potential
