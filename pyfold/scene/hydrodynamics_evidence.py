"""Measured effect of hydrodynamic interactions on C_I, per regime: the evidence ``auto`` quotes.

``model.hydrodynamics = "auto"`` (pyfold/scene/normalise.py) chooses between Jeffery
kinematics with contacts (``jeffery``, the model of Sundararajakumar & Koch 1997) and the
fluid-coupled FFT Stokes solver (``stokes``). Each row below is one paired measurement:
the same fibre scene (pyfold.scene.sheared_fibres, same particles, cell, time step and
seeds) run with both models, the closure-free C_I of each run by rate regression
(pyfold.ci_estimators.ci_rate_regression with the run's own a4), and the difference
C_I(stokes) - C_I(jeffery) averaged over the seeds with its standard error and two-sided
p from the paired t-test (pyfold.ensemble.paired_difference). "Changes C_I by more than
its statistical error" means p < SIGNIFICANCE_LEVEL, the level the studies use. Each row
also carries the same paired difference of the C_I fitted to a2(t) with Folgar-Tucker +
IBOF (pyfold.fast_fit.fit_ci_rk4), because the two estimators measure different
things (docs/physics.md#what-contacts-alone-do) and need not agree.

The rows are the single source of truth: the studies that produced them recompute them
from their run files and report any disagreement with this table
(studies/speed_accuracy/pareto.py, ``evidence_check``), and ``auto``'s recorded reason
quotes the row of the scene's regime (:func:`auto_evidence`).

Both rows share the Stokes numerics 42^3 (3.11 voxels per diameter of a beta = 5 fibre
in a 2.7 L cell), kappa = 1e3, CG tolerance 1e-4, AB2, strain 30; at that resolution one
beta = 5 spheroid orbits 16 % fast against Jeffery's period
(out/interaction_coefficient/hydrodynamics/ci_hydrodynamics.md), so the Stokes C_I is
that of this discretisation, not of the continuum (docs/speed_accuracy.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["CIEvidence", "EVIDENCE", "SIGNIFICANCE_LEVEL", "auto_evidence", "evidence_for"]

#: Two-sided level of the paired t-test below which the difference counts as beyond the
#: statistical error (the level of studies/interaction_coefficient/ci_hydrodynamics.py).
SIGNIFICANCE_LEVEL = 0.05


@dataclass(frozen=True)
class CIEvidence:
    """One paired measurement of C_I(stokes) - C_I(jeffery) (closure-free, rate regression)."""

    regime: str            # "dilute" or "semi-dilute" (pyfold.scene.shapes.regime)
    beta: float            # fibre aspect ratio L/d
    n_l3: float            # realised number density times L^3
    n_fibres: int
    seeds: int             # paired seeds
    delta_ci: float        # mean over seeds of C_I(stokes) - C_I(jeffery)
    delta_ci_stderr: float
    p: float               # two-sided p of the paired t-test
    ci_jeffery: float      # ensemble C_I of the contacts-only model
    ci_stokes: float       # ensemble C_I of the Stokes model
    ci_stokes_stderr: float  # its ensemble error (max of s.e. across seeds and pooled s.e.)
    numerics: str
    study: str             # the script that produced the row
    command: str           # its exact command
    output: str            # its analysed output (NetCDF), relative to the repository
    # The same runs, C_I by a trajectory fit of Folgar-Tucker + IBOF to a2(t)
    # (pyfold.fast_fit.fit_ci_rk4: the C_I a moulding code running IBOF needs):
    traj_delta_ci: float = math.nan  # paired mean of C_I(stokes) - C_I(jeffery)
    traj_delta_ci_stderr: float = math.nan
    traj_p: float = math.nan
    # Period of one beta spheroid on the same cell and grid against Jeffery's, minus 1: the
    # discretisation error of single-particle rotation at these numerics (ci_hydrodynamics.py's check).
    period_error: float = math.nan

    @property
    def t(self) -> float:
        """Difference in standard errors."""
        return self.delta_ci / self.delta_ci_stderr

    @property
    def significant(self) -> bool:
        """True when neglecting hydrodynamics changes C_I by more than its statistical error."""
        return self.p < SIGNIFICANCE_LEVEL

    def quote(self) -> str:
        """The measurement in one clause, with its source."""
        verdict = ("beyond its statistical error" if self.significant
                   else "within its statistical error")
        return (f"measured: neglecting hydrodynamics changes C_I by {-self.delta_ci:+.1e} ± "
                f"{self.delta_ci_stderr:.1e} (contacts only minus Stokes, closure-free rate regression; "
                f"{abs(self.t):.1f} s.e., paired p = {self.p:.2g}, {verdict}) at "
                f"β = {self.beta:g}, n L^3 = {self.n_l3:.3g} ({self.n_fibres} fibres, {self.seeds} seeds; "
                f"{self.study}); by a trajectory fit with IBOF the change is {-self.traj_delta_ci:+.1e} ± "
                f"{self.traj_delta_ci_stderr:.1e} (paired p = {self.traj_p:.2g})")


SEMI_DILUTE = CIEvidence(
    regime="semi-dilute", beta=5.0, n_l3=4.98, n_fibres=98, seeds=4,
    delta_ci=8.58e-4, delta_ci_stderr=1.12e-4, p=4.63e-3,
    ci_jeffery=1.01e-4, ci_stokes=9.60e-4, ci_stokes_stderr=3.25e-4,
    numerics="42^3 (3.11 voxels per diameter), kappa 1e3, tol 1e-4, AB2, strain 30",
    study="studies/interaction_coefficient/ci_hydrodynamics.py",
    command=".venv/bin/python studies/interaction_coefficient/ci_hydrodynamics.py",
    output="out/interaction_coefficient/hydrodynamics/ci_hydrodynamics.nc",
    traj_delta_ci=-5.88e-4, traj_delta_ci_stderr=6.50e-4, traj_p=0.432, period_error=-0.164,
)

DILUTE = CIEvidence(
    regime="dilute", beta=5.0, n_l3=0.914, n_fibres=18, seeds=4,
    delta_ci=2.15e-4, delta_ci_stderr=1.57e-4, p=0.265,
    ci_jeffery=3.25e-5, ci_stokes=2.47e-4, ci_stokes_stderr=2.06e-4,
    numerics="42^3 (3.11 voxels per diameter), kappa 1e3, tol 1e-4, AB2, strain 30",
    study="studies/speed_accuracy/ci_dilute.py",
    command="nice -n 10 .venv/bin/python studies/speed_accuracy/ci_dilute.py",
    output="out/speed_accuracy/ci_dilute/ci_hydrodynamics.nc",
    traj_delta_ci=4.74e-5, traj_delta_ci_stderr=1.49e-4, traj_p=0.771, period_error=-0.164,
)

#: The measured rows, by regime.
EVIDENCE: dict[str, CIEvidence] = {row.regime: row for row in (DILUTE, SEMI_DILUTE)}


def evidence_for(regime: str) -> tuple[CIEvidence, bool] | None:
    """The row for a fibre ``regime`` and whether it was measured in that regime.

    A concentrated scene gets the semi-dilute row (the densest measured; flagged as not
    measured in its regime). Spheres have no C_I row: None.
    """
    if regime in EVIDENCE:
        return EVIDENCE[regime], True
    if regime == "concentrated":
        return EVIDENCE["semi-dilute"], False
    return None


def auto_evidence(regime: str, chosen: str) -> str:
    """The clause ``auto``'s reason appends: the measurement for ``regime`` and what the
    ``chosen`` model ("jeffery" or "stokes") costs in C_I accuracy. Empty for spheres."""
    found = evidence_for(regime)
    if found is None:
        return ""
    row, same_regime = found
    where = "" if same_regime else f" (nearest measured regime: {row.regime}; none measured when {regime})"
    text = f"; {row.quote()}{where}"
    if chosen == "jeffery":
        text += (f"; expected C_I error of this choice: {abs(row.delta_ci):.1e} ± {row.delta_ci_stderr:.1e} "
                 f"(C_I {row.ci_jeffery:.1e} contacts only against {row.ci_stokes:.1e} with Stokes)")
    else:
        text += (f"; the Stokes model's C_I there: {row.ci_stokes:.1e} ± {row.ci_stokes_stderr:.1e} over "
                 f"{row.seeds} seeds at {row.numerics} (not grid-converged: one β = {row.beta:g} spheroid orbits "
                 f"with a period error of {row.period_error:+.0%} on that grid; docs/speed_accuracy.md)")
    return text
