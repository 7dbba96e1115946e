"""``numerics.preset = "study"``: the numerical settings chosen by their measured effect on C_I.

A user of the fluid-coupled simulation pays for a C_I at a stated accuracy, not for a
Stokes step. studies/speed_accuracy/ci_stokes_settings.py runs one fibre suspension per
regime (β = 5 fibres in simple shear, 4 seeds, strain 30) with the reference numerics
(κ = 10³, CG tolerance 10⁻⁴, 3 voxels per diameter requested, Δt = α/(γ̇L), AB2) and with
each cheaper setting on the same seeds, and measures how far each moves the C_I
(closure-free rate regression, and the Folgar–Tucker + IBOF trajectory fit) from the
reference's, seed by seed, in units of the reference's statistical error over the 4
seeds. Its rows are :data:`EVIDENCE`, the one copy of those measurements: the study
recomputes them from its runs and reports any disagreement.

The preset takes, for the scene's regime, the cheapest measured setting whose change of
C_I (the paired mean over the seeds) stays below :data:`ADMISSIBLE_FRACTION` of that
statistical error for both estimators, and fills with it the keys the scene leaves unset.
The standard error of each change is quoted beside it: in a suspension whose trajectories
decorrelate within a strain of a few units, two settings' runs of one seed are partly
independent realisations, so 4 seeds bound a change only to about half the statistical
error itself; a change at that level is what the 4-seed answer cannot resolve anyway. A key the scene states wins. The choice,
the measured change and saving, and the resolution's known error go into the run file
(``/setup/resolved/numerics_preset_reason``).

Resolution: where the scene leaves ``numerics.stokes.cells_per_diameter`` unset, the preset
takes the coarsest grid of :data:`RESOLUTION` (resolution studies of the semi-dilute scene, per
aspect ratio: the same seeds on three grids, the paired change of C_I against the finest) whose
change stays below the same fraction for both estimators, with the fibre radius calibrated to
that grid where the study calibrated it (``fibre_radius_scale``, with the study's ``fibre_shells``). A
grid the scene states that its study found too coarse is kept, and the run says so (a warning and
the reason).

Aspect ratio: :data:`BETA_EVIDENCE` holds the measurements of another aspect ratio's scene
(β = 10, where solve intervals and a longer step were measured); a scene of that β takes them,
any other β the β = 5 rows with a caveat.

Scope: the evidence is for fibres in simple shear on the periodic cell (``fft``
backend). Another scene (spheres, walls, other flows, another aspect ratio) gets the row
of its regime with that caveat in the reason when it is fibres in simple shear, and the
registry's defaults otherwise; the dilute regime takes the semi-dilute row (``auto``
runs dilute fibres without the Stokes solver).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

from pyfold.scene.schema import Scene

__all__ = ["Measured", "RegimeEvidence", "EVIDENCE", "BETA_EVIDENCE", "GridMeasured", "ResolutionEvidence",
           "RESOLUTION", "ADMISSIBLE_FRACTION", "admissible", "evidence_for", "choice_for", "resolution_for",
           "compare_changes", "evidence_check_lines", "resolution_check",
           "probe_scene", "fill"]

#: The preset's rule: a setting is admissible where its change of C_I (paired mean over the
#: seeds) stays below this fraction of the reference's statistical error over 4 seeds.
ADMISSIBLE_FRACTION = 0.5
#: Steps of the probe resolution when the scene leaves dt unset (any divisor of t_end that
#: passes the step rules serves: the probe only learns the regime, model and rates).
PROBE_STEPS = 10_000


@dataclass(frozen=True)
class Measured:
    """One setting of ci_stokes_settings.py against the reference, on one scene."""

    name: str
    stokes: Mapping[str, object]  # the [numerics.stokes] keys of the setting
    dt_factor: float  # Δt / (α/(γ̇ L)): 1 is the reference step (a tip moves α/2 per step)
    # |paired mean change of C_I| and its standard error, in units of the reference's
    # ensemble error, for the closure-free rate regression and the IBOF trajectory fit
    closure_free: float
    closure_free_stderr: float
    trajectory: float
    trajectory_stderr: float
    cpu_ratio: float  # CPU time per run / the reference's
    # The setting this one's changes were measured against, by name (None: the reference). The
    # preset bounds the change against the reference by the sum of the chain's |changes|
    # (triangle inequality), its s.e. by theirs in quadrature (RegimeEvidence.total).
    against: str | None = None
    measured_on: str = ""  # the grid, when it is not the evidence's (e.g. "96^3, 4 voxels per diameter")

    def change(self) -> float:
        """The larger of the two estimators' changes [statistical errors]."""
        return max(self.closure_free, self.trajectory)


@dataclass(frozen=True)
class RegimeEvidence:
    """The measurements of one regime's scene."""

    regime: str
    beta: float
    n_l3: float
    n_fibres: int
    seeds: int
    reference: Measured
    settings: tuple[Measured, ...]
    # Single-particle check on the reference grid: period of one β spheroid against Jeffery's, minus 1
    period_error: float
    study: str = "studies/speed_accuracy/ci_stokes_settings.py"
    command: str = ".venv/bin/python studies/speed_accuracy/ci_stokes_settings.py"
    output: str = "out/speed_accuracy/ci_stokes_settings/ci_stokes_settings.nc"
    ci_reference: tuple[float, float] = field(default=(math.nan, math.nan))  # closure-free C_I ± error
    trajectory_reference: tuple[float, float] = field(default=(math.nan, math.nan))  # IBOF-fitted C_I ± error

    def total(self, m: "Measured") -> "Measured":
        """``m`` with its changes against the reference: its own plus those of the settings it was
        measured against, |changes| summed (a bound, whatever the signs), s.e. in quadrature."""
        if m.against is None:
            return m
        base = self.total(next(o for o in self.settings if o.name == m.against))
        return Measured(name=m.name, stokes=m.stokes, dt_factor=m.dt_factor,
                        closure_free=round(m.closure_free + base.closure_free, 2),
                        closure_free_stderr=round(math.hypot(m.closure_free_stderr, base.closure_free_stderr), 2),
                        trajectory=round(m.trajectory + base.trajectory, 2),
                        trajectory_stderr=round(math.hypot(m.trajectory_stderr, base.trajectory_stderr), 2),
                        cpu_ratio=m.cpu_ratio, measured_on=m.measured_on)

    def settings_error(self, m: "Measured") -> tuple[float, float]:
        """The setting ``m``'s measured change of C_I as an absolute error (closure-free, IBOF
        trajectory fit): the paired change and its standard error added in quadrature, times the
        reference's ensemble error (a chained setting: its total against the reference)."""
        m = self.total(m)
        return (math.hypot(m.closure_free, m.closure_free_stderr) * self.ci_reference[1],
                math.hypot(m.trajectory, m.trajectory_stderr) * self.trajectory_reference[1])


_REF_STOKES = {"cells_per_diameter": 3, "kappa": 1000.0}
#: The reference numerics of both scenes, against which the changes are measured
_REFERENCE = Measured(name='tol1e-4', stokes={**_REF_STOKES, 'tolerance': 0.0001}, dt_factor=1.0, closure_free=0.0,
                      closure_free_stderr=0.0, trajectory=0.0, trajectory_stderr=0.0, cpu_ratio=1.0)

#: The measurements of studies/speed_accuracy/ci_stokes_settings.py, as it prints them
#: (its evidence check recomputes them from the runs). Changes in units of the reference's
#: statistical error over the 4 seeds; CPU ratios measured on 2 shared cores, 2 runs at a time.
EVIDENCE: Mapping[str, RegimeEvidence] = MappingProxyType({
    "semi-dilute": RegimeEvidence(
        regime="semi-dilute", beta=5.0, n_l3=98 / 2.7 ** 3, n_fibres=98, seeds=4,
        reference=_REFERENCE,
        settings=(
            Measured(name='tol1e-3', stokes={**_REF_STOKES, 'tolerance': 0.001}, dt_factor=1.0,
                     closure_free=0.02, closure_free_stderr=0.11, trajectory=0.1, trajectory_stderr=0.48,
                     cpu_ratio=0.62),
            Measured(name='tol1e-3_single', stokes={**_REF_STOKES, 'tolerance': 0.00099, 'fft_precision': 'single'},
                     dt_factor=1.0, closure_free=0.01, closure_free_stderr=0.27, trajectory=0.08,
                     trajectory_stderr=0.42, cpu_ratio=0.63),
            Measured(name='tol1e-3_every2', stokes={**_REF_STOKES, 'tolerance': 0.001, 'solve_every': 2},
                     dt_factor=1.0, closure_free=0.23, closure_free_stderr=0.37, trajectory=0.65,
                     trajectory_stderr=0.41, cpu_ratio=0.36),
            Measured(name='tol1e-3_every4', stokes={**_REF_STOKES, 'tolerance': 0.001, 'solve_every': 4},
                     dt_factor=1.0, closure_free=0.13, closure_free_stderr=0.49, trajectory=0.44,
                     trajectory_stderr=0.54, cpu_ratio=0.21),
            Measured(name='tol1e-3_dt0.04', stokes={**_REF_STOKES, 'tolerance': 0.001}, dt_factor=2.0,
                     closure_free=0.3, closure_free_stderr=0.54, trajectory=0.4, trajectory_stderr=0.41,
                     cpu_ratio=0.37),
            # a softer solid: fewer CG iterations, but the IBOF-fitted C_I rises (κ 10²) and the
            # closure-free one falls (κ 30) beyond the rule
            Measured(name='kappa100_tol1e-3_every4',
                     stokes={**_REF_STOKES, 'kappa': 100.0, 'tolerance': 0.001, 'solve_every': 4}, dt_factor=1.0,
                     closure_free=0.46, closure_free_stderr=0.32, trajectory=1.32, trajectory_stderr=0.88,
                     cpu_ratio=0.13),
            Measured(name='kappa100_tol1e-2_every4',
                     stokes={**_REF_STOKES, 'kappa': 100.0, 'tolerance': 0.01, 'solve_every': 4}, dt_factor=1.0,
                     closure_free=0.45, closure_free_stderr=0.82, trajectory=1.24, trajectory_stderr=0.8,
                     cpu_ratio=0.09),
            Measured(name='kappa30_tol1e-2_every4',
                     stokes={**_REF_STOKES, 'kappa': 30.0, 'tolerance': 0.01, 'solve_every': 4}, dt_factor=1.0,
                     closure_free=1.94, closure_free_stderr=0.62, trajectory=1.35, trajectory_stderr=0.86,
                     cpu_ratio=0.07),
        ),
        # one beta = 5 spheroid at 3 voxels per diameter (42^3, 2.7 L cell), studies/interaction_coefficient/
        # ci_hydrodynamics.py's single-particle check (pyfold/scene/hydrodynamics_evidence.py)
        period_error=-0.164,
        ci_reference=(9.41e-4, 3.5e-4), trajectory_reference=(4.67e-3, 4.50e-4)),
    "concentrated": RegimeEvidence(
        regime="concentrated", beta=5.0, n_l3=157 / 2.7 ** 3, n_fibres=157, seeds=4,
        reference=_REFERENCE,
        settings=(
            Measured(name='tol1e-3', stokes={**_REF_STOKES, 'tolerance': 0.001}, dt_factor=1.0,
                     closure_free=0.28, closure_free_stderr=0.58, trajectory=0.85, trajectory_stderr=0.57,
                     cpu_ratio=0.68),
            Measured(name='tol1e-3_every4', stokes={**_REF_STOKES, 'tolerance': 0.001, 'solve_every': 4},
                     dt_factor=1.0, closure_free=0.23, closure_free_stderr=0.58, trajectory=0.9,
                     trajectory_stderr=0.9, cpu_ratio=0.22),
            Measured(name='kappa100_tol1e-3_every4',
                     stokes={**_REF_STOKES, 'kappa': 100.0, 'tolerance': 0.001, 'solve_every': 4}, dt_factor=1.0,
                     closure_free=0.52, closure_free_stderr=0.97, trajectory=0.35, trajectory_stderr=0.77,
                     cpu_ratio=0.12),
            Measured(name='kappa100_tol1e-2_every4',
                     stokes={**_REF_STOKES, 'kappa': 100.0, 'tolerance': 0.01, 'solve_every': 4}, dt_factor=1.0,
                     closure_free=0.38, closure_free_stderr=0.72, trajectory=1.17, trajectory_stderr=0.52,
                     cpu_ratio=0.09),
            Measured(name='kappa30_tol1e-2_every4',
                     stokes={**_REF_STOKES, 'kappa': 30.0, 'tolerance': 0.01, 'solve_every': 4}, dt_factor=1.0,
                     closure_free=0.68, closure_free_stderr=0.6, trajectory=0.03, trajectory_stderr=0.61,
                     cpu_ratio=0.08),
        ),
        # the same fibre and grid as the semi-dilute scene's check (42^3, 2.7 L cell)
        period_error=-0.164,
        ci_reference=(8.71e-4, 4.3e-4), trajectory_reference=(5.49e-3, 2.68e-4)),
})


#: Another aspect ratio's measurements, by (regime, β). β = 10, semi-dilute: the calibrated β = 10
#: series' scene (88 fibres, n L³ = 6.37, φβ = 0.5, cell 2.4 L, α = 0.1 d, fibres voxelised at the
#: calibrated radius, CG tolerance 10⁻³), 4 seeds, strain 20. Its reference is the β = 5 preset's
#: setting (a solve every 4th step, Δt = α/(γ̇L)). The longer step was measured on 72³
#: (studies/speed_accuracy/time_step_beta10.py); a solve every 8th step against it on 72³
#: (studies/speed_accuracy/solve_reuse.py --beta 10); a solve every 16th step on 96³, the grid
#: the resolution study keeps (studies/interaction_coefficient/ci_resolution_beta10.py's control,
#: where it sits at 0.51 of the statistical error for the IBOF trajectory fit; on 72³ it gave
#: 0.02). CPU ratios: each grid's own runs.
_BETA10_REF_STOKES = {"cells_per_diameter": 3, "kappa": 1000.0, "tolerance": 0.001, "solve_every": 4}
BETA_EVIDENCE: Mapping[tuple[str, float], RegimeEvidence] = MappingProxyType({
    ("semi-dilute", 10.0): RegimeEvidence(
        regime="semi-dilute", beta=10.0, n_l3=88 / 2.4 ** 3, n_fibres=88, seeds=4,
        reference=Measured(name="tol1e-3_every4", stokes=_BETA10_REF_STOKES, dt_factor=1.0, closure_free=0.0,
                           closure_free_stderr=0.0, trajectory=0.0, trajectory_stderr=0.0, cpu_ratio=1.0),
        settings=(
            Measured(name="tol1e-3_every4_dt2", stokes=_BETA10_REF_STOKES, dt_factor=2.0,
                     closure_free=0.19, closure_free_stderr=0.05, trajectory=0.03, trajectory_stderr=0.08,
                     cpu_ratio=0.52),
            Measured(name="tol1e-3_every8_jeffery_dt2",
                     stokes={**_BETA10_REF_STOKES, "solve_every": 8, "reuse": "jeffery"}, dt_factor=2.0,
                     closure_free=0.21, closure_free_stderr=0.09, trajectory=0.03, trajectory_stderr=0.05,
                     cpu_ratio=0.28, against="tol1e-3_every4_dt2"),
            Measured(name="tol1e-3_every16_jeffery_dt2",
                     stokes={**_BETA10_REF_STOKES, "cells_per_diameter": 4, "solve_every": 16, "reuse": "jeffery"},
                     dt_factor=2.0, closure_free=0.0, closure_free_stderr=0.06, trajectory=0.51,
                     trajectory_stderr=0.24, cpu_ratio=0.14, against="tol1e-3_every4_dt2",
                     measured_on="96^3, 4 voxels per diameter"),
        ),
        # one beta = 10 fibre on 96^3 voxelised at 1.100 R turns with beta_e 7.63, Zhang et al. 2011's cylinder
        # 7.61 (ci_resolution.py's calibrate_scale): the period of 2 pi (beta_e + 1/beta_e) is 0.3 % long
        period_error=0.003,
        study="studies/speed_accuracy/time_step_beta10.py, studies/speed_accuracy/solve_reuse.py --beta 10, "
              "studies/interaction_coefficient/ci_resolution_beta10.py",
        command=".venv/bin/python studies/speed_accuracy/solve_reuse.py --beta 10",
        output="out/speed_accuracy/solve_reuse_beta10/solve_reuse.nc",
        ci_reference=(1.14e-3, 2.7e-4), trajectory_reference=(2.85e-3, 3.9e-4)),
    # beta = 10, concentrated: the series' phi beta = 1.0 scene (176 fibres, n L^3 = 12.7) on 96^3, its
    # reference a solve every 4th step at the longer step (studies/speed_accuracy/solve_reuse.py --beta 10
    # --concentrated); the longer step itself was measured at phi beta = 0.5 only
    ("concentrated", 10.0): RegimeEvidence(
        regime="concentrated", beta=10.0, n_l3=176 / 2.4 ** 3, n_fibres=176, seeds=4,
        reference=Measured(name="tol1e-3_every4_dt2", stokes={**_BETA10_REF_STOKES, "cells_per_diameter": 4},
                           dt_factor=2.0, closure_free=0.0, closure_free_stderr=0.0, trajectory=0.0,
                           trajectory_stderr=0.0, cpu_ratio=1.0,
                           measured_on="96^3; its step 2 alpha/(gamma_dot L) measured at phi beta = 0.5 only"),
        settings=(
            Measured(name="tol1e-3_every8_jeffery_dt2",
                     stokes={**_BETA10_REF_STOKES, "cells_per_diameter": 4, "solve_every": 8, "reuse": "jeffery"},
                     dt_factor=2.0, closure_free=0.03, closure_free_stderr=0.03, trajectory=0.19,
                     trajectory_stderr=0.16, cpu_ratio=0.51, measured_on="96^3, 4 voxels per diameter"),
            Measured(name="tol1e-3_every16_jeffery_dt2",
                     stokes={**_BETA10_REF_STOKES, "cells_per_diameter": 4, "solve_every": 16, "reuse": "jeffery"},
                     dt_factor=2.0, closure_free=0.04, closure_free_stderr=0.24, trajectory=0.30,
                     trajectory_stderr=0.25, cpu_ratio=0.28, measured_on="96^3, 4 voxels per diameter"),
        ),
        period_error=0.003,  # the same fibre and grid as the semi-dilute row's
        study="studies/speed_accuracy/solve_reuse.py --beta 10 --concentrated",
        command=".venv/bin/python studies/speed_accuracy/solve_reuse.py --beta 10 --concentrated",
        output="out/speed_accuracy/solve_reuse_beta10_concentrated/solve_reuse.nc",
        ci_reference=(7.65e-4, 1.8e-4), trajectory_reference=(6.18e-4, 3.2e-4)),
})


@dataclass(frozen=True)
class GridMeasured:
    """One grid of a resolution study: the paired change of C_I against the study's finest grid, in
    units of this grid's own statistical error over the seeds (the answer's error at this grid)."""

    cells_per_diameter: int  # as requested (numerics.stokes.cells_per_diameter)
    grid: str
    fibre_radius_scale: float  # the radius the fibres were voxelised at, over R (1: geometric)
    closure_free: float
    closure_free_stderr: float
    trajectory: float
    trajectory_stderr: float
    cpu_ratio: float  # CPU time per run / the coarsest grid's
    #: numerics.stokes.fibre_shells of the runs ("overlap", the registry's default, or "apart")
    fibre_shells: str = "overlap"

    def change(self) -> float:
        """The larger of the two estimators' changes [statistical errors]."""
        return max(self.closure_free, self.trajectory)


@dataclass(frozen=True)
class ResolutionEvidence:
    """A resolution study of one aspect ratio's semi-dilute scene: its grids, coarsest first; the
    last is the finest, against which the others' changes are measured."""

    beta: float
    scene: str
    grids: tuple[GridMeasured, ...]
    study: str

    @property
    def finest(self) -> GridMeasured:
        return self.grids[-1]

    def choice(self) -> GridMeasured:
        """The coarsest grid within the preset's rule (the finest when none is)."""
        return next((g for g in self.grids[:-1] if admissible(g)), self.finest)

    def at(self, cells_per_diameter: int) -> GridMeasured | None:
        return next((g for g in self.grids if g.cells_per_diameter == cells_per_diameter), None)


def _grids(*rows: tuple, fibre_shells: str = "overlap") -> tuple[GridMeasured, ...]:
    """GridMeasured of rows (cells per diameter, grid, radius scale, closure-free change ± s.e.,
    trajectory change ± s.e., CPU ratio), all run with ``fibre_shells``; the last row, the finest,
    is the reference."""
    return tuple(GridMeasured(*row[:3], closure_free=row[3], closure_free_stderr=row[4], trajectory=row[5],
                              trajectory_stderr=row[6], cpu_ratio=row[7], fibre_shells=fibre_shells) for row in rows)


#: The resolution studies, by β. Changes against the finest grid, paired over the seeds (strain 20
#: from the isotropic start, the numerics of the fluid-coupled series), in statistical errors of
#: the coarser grid's C_I over the same seeds; docs/fluid_coupled_ci.md, "Fibre shells kept apart"
#: and "β = 10: the calibrated C_I against the grid". In the comments: the changes and the coarser
#: grid's error, absolute.
RESOLUTION: Mapping[float, ResolutionEvidence] = MappingProxyType({
    5.0: ResolutionEvidence(
        beta=5.0, scene="98 beta = 5 fibres, n L^3 = 4.98, fibres voxelised at the radius calibrated per grid with "
                        "the shells apart, Zhang's beta_e (the calibrated grid fibre's) in the fits, 8 seeds",
        study="studies/interaction_coefficient/ci_resolution.py --calibrated --shells apart",
        # 8 seeds, so in units of the 8-seed error, sqrt(2) smaller than the 4-seed error the rule names:
        # 42^3: -2.4e-5 +- 1.9e-4 (3.2e-4), -6.5e-5 +- 3.9e-4 (4.6e-4); 54^3: -2.0e-4 +- 2.2e-4 (3.0e-4),
        # -1.5e-4 +- 2.3e-4 (4.7e-4). With the geometric radius (4 seeds) 42^3 moved C_I by 0.82 and 1.64.
        grids=_grids((3, "42^3", 1.129, 0.08, 0.62, 0.14, 0.83, 1.0),
                     (4, "54^3", 1.094, 0.66, 0.74, 0.31, 0.48, 1.82),
                     (5, "70^3", 1.071, 0.0, 0.0, 0.0, 0.0, 4.48), fibre_shells="apart")),
    10.0: ResolutionEvidence(
        beta=10.0, scene="88 beta = 10 fibres, n L^3 = 6.37, fibres voxelised at the radius calibrated per grid",
        study="studies/interaction_coefficient/ci_resolution_beta10.py",
        # 72^3: +6.7e-4 +- 1.6e-4 (2.5e-4), +2.48e-3 +- 3.4e-4 (3.9e-4); 96^3: -1.4e-5 +- 1.8e-5 (1.4e-4),
        # -2.2e-5 +- 4.1e-5 (1.2e-4)
        grids=_grids((3, "72^3", 1.212, 2.68, 0.64, 6.31, 0.87, 1.0),
                     (4, "96^3", 1.100, 0.10, 0.13, 0.18, 0.34, 2.23),
                     (5, "120^3", 1.091, 0.0, 0.0, 0.0, 0.0, 4.39))),
})


def compare_changes(label: str, stored: Measured | GridMeasured,
                    recomputed: Measured | GridMeasured) -> tuple[list[str], list[str]]:
    """A stored change of C_I against one recomputed from runs, per estimator: (notes, disagreements).
    The same runs give the same value; runs remade on another machine are other realisations of a
    chaotic suspension, so a change agrees when it differs from the stored one by at most twice
    their combined standard error."""
    notes, bad = [], []
    for est in ("closure_free", "trajectory"):
        a, b = getattr(stored, est), getattr(recomputed, est)
        width = 2.0 * math.hypot(getattr(stored, f"{est}_stderr"), getattr(recomputed, f"{est}_stderr"))
        if a != b:
            (bad if abs(a - b) > width else notes).append(
                f"{label}/{est}: stored {a:.2f}, recomputed {b:.2f} (2 combined s.e. {width:.2f})")
    return notes, bad


def evidence_check_lines(table: str, notes: list[str], bad: list[str], agreed: str) -> list[str]:
    """A study's Markdown section on its check against the preset's copy ``table`` (a name in
    this module): the disagreements, the notes, and ``agreed`` when nothing disagrees."""
    return (["", f"## Against the preset's copy (pyfold.scene.study_preset.{table})", ""]
            + [f"* disagrees: {b}" for b in bad] + [f"* note: {n}" for n in notes] + ([] if bad else [f"* {agreed}"]))


def resolution_check(beta: float, recomputed: list[GridMeasured]) -> tuple[list[str], list[str]]:
    """A resolution study's grids, recomputed from its runs, against :data:`RESOLUTION` (the
    preset's copy): (notes, disagreements), the changes by :func:`compare_changes`; CPU ratios are
    the machine's and are only noted."""
    stored = resolution_for(beta)
    if stored is None:
        return [], [f"beta = {beta:g}: no resolution study in pyfold/scene/study_preset.py"]
    notes, bad = [], []
    for g in recomputed:
        old = stored.at(g.cells_per_diameter)
        if old is None:
            bad.append(f"{g.cells_per_diameter} voxels per diameter: not in pyfold/scene/study_preset.py")
            continue
        n, b = compare_changes(f"{g.cells_per_diameter} voxels per diameter", old, g)
        notes += n
        bad += b
        if abs(old.fibre_radius_scale - g.fibre_radius_scale) > 1e-9:
            bad.append(f"{g.cells_per_diameter} voxels per diameter: radius scale stored {old.fibre_radius_scale:g}, "
                       f"run at {g.fibre_radius_scale:g}")
        if old.fibre_shells != g.fibre_shells:
            bad.append(f"{g.cells_per_diameter} voxels per diameter: fibre shells stored {old.fibre_shells!r}, "
                       f"run with {g.fibre_shells!r}")
        if old.cpu_ratio != g.cpu_ratio:
            notes.append(f"{g.cells_per_diameter} voxels per diameter: CPU ratio stored {old.cpu_ratio:.2f}, "
                         f"this machine {g.cpu_ratio:.2f}")
    return notes, bad


def admissible(m: Measured | GridMeasured) -> bool:
    """True when the setting's (or grid's) measured change of C_I stays within the preset's rule."""
    return m.change() <= ADMISSIBLE_FRACTION


def _beta_key(beta: float | None, keys) -> float | None:
    return next((k for k in keys if beta is not None and abs(k - beta) <= 1e-6 * k), None)


def evidence_for(regime: str, beta: float | None = None) -> RegimeEvidence | None:
    """The evidence of ``regime`` (dilute: the semi-dilute scene's) at aspect ratio ``beta`` when
    :data:`BETA_EVIDENCE` has it, else the β = 5 scene's (:data:`EVIDENCE`); None without any."""
    reg = "semi-dilute" if regime == "dilute" else regime
    key = _beta_key(beta, [b for r, b in BETA_EVIDENCE if r == reg])
    return BETA_EVIDENCE[reg, key] if key is not None else EVIDENCE.get(reg)


def choice_for(regime: str, beta: float | None = None) -> tuple[RegimeEvidence, Measured] | None:
    """The evidence of ``regime`` (:func:`evidence_for`) and its cheapest admissible setting, its
    changes those against the reference (RegimeEvidence.total; the reference when none is
    cheaper), or None without evidence."""
    ev = evidence_for(regime, beta)
    if ev is None:
        return None
    best = min((t for t in map(ev.total, ev.settings) if admissible(t)), key=lambda m: m.cpu_ratio,
               default=ev.reference)
    return ev, (best if best.cpu_ratio < ev.reference.cpu_ratio else ev.reference)


def resolution_for(beta: float | None) -> ResolutionEvidence | None:
    """The resolution study of aspect ratio ``beta``, or None when none was made."""
    key = _beta_key(beta, RESOLUTION)
    return RESOLUTION[key] if key is not None else None


def probe_scene(scene: Scene) -> Scene:
    """The scene with a provisional dt (t_end / PROBE_STEPS) and the default output intervals
    when it has no dt, and without a grid budget when it states none (the preset may choose a
    finer grid than the default's, and raises the budget to it): the probe only learns the
    regime, the model and the rates."""
    from pyfold.scene import registry

    num = scene.numerics
    if "max_grid_points" not in num.stokes.model_fields_set:
        budget = registry.setting("numerics.stokes.max_grid_points").hi
        num = num.model_copy(update={"stokes": num.stokes.model_copy(update={"max_grid_points": budget})})
    out = scene.output
    if num.dt is None:
        num = num.model_copy(update={"dt": num.t_end / PROBE_STEPS})
        out = out.model_copy(update={"interval": None, "snapshot_interval": None, "checkpoint_interval": None})
    return scene.model_copy(update={"numerics": num, "output": out})


def _dt_for(factor: float, probe, scene: Scene) -> float:
    """The largest step <= factor α/(γ̇ L) (L of the longest family) of which t_end and every
    output interval the scene gives are whole multiples."""
    longest = max(f.length for f in probe.families)
    target = factor * probe.alpha / (probe.shear_rate * longest)
    times = [probe.t_end] + [t for t in (scene.output.interval, scene.output.snapshot_interval,
                                         scene.output.checkpoint_interval) if t]
    base = min(times)
    n = max(1, math.ceil(base / target * (1 - 1e-12)))
    for k in range(n, n + 100_000):
        dt = base / k
        if all(abs(t / dt - round(t / dt)) <= 1e-9 * t / dt for t in times):
            return dt
    return probe.t_end / math.ceil(probe.t_end / target * (1 - 1e-12))


def fill(scene: Scene, probe) -> tuple[Scene, str, tuple[str, ...]]:
    """``scene`` with the preset's values in the numerical keys it leaves unset, the reason, and
    the warnings the run prints (a stated grid that its resolution study found too coarse)."""
    num = scene.numerics
    fibres_in_shear = (all(f.shape == "fibre" for f in probe.families) and not probe.walls
                       and _simple_shear(probe.velocity_gradient))
    betas = sorted({round(f.aspect_ratio, 6) for f in probe.families})
    beta = betas[0] if len(betas) == 1 else None
    picked = choice_for(probe.regime, beta) if fibres_in_shear else None
    if picked is None:
        why = ("no measured evidence for this scene (the preset's measurements are of fibres in simple shear on "
               "the periodic cell)" if not fibres_in_shear else f"no measured evidence for the {probe.regime} regime")
        dt_text = ""
        if num.dt is None:
            dt = _dt_for(1.0, probe, scene)
            scene = scene.model_copy(update={"numerics": num.model_copy(update={"dt": dt})})
            dt_text = f"; dt = {dt:.6g} (a tip moves alpha/2 per step, docs/physics.md#time-step)"
        return scene, f'numerics.preset = "study": {why}: the registry\'s defaults stand{dt_text}', ()
    ev, m = picked
    stokes_set = num.stokes.model_fields_set
    wanted = dict(m.stokes)
    res = resolution_for(beta)
    if res is not None:
        wanted["cells_per_diameter"] = res.choice().cells_per_diameter
    cells = (num.stokes.cells_per_diameter if "cells_per_diameter" in stokes_set
             else wanted.get("cells_per_diameter", num.stokes.cells_per_diameter))
    row = res.at(cells) if res is not None else None
    if row is not None and row.fibre_radius_scale != 1.0:
        wanted["fibre_radius_scale"] = row.fibre_radius_scale
        wanted["fibre_shells"] = row.fibre_shells
    points = _grid_points(probe, cells)
    # the budget follows the grid the preset chose for a Stokes scene; under hydrodynamics = "auto" the
    # budget decides whether the solver runs at all, which is the scene's choice, not a numerical setting
    if ("max_grid_points" not in stokes_set and "cells_per_diameter" not in stokes_set
            and scene.model.hydrodynamics == "stokes" and points > num.stokes.max_grid_points):
        wanted["max_grid_points"] = points
    filled = {k: v for k, v in wanted.items() if k not in stokes_set}
    kept = sorted(k for k in wanted if k in stokes_set)
    updates = {}
    if filled:
        updates["stokes"] = num.stokes.model_copy(update=filled)
    if num.dt is None:
        updates["dt"] = _dt_for(m.dt_factor, probe, scene)
    if updates:
        scene = scene.model_copy(update={"numerics": num.model_copy(update=updates)})
    caveats = []
    if probe.regime == "dilute":
        caveats.append("dilute scene: the semi-dilute scene's measurement applied")
    if set(betas) != {round(ev.beta, 6)}:
        caveats.append(f"measured at beta = {ev.beta:g}, this scene's beta = "
                       f"{', '.join(f'{b:g}' for b in betas)}: not measured")
    chosen = ", ".join(f"{k} = {v!r}" for k, v in filled.items()) or "nothing in [numerics.stokes]"
    if "dt" in updates:
        chosen += f", dt = {updates['dt']:.6g} ({m.dt_factor:g} alpha/(gamma_dot L))"
    measured_on = f"{ev.n_fibres} beta = {ev.beta:g} fibres, n L^3 = {ev.n_l3:.3g}, {ev.seeds} seeds"
    if all(math.isfinite(v) for v in ev.ci_reference):
        measured_on += (f" (closure-free C_I {ev.ci_reference[0]:.2e} +- {ev.ci_reference[1]:.1e} with the "
                        "reference numerics)")
    if m is ev.reference:
        worst = ", ".join(f"{o.name} {ev.total(o).change():.2f}" for o in ev.settings)
        text = (f'numerics.preset = "study": the reference numerics {m.name} ({chosen}) for the {ev.regime} '
                f"regime: measured on {measured_on}, no cheaper setting kept C_I within {ADMISSIBLE_FRACTION:g} "
                f"of its statistical error (largest change of the two estimators: {worst}; {ev.study})")
    else:
        text = (f'numerics.preset = "study": {m.name} ({chosen}) for the {ev.regime} regime: measured on '
                f"{measured_on}{f' ({m.measured_on})' if m.measured_on else ''}, it changes C_I by "
                f"{m.closure_free:.2f} +- {m.closure_free_stderr:.2f} (closure-free) and {m.trajectory:.2f} +- "
                f"{m.trajectory_stderr:.2f} (IBOF trajectory fit) statistical errors against the reference numerics"
                f"{f' ({ev.reference.name}: {ev.reference.measured_on})' if ev.reference.measured_on else ''}, "
                f"at {m.cpu_ratio:.2f} of its CPU time (rule: change <= {ADMISSIBLE_FRACTION:g}; "
                f"{ev.study})")
    if kept:
        text += f"; kept as the scene states: {', '.join(kept)}"
    if "max_grid_points" in filled:
        text += f"; max_grid_points raised to the grid's {points} points"
    warnings: tuple[str, ...] = ()
    if res is None:
        cpd = ev.reference.stokes.get("cells_per_diameter")
        text += (f"; resolution: the measurement is at {cpd} voxels per diameter, where one beta = {ev.beta:g} "
                 f"spheroid's period is off by {100 * ev.period_error:+.0f} %: the C_I is that discretisation's, "
                 "its convergence with the grid not measured at this beta"
                 + (f" (measured at beta = {', '.join(f'{b:g}' for b in RESOLUTION)}: docs/fluid_coupled_ci.md)"
                    if RESOLUTION else ""))
    else:
        cpd = None if m.measured_on else m.stokes.get("cells_per_diameter")
        if cpd is not None and cpd != cells:
            text += f"; the setting was measured at {cpd} voxels per diameter"
        resolution, warnings = _resolution_text(res, cells, "cells_per_diameter" in stokes_set, scene, probe)
        text += "; " + resolution
    if caveats:
        text += "; " + "; ".join(caveats)
    return scene, text, warnings


def _grid_points(probe, cells: int) -> int:
    """Points of the Stokes grid of ``probe``'s cell at ``cells`` voxels per thinnest diameter."""
    from pyfold.scene.normalise import stokes_grid

    grid = stokes_grid(probe.cell_lengths[:probe.dim], 2.0 * min(f.radius for f in probe.families), cells)
    return int(math.prod(grid))


def _changes(g: GridMeasured) -> str:
    return (f"{g.closure_free:.2f} +- {g.closure_free_stderr:.2f} (closure-free) and {g.trajectory:.2f} +- "
            f"{g.trajectory_stderr:.2f} (IBOF trajectory fit)")


def _resolution_text(res: ResolutionEvidence, cells: int, stated: bool, scene: Scene,
                     probe) -> tuple[str, tuple[str, ...]]:
    """What the resolution study says of ``cells`` voxels per diameter, and the warning of a grid
    known to be too coarse."""
    best, finest, row = res.choice(), res.finest, res.at(cells)
    against = (f"statistical errors against {finest.cells_per_diameter} voxels per diameter ({finest.grid}, "
               f"{res.study}, {res.scene})")
    where = "" if probe.regime == "semi-dilute" else f" (measured on the semi-dilute scene; this one is {probe.regime})"
    warnings: list[str] = []
    if not stated:
        coarser = "; ".join(f"{g.cells_per_diameter} voxels per diameter {g.change():.2f}" for g in res.grids
                            if g.cells_per_diameter < best.cells_per_diameter)
        text = (f"resolution: cells_per_diameter = {cells}, the coarsest grid whose C_I stays within "
                f"{ADMISSIBLE_FRACTION:g} of its statistical error: it moves by {_changes(best)} {against}"
                f"{f', coarser grids by {coarser}' if coarser else ''}; {best.cpu_ratio:.2f} times the CPU time of "
                f"{res.grids[0].cells_per_diameter}{where}")
    elif row is not None and row is not finest and not admissible(row):
        text = (f"resolution: cells_per_diameter = {cells} as the scene states is known to be too coarse: its C_I "
                f"moves by {_changes(row)} {against}; {best.cells_per_diameter} voxels per diameter keeps it within "
                f"{ADMISSIBLE_FRACTION:g} at {best.cpu_ratio / row.cpu_ratio:.2f} times the CPU time{where}")
        warnings.append(f"numerics.stokes.cells_per_diameter = {cells} is too coarse for C_I at beta = {res.beta:g}: "
                        f"it moves C_I by {row.change():.2f} statistical errors against the finest grid measured "
                        f"({res.study}); {best.cells_per_diameter} keeps it within {ADMISSIBLE_FRACTION:g}")
    elif row is not None:
        text = (f"resolution: cells_per_diameter = {cells} as the scene states: its C_I moves by {_changes(row)} "
                f"{against}{where}" if row is not finest else
                f"resolution: cells_per_diameter = {cells} as the scene states, the finest grid of {res.study}")
    elif cells < res.grids[0].cells_per_diameter and not admissible(res.grids[0]):
        g = res.grids[0]
        text = (f"resolution: cells_per_diameter = {cells} as the scene states is known to be too coarse: it is "
                f"coarser than {g.cells_per_diameter} voxels per diameter, whose C_I moves by {_changes(g)} {against}")
        warnings.append(f"numerics.stokes.cells_per_diameter = {cells} is too coarse for C_I at beta = {res.beta:g}: "
                        f"{g.cells_per_diameter} already moves C_I by {g.change():.2f} statistical errors against the "
                        f"finest grid measured ({res.study}); {best.cells_per_diameter} keeps it within "
                        f"{ADMISSIBLE_FRACTION:g}")
    else:
        text = (f"resolution: cells_per_diameter = {cells} as the scene states, not measured by {res.study} "
                f"(its grids: {', '.join(str(g.cells_per_diameter) for g in res.grids)} voxels per diameter; "
                f"{best.cells_per_diameter} keeps C_I within {ADMISSIBLE_FRACTION:g})")
    if row is not None and row.fibre_radius_scale != 1.0:
        scale = scene.numerics.stokes.fibre_radius_scale
        if abs(scale - row.fibre_radius_scale) > 1e-9:
            text += (f"; that grid's measurement voxelised the fibres at {row.fibre_radius_scale:g} R "
                     f"(fibre_radius_scale), this scene at {scale:g} R")
        shells = scene.numerics.stokes.fibre_shells
        if shells != row.fibre_shells:
            text += (f"; that grid's measurement ran with fibre_shells = {row.fibre_shells!r}, this scene with "
                     f"{shells!r}")
    return text, tuple(warnings)


def _simple_shear(G) -> bool:
    import numpy as np

    G = np.asarray(G)
    off = G.copy()
    off[0, 1] = 0.0
    return bool(G[0, 1] != 0.0 and np.all(off == 0.0))
