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

__all__ = ["Measured", "RegimeEvidence", "EVIDENCE", "ADMISSIBLE_FRACTION", "admissible", "choice_for",
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

    def settings_error(self, m: "Measured") -> tuple[float, float]:
        """The setting ``m``'s measured change of C_I as an absolute error (closure-free, IBOF
        trajectory fit): the paired change and its standard error added in quadrature, times the
        reference's ensemble error."""
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


def admissible(m: Measured) -> bool:
    """True when the setting's measured change of C_I stays within the preset's rule."""
    return m.change() <= ADMISSIBLE_FRACTION


def choice_for(regime: str) -> tuple[RegimeEvidence, Measured] | None:
    """The evidence of ``regime`` (dilute: the semi-dilute scene's) and its cheapest admissible
    setting (the reference when none is cheaper), or None without evidence."""
    ev = EVIDENCE.get("semi-dilute" if regime == "dilute" else regime)
    if ev is None:
        return None
    best = min((m for m in ev.settings if admissible(m)), key=lambda m: m.cpu_ratio, default=ev.reference)
    return ev, (best if best.cpu_ratio < ev.reference.cpu_ratio else ev.reference)


def probe_scene(scene: Scene) -> Scene:
    """The scene with a provisional dt (t_end / PROBE_STEPS) and the default output intervals
    when it has no dt: the probe only learns the regime, the model and the rates."""
    if scene.numerics.dt is not None:
        return scene
    num = scene.numerics.model_copy(update={"dt": scene.numerics.t_end / PROBE_STEPS})
    out = scene.output.model_copy(update={"interval": None, "snapshot_interval": None, "checkpoint_interval": None})
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


def fill(scene: Scene, probe) -> tuple[Scene, str]:
    """``scene`` with the preset's values in the numerical keys it leaves unset, and the reason."""
    num = scene.numerics
    fibres_in_shear = (all(f.shape == "fibre" for f in probe.families) and not probe.walls
                       and _simple_shear(probe.velocity_gradient))
    picked = choice_for(probe.regime) if fibres_in_shear else None
    if picked is None:
        why = ("no measured evidence for this scene (the preset's measurements are of fibres in simple shear on "
               "the periodic cell)" if not fibres_in_shear else f"no measured evidence for the {probe.regime} regime")
        dt_text = ""
        if num.dt is None:
            dt = _dt_for(1.0, probe, scene)
            scene = scene.model_copy(update={"numerics": num.model_copy(update={"dt": dt})})
            dt_text = f"; dt = {dt:.6g} (a tip moves alpha/2 per step, docs/physics.md#time-step)"
        return scene, f'numerics.preset = "study": {why}: the registry\'s defaults stand{dt_text}'
    ev, m = picked
    stokes_set = num.stokes.model_fields_set
    wanted = dict(m.stokes)
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
    betas = {round(f.aspect_ratio, 6) for f in probe.families}
    if betas != {round(ev.beta, 6)}:
        caveats.append(f"measured at beta = {ev.beta:g}, this scene's beta = "
                       f"{', '.join(f'{b:g}' for b in sorted(betas))}: not measured")
    chosen = ", ".join(f"{k} = {v!r}" for k, v in filled.items()) or "nothing in [numerics.stokes]"
    if "dt" in updates:
        chosen += f", dt = {updates['dt']:.6g} ({m.dt_factor:g} alpha/(gamma_dot L))"
    measured_on = f"{ev.n_fibres} beta = {ev.beta:g} fibres, n L^3 = {ev.n_l3:.3g}, {ev.seeds} seeds"
    if all(math.isfinite(v) for v in ev.ci_reference):
        measured_on += (f" (closure-free C_I {ev.ci_reference[0]:.2e} +- {ev.ci_reference[1]:.1e} with the "
                        "reference numerics)")
    if m is ev.reference:
        worst = ", ".join(f"{o.name} {o.change():.2f}" for o in ev.settings)
        text = (f'numerics.preset = "study": the reference numerics {m.name} ({chosen}) for the {ev.regime} '
                f"regime: measured on {measured_on}, no cheaper setting kept C_I within {ADMISSIBLE_FRACTION:g} "
                f"of its statistical error (largest change of the two estimators: {worst}; {ev.study})")
    else:
        text = (f'numerics.preset = "study": {m.name} ({chosen}) for the {ev.regime} regime: measured on '
                f"{measured_on}, it changes C_I by "
                f"{m.closure_free:.2f} +- {m.closure_free_stderr:.2f} (closure-free) and {m.trajectory:.2f} +- "
                f"{m.trajectory_stderr:.2f} (IBOF trajectory fit) statistical errors against the reference numerics, "
                f"at {m.cpu_ratio:.2f} of its CPU time (rule: change <= {ADMISSIBLE_FRACTION:g}; "
                f"{ev.study})")
    if kept:
        text += f"; kept as the scene states: {', '.join(kept)}"
    cpd = ev.reference.stokes.get("cells_per_diameter")
    text += (f"; resolution: the measurement is at {cpd} voxels per diameter, where one beta = {ev.beta:g} "
             f"spheroid's period is off by {100 * ev.period_error:+.0f} %: the C_I is that discretisation's, "
             "its convergence with the grid not measured")
    if caveats:
        text += "; " + "; ".join(caveats)
    return scene, text


def _simple_shear(G) -> bool:
    import numpy as np

    G = np.asarray(G)
    off = G.copy()
    off[0, 1] = 0.0
    return bool(G[0, 1] != 0.0 and np.all(off == 0.0))
