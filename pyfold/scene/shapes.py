"""Particle shapes: codes shared with the Fortran core, volumes, Jeffery shape factors,
random-packing limits and the suspension regime.

Shape conventions follow ``fortran/particles/fold_particles.f90``: a fibre is a
cylinder of radius R and length L, a spheroid is prolate with semi-axes
a = L/2 (along p) and b = R, a sphere has L = 2R. In 2-D a fibre is a 2R x L
rectangle, a spheroid an ellipse, a sphere a disk; volumes are areas.
"""
from __future__ import annotations

import math

import numpy as np

from pyfold.errors import InputError
from pyfold.scene import registry

#: shape name -> code of fold_particles (FOLD_FIBRE, FOLD_SPHERE, FOLD_SPHEROID): the registry's
SHAPE_CODES = registry.codes("particles.shape")

#: Random close packing of identical disks (2-D) and spheres (3-D): 0.82 and 0.64
#: (Berryman 1983, Phys. Rev. A 27:1053). The placement kernel goes beyond random
#: sequential addition (jamming at 0.547 / 0.384) by relaxation sweeps, but no random
#: packing of identical disks or spheres is denser than these.
RANDOM_CLOSE_PACKING = {2: 0.82, 3: 0.64}

#: Random packing of long rods: phi * (L/d) -> 5.4 for L/d >> 1
#: (Philipse 1996, Langmuir 12:1127; docs/physics.md#packing). An upper bound for
#: finite rods (excluded-volume corrections only lower it).
ROD_PACKING_PHI_TIMES_BETA = 5.4

#: Densest *random* packing of any prolate ellipsoid, ~0.735 near aspect ratio 1.5
#: (Donev et al. 2004, Science 303:990); caps the rod bound for short particles.
MAX_RANDOM_PACKING_ELONGATED = 0.735


def particle_volume(dim: int, shape: str, radius: float, length: float) -> float:
    """Volume (area in 2-D) of one particle, as ``fold_particles.particle_volume``.

    3-D: fibre ``pi R^2 L``, spheroid ``(4/3) pi (L/2) R^2``, sphere ``(4/3) pi R^3``;
    2-D: fibre ``2 R L``, ellipse ``pi (L/2) R``, disk ``pi R^2``.
    """
    if dim == 2:
        return {"fibre": 2.0 * radius * length, "spheroid": math.pi * 0.5 * length * radius}.get(
            shape, math.pi * radius**2)
    return {"fibre": math.pi * radius**2 * length, "spheroid": 4.0 / 3.0 * math.pi * 0.5 * length * radius**2}.get(
        shape, 4.0 / 3.0 * math.pi * radius**3)


def random_packing_limit(shape: str, dim: int, beta: float) -> tuple[float, str] | None:
    """Largest volume fraction random placement can reach for this shape, with its source.

    Returns ``None`` where no published limit is used (2-D fibres and ellipses:
    the placement kernel reports the fraction it reached when it fails).
    """
    if shape == "sphere":
        return RANDOM_CLOSE_PACKING[dim], (
            f"random close packing of {'disks' if dim == 2 else 'spheres'} is "
            f"{RANDOM_CLOSE_PACKING[dim]:.2f} (Berryman 1983)")
    if dim == 3:
        limit = min(MAX_RANDOM_PACKING_ELONGATED, ROD_PACKING_PHI_TIMES_BETA / beta)
        return limit, (
            f"random packing of rods of aspect ratio {beta:.3g}: phi <= min(5.4/beta (Philipse 1996), "
            f"0.735 (Donev et al. 2004)) = {limit:.4f}")
    return None


def jeffery_xi(shape: str, beta: float, rule: str) -> tuple[float, float]:
    """Equivalent aspect ratio ``beta_e`` and Jeffery shape factor ``xi`` of one particle.

    Spheroids: ``beta_e = beta``; spheres: ``beta_e = 1`` (``xi = 0``); finite
    cylinders: ``beta_e`` from :func:`pyfold.kinematics.equivalent_aspect_ratio`
    with ``rule``. ``xi = (beta_e^2 - 1) / (beta_e^2 + 1)`` (Jeffery 1922,
    Proc. R. Soc. A 102:161; Bretherton 1962, J. Fluid Mech. 14:284).
    """
    from pyfold.kinematics import aspect_ratio_to_xi, equivalent_aspect_ratio

    if shape == "sphere":
        beta_e = 1.0
    elif shape == "spheroid":
        beta_e = float(beta)
    else:
        beta_e = float(equivalent_aspect_ratio(beta, rule=rule))
    return beta_e, float(aspect_ratio_to_xi(beta_e))


def regime(number_density: float, length: float, diameter: float, dim: int) -> tuple[str, float]:
    """Suspension regime from ``n L^dim`` (docs/physics.md#suspension-regimes).

    dilute ``n L^3 < 1``; semi-dilute ``1 <= n L^3 < L/d``; concentrated
    ``n L^3 >= L/d`` (Doi & Edwards 1978, J. Chem. Soc. Faraday Trans. 2 74:560).
    In 2-D the same rule is applied to ``n L^2`` with ``n`` per unit area.
    """
    measure = number_density * length**dim
    if measure < 1.0:
        return "dilute", measure
    if measure < length / diameter:
        return "semi-dilute", measure
    return "concentrated", measure


def unit_vectors(vectors, path: str, dim: int) -> np.ndarray:
    """Normalise axis vectors ``(n, dim)`` (:func:`pyfold.scene.vectors.unit_rows`); a zero or
    non-finite vector is an input error at ``path``."""
    from pyfold.scene.vectors import unit_rows

    unit, why = unit_rows(np.asarray(vectors, dtype=np.float64).reshape(-1, dim))
    if why is not None:
        raise InputError(f"{path}: {why}")
    return unit


def half_segment(shape: str, radius: float, length: float) -> float:
    """Half length of the particle's core segment (``fold_particles.particle_half_segment``):
    fibre ``L/2``, spheroid ``max(0, L/2 - R)``, sphere 0 [m]."""
    if shape == "fibre":
        return 0.5 * length
    if shape == "spheroid":
        return max(0.0, 0.5 * length - radius)
    return 0.0


def interaction_range(particles, alpha: float) -> float:
    """Centre-distance range of fold_run's contact search (``fold_contacts.contact_search_range``
    with the default Verlet skin ``alpha + R_max``)::

        rc = 2 max_k (h_k + R_k) + alpha + skin = max extent + 2 alpha + R_max

    ``particles`` is a sequence of ``(shape, radius, length)`` (one per family is enough);
    the extent of a particle is ``2 (h + R)``: ``L + 2R`` for a fibre, ``L`` for a spheroid,
    ``2R`` for a sphere. 0 without particles [m].
    """
    particles = list(particles)
    if not particles:
        return 0.0
    skin = alpha + max(r for _, r, _ in particles)
    return 2.0 * max(half_segment(s, r, l) + r for s, r, l in particles) + (alpha + skin)


def range_rule_applies(n_particles: int) -> bool:
    """The cell/interaction-range rule binds only when a pair exists: with at most one
    particle there is no pair (a rigid particle never meets its own periodic images, which
    move with it), and fold_run's cell lists skip the check (``fold_cell_list.cell_list_setup``)."""
    return n_particles >= 2


def periodic_edges(lengths, dim: int, walls: bool) -> list[tuple[int, float]]:
    """The periodic cell edges ``(axis, length)`` fold_run checks against ``2 rc`` at t = 0
    (``fold_cell_list.cell_list_setup``: every edge but y between Couette walls)."""
    return [(ax, float(lengths[ax])) for ax in range(dim) if not (walls and ax == 1)]


def cell_range_violation(lengths, dim: int, walls: bool, particles, alpha: float,
                         n_particles: int) -> tuple[int, float, float] | None:
    """fold_run's rule, the one place pyfold states it: with two or more particles every
    periodic edge must exceed twice the interaction range (``L > 2 rc``, strictly), so that
    the minimum image of a pair is unique. Returns ``(axis, edge, rc)`` of the shortest
    violating edge, or None when the rule holds (or does not apply)."""
    if not range_rule_applies(n_particles):
        return None
    rc = interaction_range(particles, alpha)
    edges = periodic_edges(lengths, dim, walls)
    if not edges:
        return None
    ax, edge = min(edges, key=lambda t: t[1])
    if not edge > 2.0 * rc:
        return ax, edge, rc
    return None
