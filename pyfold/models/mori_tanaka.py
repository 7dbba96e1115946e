"""Jeffery-type orientation equation with Mori-Tanaka fibre interaction."""
from __future__ import annotations

from pyfold._jax import jax
from pyfold.models._base import ClosureModel, parameter
from pyfold.models._terms import flow_parts, mat, rotation_term, stretching_term


class MoriTanaka(ClosureModel):
    """Mori-Tanaka modified Jeffery equation (Karl & Böhlke 2023, "Generalized
    micromechanical formulation of fiber orientation tensor evolution equations",
    Int. J. Mech. Sci., doi:10.1016/j.ijmecsci.2023.108771; as implemented in
    fiberoripy's ``mori_tanaka_ode``).

    ``Da/Dt = W.a - a.W + xi/(1-c_f) (D.a + a.D - 2 a4:D)
    - xi c_f/(1-c_f) (D.a.a + a.a.D - 2 a.D.a)``

    with fibre volume fraction ``c_f``: the strain rate seen by the fibres is the
    Mori-Tanaka average, amplified by ``1/(1 - c_f)`` and corrected by the
    orientation-dependent interaction term. ``c_f = 0`` is Jeffery's equation;
    both extra terms are trace-free, so ``tr a = 1`` is kept. Dimension-free
    algebra, so the planar form is the same expression with ``d = 2``.

    Parameters
    ----------
    cf : float
        Fibre volume fraction in [0, 1).
    xi, closure, dim
        As in :class:`~pyfold.models.Jeffery`.
    """

    cf: jax.Array = parameter(0.1, low=0.0, high=0.999)

    def _rate(self, t, a2, L):
        D, W, _ = flow_parts(L)
        a4 = self.a4(a2, t)
        inv_matrix = 1.0 / (1.0 - self.cf)
        aa = mat(a2, a2)
        interaction = mat(D, aa) + mat(aa, D) - 2.0 * mat(a2, mat(D, a2))
        return (
            rotation_term(a2, W)
            + inv_matrix * stretching_term(a2, a4, D, self.xi)
            - self.xi * self.cf * inv_matrix * interaction
        )
