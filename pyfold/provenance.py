"""What lies behind a report's numbers, and whether the estimators apply to a run.

Every summary, figure and results file of ``pyfold analyse`` and ``pyfold report``
names the physics model of its runs (from ``/setup/resolved/hydrodynamics`` and
``hydrodynamics_reason``, as ``pyfold run`` resolved them), the resolution and the
strain range, because the fitted ``C_I`` means different things for different
models: with Jeffery kinematics and contacts only (no hydrodynamic interactions) it
is several times below the published correlations, as expected for that model
(docs/physics.md#what-contacts-alone-do).

The checks (:func:`applicability_problems`) refuse, unless ``--force``, a run whose
particles have no orientation (spheres; in 2-D disks: ``a2`` does not follow
Jeffery's equation and ``C_I`` is undefined) or whose strain is shorter than
:data:`MIN_FIT_PERIODS` Jeffery periods of its particles' aspect ratio.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pyfold.errors import InputError

#: Shortest strain a C_I estimate needs, in Jeffery periods ``T = 2 pi (beta_e + 1/beta_e) / gamma_dot``
#: of the particles' (equivalent) aspect ratio: a fibre spends most of its orbit near the
#: flow direction and flips once per half period, so within less than a period the
#: record holds less than one flip of every orbit and the rate of a2 is the Jeffery
#: transient, not the interactions that C_I stands for (a fit then returns whatever
#: value the closure's error and the initial state dictate).
MIN_FIT_PERIODS = 1.0
#: |xi| below this: no orientation dynamics (spheres, disks). Double-precision round-off of
#: xi = (beta_e^2 - 1) / (beta_e^2 + 1) at beta_e = 1.
NO_ORIENTATION_XI = 1e-12
#: /setup/resolved/family_shape codes (pyfold/scene/normalise.py: 1 fibre, 2 sphere, 3 spheroid).
SPHERE_SHAPE = 2
#: /setup/resolved/collisions codes (pyfold/scene/normalise.py).
_COLLISIONS = {0: "no contacts", 1: "contacts (naive pair loop)", 2: "contacts (collision strategy)"}


def shear_rate_of(L: np.ndarray) -> float:
    """``gamma_dot = sqrt(2 D:D)`` of a velocity gradient (the shear rate of a simple shear)."""
    L = np.asarray(L, dtype=np.float64)
    D = 0.5 * (L + L.T)
    return math.sqrt(2.0 * float(np.sum(D * D))) or 1.0


def equivalent_aspect_ratio(xi: float) -> float:
    """``beta_e = sqrt((1 + xi) / (1 - xi))`` of Jeffery's shape factor ``xi`` (infinite at xi = 1)."""
    xi = abs(float(xi))
    return math.sqrt((1.0 + xi) / (1.0 - xi)) if xi < 1.0 else math.inf


def jeffery_period_strain(xi: float) -> float:
    """Jeffery's period in strain units, ``2 pi (beta_e + 1/beta_e)`` (Jeffery 1922); inf for xi = +-1."""
    beta_e = equivalent_aspect_ratio(xi)
    return 2.0 * math.pi * (beta_e + 1.0 / beta_e) if math.isfinite(beta_e) else math.inf


@dataclass(frozen=True)
class Provenance:
    """The physics model, resolution and strain range behind a set of numbers."""

    hydrodynamics: str  # "jeffery" or "stokes"
    model: str  # e.g. "Jeffery kinematics + contacts (collision strategy), no hydrodynamic interactions"
    resolution: str
    strain: tuple[float, float]
    period_strain: float  # Jeffery period of the particles [strain]
    reason: str  # /setup/resolved/hydrodynamics_reason verbatim

    def line(self) -> str:
        """One line for a summary or a figure."""
        periods = (self.strain[1] - self.strain[0]) / self.period_strain if math.isfinite(self.period_strain) else 0.0
        span = f"strain {self.strain[0]:.3g}-{self.strain[1]:.3g}"
        if math.isfinite(self.period_strain):
            span += f" ({periods:.2g} Jeffery periods of {self.period_strain:.3g})"
        return f"model: {self.model}; resolution: {self.resolution}; {span}"

    def attrs(self) -> dict[str, str | float]:
        """Global attributes of a results file."""
        return {"physics_model": self.model, "hydrodynamics": self.hydrodynamics, "resolution": self.resolution,
                "strain_start": self.strain[0], "strain_end": self.strain[1],
                "jeffery_period_strain": self.period_strain, "hydrodynamics_reason": self.reason}


def _text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.dtype.kind in "SO" and value.ndim == 0:
        return _text(value.item())
    return str(value)


def provenance_of(run_path: Path, t: np.ndarray, L: np.ndarray, xi: float) -> Provenance:
    """The :class:`Provenance` of one run file over its record times ``t`` [s]."""
    from pyfold.run_input import read_setup

    res = read_setup(run_path).resolved
    gamma_dot = shear_rate_of(L)
    hydro = int(np.asarray(res.get("hydrodynamics", 0)))
    reason = _text(res.get("hydrodynamics_reason", ""))
    contacts = _COLLISIONS.get(int(np.asarray(res.get("collisions", 2))), "contacts")
    lubrication = " + lubrication" if int(np.asarray(res.get("lubrication", 0))) else ""
    # "X + contacts (...)" or "X, no contacts"
    joined = f", {contacts}" if contacts == _COLLISIONS[0] else f" + {contacts}"
    counts = np.atleast_1d(res.get("family_count", [0]))
    dt = float(np.asarray(res.get("dt", math.nan)))
    dim = int(np.asarray(res.get("dim", 3)))
    parts = [f"{int(np.sum(counts))} particles", f"time step {dt * gamma_dot:.3g}/shear rate"]
    if hydro == 1:
        grid = [int(g) for g in np.atleast_1d(res.get("stokes_grid", []))]
        cell = np.asarray(res.get("cell_lengths", [math.nan] * 3), dtype=float)[:dim]
        radius = float(np.min(np.atleast_1d(res.get("family_radius", [math.nan]))))
        h = float(np.max(cell / np.asarray(grid, dtype=float))) if grid else math.nan
        model = f"fluid-coupled Stokes (hydrodynamic interactions resolved on a grid){joined}{lubrication}"
        parts.insert(0, f"Stokes grid {' x '.join(map(str, grid))}, {2.0 * radius / h:.3g} grid cells per diameter")
    else:
        model = f"Jeffery kinematics{joined}{lubrication}, no hydrodynamic interactions"
    t = np.asarray(t, dtype=float)
    return Provenance(hydrodynamics="stokes" if hydro == 1 else "jeffery", model=model, resolution=", ".join(parts),
                      strain=(float(t[0]) * gamma_dot, float(t[-1]) * gamma_dot),
                      period_strain=jeffery_period_strain(xi), reason=reason)


def has_no_orientation(run_path: Path, xi: float) -> bool:
    """True when the particles have no orientation dynamics: every family a sphere (a disk
    in 2-D), or ``|xi|`` at round-off of 0."""
    from pyfold.run_input import read_setup

    shapes = np.atleast_1d(read_setup(run_path).resolved.get("family_shape", [1]))
    return bool(np.all(shapes.astype(int) == SPHERE_SHAPE) or abs(float(xi)) < NO_ORIENTATION_XI)


def applicability_problems(run_path: Path, t: np.ndarray, L: np.ndarray, xi: float) -> list[str]:
    """Why the C_I estimators do not apply to a run (empty when they do)."""
    problems = []
    if has_no_orientation(run_path, xi):
        problems.append(f"{run_path}: the particles have no orientation (spheres or disks, xi = {xi:.3g}): a2 does not "
                        "evolve by Jeffery's equation and C_I is undefined")
        return problems
    period = jeffery_period_strain(xi)
    t = np.asarray(t, dtype=float)
    strain = (float(t[-1]) - float(t[0])) * shear_rate_of(L)
    if math.isfinite(period) and strain < MIN_FIT_PERIODS * period:
        problems.append(f"{run_path}: strain {strain:.3g} is {strain / period:.2g} Jeffery periods; estimating C_I "
                        f"needs at least {MIN_FIT_PERIODS:g} (period 2 pi (beta_e + 1/beta_e) = {period:.3g} strain "
                        f"for beta_e = {equivalent_aspect_ratio(xi):.3g}, xi = {xi:.4g}): within less than one "
                        "period the records hold less than one flip of each orbit; run longer "
                        f"(t_end >= {t[0] + MIN_FIT_PERIODS * period / shear_rate_of(L):.4g} s)")
    return problems


def enforce(problems: list[str], force: bool, command: str) -> list[str]:
    """Refuse (:class:`InputError`) when there are ``problems``, unless ``force``: then
    print each as a warning on stderr and return them (for the summary)."""
    if not problems:
        return []
    if not force:
        raise InputError("; ".join(problems) + ". Give --force to estimate C_I anyway (the result is then "
                         "marked as such)")
    for p in problems:
        print(f"{command}: WARNING (--force): {p}", file=sys.stderr)
    return [f"WARNING (--force): {p}" for p in problems]
