"""Published C_I correlations and values, the one place pyfold states them.

Moulding codes pick the Folgar-Tucker interaction coefficient from a correlation
in the product ``phi * beta`` (volume fraction times aspect ratio); pyfold's
studies and reports plot their fitted ``C_I`` beside these
(docs/physics.md#c_i-correlations, docs/physics.md#published-c_i-values):

* Bay (1991):                 ``C_I = 0.0184 exp(-0.7148 phi beta)``
* Phan-Thien et al. (2002):   ``C_I = 0.03 (1 - exp(-0.224 phi beta))``
* Folgar & Tucker (1984), Couette experiments: three points.

Concentration measures of a fibre population (``n`` fibres per unit volume, length
``L``, diameter ``d``, ``beta = L/d``; cylinders without caps):

    phi = n (pi/4) d^2 L = (pi/4) n L^3 / beta^2,    n L^2 d = n L^3 / beta.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np


def volume_fraction(n_l3: float, beta: float) -> float:
    """``phi = (pi/4) n L^3 / beta^2`` of cylinders of aspect ratio ``beta`` (caps ignored)."""
    return math.pi / 4.0 * float(n_l3) / float(beta) ** 2


def phi_beta(n_l3: float, beta: float) -> float:
    """``phi beta = (pi/4) n L^3 / beta``, the variable of the C_I correlations."""
    return volume_fraction(n_l3, beta) * float(beta)


def n_l2d(n_l3: float, beta: float) -> float:
    """``n L^2 d = n L^3 / beta`` (the concentration of Sundararajakumar & Koch 1997)."""
    return float(n_l3) / float(beta)


def bay_1991(phi_b):
    """Bay (1991), PhD thesis, UIUC: ``C_I = 0.0184 exp(-0.7148 phi beta)``."""
    return 0.0184 * np.exp(-0.7148 * np.asarray(phi_b, dtype=float))


def phan_thien_2002(phi_b):
    """Phan-Thien, Fan, Tanner & Zheng (2002), JNNFM 103:251: ``C_I = 0.03 (1 - exp(-0.224 phi beta))``."""
    return 0.03 * (1.0 - np.exp(-0.224 * np.asarray(phi_b, dtype=float)))


#: name -> (function of phi*beta, citation)
CORRELATIONS = {
    "Bay 1991": (bay_1991, "Bay (1991), PhD thesis, University of Illinois: 0.0184 exp(-0.7148 phi beta)"),
    "Phan-Thien 2002": (phan_thien_2002,
                        "Phan-Thien, Fan, Tanner & Zheng (2002), J. Non-Newtonian Fluid Mech. 103:251: "
                        "0.03 (1 - exp(-0.224 phi beta))"),
}


@dataclasses.dataclass(frozen=True)
class PublishedValue:
    """A published C_I at a concentration ``phi_beta`` (NaN when the source does not give it)."""

    source: str
    method: str
    phi_beta: float
    ci: float


#: Folgar & Tucker (1984), J. Reinf. Plast. Compos. 3:98, Couette experiments.
FOLGAR_TUCKER_1984 = (
    PublishedValue("Folgar & Tucker 1984", "Couette experiment", 0.16, 0.0038),
    PublishedValue("Folgar & Tucker 1984", "Couette experiment", 1.28, 0.0081),
    PublishedValue("Folgar & Tucker 1984", "Couette experiment", 2.56, 0.0165),
)

#: Range of published C_I values from experiments and simulations
#: (docs/physics.md#published-c_i-values): about 1e-4 (lattice-Boltzmann, Salahuddin,
#: Wu & Aidun 2012) to 3e-2 (the Phan-Thien plateau).
PUBLISHED_RANGE = (1.0e-4, 3.0e-2)


def correlations_at(phi_b: float) -> dict[str, float]:
    """Each correlation's C_I at ``phi_b`` (name -> value)."""
    return {name: float(fn(phi_b)) for name, (fn, _) in CORRELATIONS.items()}
