"""The fluid-coupled C_I of β = 5 and β = 10 fibres against concentration, at steady state.

Question
    What Folgar–Tucker C_I — per closure, and closure-free — does a suspension of rigid
    β = 5 (and β = 10) fibres coupled through the fluid (Stokes solver, fictitious domain on the FFT
    grid, with the collision strategy) have at three concentrations from semi-dilute to
    concentrated, run long enough to reach its steady state? Which closure reproduces the
    fluid-coupled a4, and how far are the contacts-only twins (the same seeds and
    initial states, Jeffery kinematics + contacts) from it? This is the table
    data/ci_fluid_coupled.{nc,csv} and the fit pyfold.correlations.fluid_coupled_ci.

Method
    Scenes: pyfold.scene.sheared_fibres, β = 5 (L = 1, d = 0.2), cubic cell 2.7 L, simple
    shear γ̇ = 1 from an isotropic random placement, security zone α = 0.1 d,
    Δt = α/(γ̇L) = 0.02, records every 0.2 strain, strain 200 (about 6 Jeffery periods of a
    single fibre), n L³ = 2.49 / 4.98 / 7.98 (49 / 98 / 157 fibres, φβ = 0.39 / 0.78 / 1.25),
    4 seeds (studies/sweeps/ci_fluid_series.toml). ``--beta 10`` (studies/sweeps/
    ci_fluid_series_beta10.toml): β = 10 (d = 0.1), cell 2.4 L, Δt = 0.01, φβ = 0.5 / 0.25 / 1.0
    (n L³ = 6.37 / 3.18 / 12.7; 88 / 44 / 176 fibres; Meyer et al. 2020's middle point first), the
    same Stokes numerics on a 72³ grid. Stokes numerics (STOKES): 3 voxels per
    diameter (42³), κ = 10³, CG tolerance 10⁻³, a solve every 4th step, AB2: the cheapest
    setting measured by studies/speed_accuracy/ci_stokes_settings.py (its CPU time 0.21–0.22
    of the reference's).
    Each (n L³, model) ensemble is analysed as ``pyfold report`` does (pyfold.report.build_report):
    MSER-5 steady-state onset and drift per run; the rate-regression C_I over each run's
    stationary window per closure and with the run's own a4 (closure-free); the trajectory fit
    of Folgar–Tucker per closure to a2(t) over two Jeffery periods from the isotropic start
    (the C_I a moulding code running that closure should use); the closures ranked by their
    a4:D error against the runs' own a4 (paired t-tests, Holm-adjusted).
    Errors in the table, per estimate: the statistical error (pyfold.ensemble: the larger of
    the scatter over seeds and the pooled run errors); the settings error, the measured
    change of C_I of this setting against the reference numerics (κ 10³, tolerance 10⁻⁴, a solve
    every step) on the same regime, paired change and its s.e. in quadrature
    (pyfold.scene.study_preset.RegimeEvidence.settings_error; measured at strain 30 from the
    isotropic start, applied here to every estimator); the shape-factor sensitivity, the
    change of C_I when the Jeffery term is subtracted with the rotation rate the solver gives
    one fibre on this grid (single-fibre check: its β_e from the orbit period, as
    ci_hydrodynamics.py) instead of Cox's β_e (how much of the C_I rests on the 3-voxel
    fibre's kinematics); the resolution error, the bias of the 3-voxel C_I against the
    Richardson limit measured by ci_resolution.py on the semi-dilute scene (three grids,
    paired seeds; closure-free for the rate regressions, IBOF for the trajectory fits;
    applied to every concentration). The total error is the four in quadrature. At β = 10 the
    settings error is the β = 5 regime's (not measured at β = 10); the geometric series' resolution
    error is not measured: its column is NaN, ``resolution_in_total`` = 0 and the total leaves it out.
    The calibrated series' is the bias of its 96³ C_I against the Richardson limit of 96³ and
    120³ (all calibrated) measured by ci_resolution_beta10.py on the φβ = 0.5 scene
    (RESOLUTION_BETA10; applied to every concentration; left out, as unmeasured, while that file
    is missing).
    ``--beta 10 --calibrated`` (ci_fluid_series_beta10_calibrated.toml): the same scenes and
    seeds, the Stokes runs on 96³ (4 voxels per diameter: on 72³ the calibrated C_I is not
    converged) with their fibres voxelised at 1.100 times their radius (one fibre there then
    turns with β_e 7.63, the converged cylinder's, ci_resolution.py's calibrate_scale) and both
    models recording Zhang's β_e, so every fit uses the ξ of the fibres simulated; the shape
    column is then the calibration's residual (the grid fibre's measured β_e at that scale).
    It steps at Δt = 2α/(γ̇L) = 0.02, twice the geometric series' step, both models (the
    change of C_I measured by studies/speed_accuracy/time_step_beta10.py), and its Stokes runs
    solve every 16th step with numerics.stokes.reuse = "jeffery" between solves; the change of
    C_I that makes joins the settings error in quadrature, measured as close to each point as
    there is a measurement (reuse_evidence): at φβ = 1.0 on 96³ by solve_reuse.py --beta 10
    --concentrated (REUSE_EVIDENCE_CONCENTRATED), at φβ = 0.5 on 96³ by ci_resolution_beta10.py's
    control (φβ = 0.25 takes that one), else on 72³ by studies/speed_accuracy/solve_reuse.py
    --beta 10 (REUSE_EVIDENCE).
    ``--calibrated --shells apart`` at β = 5 (ci_fluid_series_calibrated_apart.toml): the β = 5 series'
    scenes and seeds on the same 42³ grid with the fibres of the Stokes runs voxelised at 1.129 R
    (one fibre there turns with Zhang's β_e, 4.11) and the shells that adds kept the security zone
    apart, both models recording Zhang's β_e: the grid numerics.preset = "study" takes at β = 5.
    It adds three concentrations to the three, n L³ = 1.52 / 3.51 / 6.50 (30 / 69 / 128 fibres,
    φβ = 0.24 / 0.55 / 1.02), and its rows are the shipped table's β = 5 rows (--write-data).
    Its resolution error is the bias of the 42³ C_I against the Richardson limit of 54³ and 70³
    (all calibrated, shells apart, with the grid fibre's ξ; seeds 1-8) measured by
    ci_resolution.py --calibrated --shells apart (RESOLUTION_CALIBRATED_APART).
    Steady state: every run goes to strain 200; the MSER-5 onset and the end drift of each
    run are in the table (the study's rule: a detected steady state, or strain ≥ 200 with
    its drift reported).

Command
    .venv/bin/python studies/interaction_coefficient/ci_fluid_series.py [--executor slurm] [--seeds 1 2]
    .venv/bin/python studies/interaction_coefficient/ci_fluid_series.py --beta 10   # the β = 10 sweep
        (analysed once a concentration has two finished pairs of runs; no --write-data)
    .venv/bin/python studies/interaction_coefficient/ci_fluid_series.py --beta 10 --calibrated [--write-data]
        (--write-data: its rows replace the table's β = 10 rows, the β = 5 rows stay)
    .venv/bin/python studies/interaction_coefficient/ci_fluid_series.py --calibrated --shells apart [--write-data]
        (the β = 5 series at the preset's grid, six concentrations; --write-data: its rows replace the
        table's β = 5 rows; the geometric β = 5 series is analysed into --out only)
    (the sweep runs two serial simulations at a time; finished runs are re-used, a killed one
    is resumed from its checkpoint; --analyse-only analyses what is there)

Cost (2 cores)
    Measured (CPU time per run, two serial runs at a time on the shared 2-core machine):
    Stokes runs 641–689 / 822–847 / 874–887 CPU-s at n L³ 2.49 / 4.98 / 7.98, i.e. 0.7–1.0
    CPU-hour per point of 4 seeds; contacts-only twins 5–20 CPU-s. The sweep took 115 min
    wall sharing the machine with the resolution study; the analysis about 6 CPU-min.
    β = 10: about 33 CPU-s per unit strain per Stokes run at φβ = 0.5 (7 000 CPU-s per run,
    ~7 CPU-hours per point of 4 seeds; docs/fluid_coupled_ci.md#cost), contacts-only twins ~1 CPU-min;
    calibrated, at twice the step and a solve every 16th step: about 9 CPU-s per unit strain on
    96³ (ci_resolution_beta10.py); measured: 1822 / 1940 / 2787 CPU-s per Stokes run, 2.0 / 2.2 / 3.1
    CPU-hours per point of 4 seeds at φβ = 0.25 / 0.5 / 1.0; the analysis of the three points 4 min.
    β = 5 on the preset's grid (--calibrated --shells apart): 463 / 579 / 630 / 857 / 787 / 866–878
    CPU-s per Stokes run at n L³ 1.52 / 2.49 / 3.51 / 4.98 / 6.50 / 7.98, twins 3–30 CPU-s: 0.52 /
    0.65 / 0.71 / 0.97 / 0.90 / 1.00 CPU-hours per point (docs/fluid_coupled_ci.md#cost); the
    analysis of the six points 5 min.

Outputs (under out/interaction_coefficient/fluid_series/, β = 10: fluid_series_beta10/, + _calibrated[_apart]/;
``--out``)
    sweep/                        the runs (pyfold sweep folder)
    nl3_<n>/stokes/, .../jeffery/ the report of each ensemble (pyfold report's files)
    ci_fluid_series.nc, .csv      the table (one row per n L³, model, closure and estimator)
    ci_fluid_series.md            the tables, closure ranking, steady state and cost
    ci_fluid_series.png           C_I against φβ beside the published values and correlations

References
    Folgar & Tucker (1984), J. Reinf. Plast. Compos. 3:98; Bay (1991), PhD thesis UIUC;
    Phan-Thien et al. (2002), JNNFM 103:251; Salahuddin, Wu & Aidun (2012), JFM 692;
    Meyer et al. (2020), J. Compos. Sci. 4:77; Chung & Kwon (2002), J. Rheol. 46:169 (IBOF).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from pyfold.scene import registry
from pyfold.scene.sheared_fibres import sheared_fibres

ROOT = Path(__file__).resolve().parents[2]
SWEEPS = ROOT / "studies" / "sweeps"
ALPHA_OVER_D = 0.1
BETA = 5.0
MODELS = ("stokes", "jeffery")  # fluid-coupled with contacts, contacts only
#: The Stokes numerics of every fluid-coupled run: the cheapest setting measured by
#: studies/speed_accuracy/ci_stokes_settings.py (its change of C_I enters the error bars).
STOKES = {"cells_per_diameter": 3, "kappa": 1e3, "tolerance": 1e-3, "solve_every": 4}
SETTING = "tol1e-3_every4"  # its name in pyfold.scene.study_preset.EVIDENCE
#: The sweep (studies/sweeps/<name>.toml) of each aspect ratio
SERIES = {5.0: "ci_fluid_series", 10.0: "ci_fluid_series_beta10"}
#: The shipped table (``--write-data``), read by pyfold.correlations.fluid_coupled_table
DATA = ROOT / "data" / "ci_fluid_coupled"


def scene_of(n_l3: float, model: str, seed: int, t_end: float, beta: float = BETA,
             max_grid_points: int | None = None, fibre_radius_scale: float = 1.0,
             equivalent_aspect_ratio: str | None = None, dt: float | None = None,
             solve_every: int | None = None, reuse: str | None = None, cells_per_diameter: int | None = None,
             fibre_shells: str | None = None):
    """The sweep's builder: ``beta`` fibres at ``n_l3``, ``model`` "stokes" or "jeffery", seed ``seed``
    (``max_grid_points``: the Stokes grid bound, for the finer grids of slender fibres;
    ``fibre_radius_scale``: the Stokes runs' voxelised radius over the geometric one;
    ``equivalent_aspect_ratio``: the rule of the Jeffery β_e both models record, None the default;
    ``dt``: the time step, None for α/(γ̇L); ``solve_every``: the Stokes runs' solve interval in
    steps, None for STOKES'; ``reuse``: numerics.stokes.reuse of the Stokes runs, None its default;
    ``cells_per_diameter``: the Stokes grid's voxels per diameter, None for STOKES'; ``fibre_shells``:
    numerics.stokes.fibre_shells of the Stokes runs, None its default)."""
    if model == "jeffery":
        return sheared_fibres(beta, n_l3, seed, t_end, alpha_over_d=ALPHA_OVER_D,
                              equivalent_aspect_ratio=equivalent_aspect_ratio, dt=dt)
    stokes = STOKES if max_grid_points is None else {**STOKES, "max_grid_points": int(max_grid_points)}
    if fibre_radius_scale != 1.0:
        stokes = {**stokes, "fibre_radius_scale": float(fibre_radius_scale)}
    if solve_every is not None:
        stokes = {**stokes, "solve_every": int(solve_every)}
    if reuse is not None:
        stokes = {**stokes, "reuse": str(reuse)}
    if cells_per_diameter is not None:
        stokes = {**stokes, "cells_per_diameter": int(cells_per_diameter)}
    if fibre_shells is not None:
        stokes = {**stokes, "fibre_shells": str(fibre_shells)}
    return sheared_fibres(beta, n_l3, seed, t_end, alpha_over_d=ALPHA_OVER_D, hydrodynamics="stokes",
                          stokes=stokes, time_scheme="ab2", equivalent_aspect_ratio=equivalent_aspect_ratio, dt=dt)


def settings_errors(n_l3: float, beta: float = BETA) -> tuple[float, float]:
    """(closure-free, trajectory) absolute error of SETTING in the regime of ``n_l3`` (measured on
    β = 5 fibres, pyfold.scene.study_preset.EVIDENCE; applied to another β as the measured value of
    its regime, which the tables say)."""
    from pyfold.scene.shapes import regime
    from pyfold.scene.study_preset import choice_for

    reg, _ = regime(n_l3, 1.0, 1.0 / beta, 3)
    ev, _ = choice_for(reg)
    m = next(s for s in ev.settings if s.name == SETTING)
    return ev.settings_error(m)


def solve_label(solve_every: int, reuse: str = "linear") -> str:
    """The name of a Stokes solve setting in the solve-interval studies' tables and files: its
    interval and its estimate between solves ("every 16, jeffery")."""
    return f"every {int(solve_every)}, {reuse}"


#: The solve-reuse study (studies/speed_accuracy/solve_reuse.py --beta 10): the measured change of C_I
#: of each solve interval and estimate between solves against the series' every 4th step
REUSE_EVIDENCE = Path("out/speed_accuracy/solve_reuse_beta10/solve_reuse.nc")
#: ... and at φβ = 1.0 on the calibrated series' 96³ grid (solve_reuse.py --beta 10 --concentrated)
REUSE_EVIDENCE_CONCENTRATED = Path("out/speed_accuracy/solve_reuse_beta10_concentrated/solve_reuse.nc")


def reuse_errors(arguments: dict, evidence: Path = REUSE_EVIDENCE, grid_evidence: Path | None = None,
                 point_evidence: Path | None = None, n_l3: float | None = None) -> tuple[float, float] | None:
    """(closure-free, trajectory) error of a sweep's solve interval and estimate between solves
    (``arguments`` solve_every, reuse) against STOKES' every 4th step: the paired change and its
    s.e. in quadrature (closure-free; IBOF trajectory for the trajectory fits); None when the sweep
    keeps STOKES' solves. :func:`reuse_evidence` says where it was measured."""
    found = reuse_evidence(arguments, evidence, grid_evidence, point_evidence, n_l3)
    return None if found is None else found[0]


def reuse_evidence(arguments: dict, evidence: Path = REUSE_EVIDENCE, grid_evidence: Path | None = None,
                   point_evidence: Path | None = None, n_l3: float | None = None
                   ) -> tuple[tuple[float, float], str] | None:
    """:func:`reuse_errors` and where it was measured, the closest measurement first: at this
    concentration ``n_l3`` on the sweep's grid (``point_evidence``, a solve_reuse.py output whose
    attributes name its n L³ and grid, e.g. REUSE_EVIDENCE_CONCENTRATED); at φβ = 0.5 on the sweep's
    grid (``grid_evidence``, ci_resolution_beta10.py's summary, ``solve_interval``); at φβ = 0.5
    on 72³ (``evidence``, solve_reuse.py --beta 10). At β = 5 and φ = 0.16 a solve every 16th step
    fails the rule (docs/speed_accuracy.md#fewer-stokes-solves-at-β--10), so a concentration without
    its own measurement carries the φβ = 0.5 one, which the source says. SystemExit naming the study
    when the last resort is missing or lacks the setting."""
    import json

    import xarray as xr

    if "solve_every" not in arguments and "reuse" not in arguments:
        return None
    name = solve_label(arguments.get("solve_every", STOKES["solve_every"]), arguments.get("reuse", "linear"))
    cells = int(arguments.get("cells_per_diameter", STOKES["cells_per_diameter"]))

    def row_of(ds, path: Path) -> tuple[float, float]:
        if name not in list(ds["setting"].values):
            raise SystemExit(f"{path} has no setting '{name}' (it has {list(ds['setting'].values)})")
        row = ds.sel(setting=name)
        return tuple(math.hypot(float(row[f"change_{est}"]), float(row[f"change_{est}_stderr"]))
                     for est in ("closure_free", "ibof_trajectory"))

    if point_evidence is not None and n_l3 is not None and point_evidence.is_file():
        with xr.open_dataset(point_evidence, engine="h5netcdf") as ds:
            if (abs(float(ds.attrs.get("n_l3", math.nan)) - n_l3) <= 1e-9 * n_l3
                    and int(ds.attrs.get("cells_per_diameter", -1)) == cells and name in list(ds["setting"].values)):
                return row_of(ds, point_evidence), f"n L^3 {n_l3:g} on its grid ({point_evidence})"
    if grid_evidence is not None and grid_evidence.is_file():
        control = json.loads(grid_evidence.read_text(encoding="utf-8")).get("solve_interval")
        if control and control["series"] == name and control["cells_per_diameter"] == cells:
            return (tuple(math.hypot(control[est]["change"], control[est]["stderr"])
                          for est in ("closure_free", "ibof_trajectory")),
                    f"phi beta 0.5 on this grid ({grid_evidence})")
    if not evidence.is_file():
        raise SystemExit(f"the sweep solves '{name}': its change of C_I is measured by "
                         f"studies/speed_accuracy/solve_reuse.py --beta 10, whose {evidence} is missing; run it first")
    with xr.open_dataset(evidence, engine="h5netcdf") as ds:
        return row_of(ds, evidence), f"phi beta 0.5 on 72^3 ({evidence})"


def xi_sensitivity(rep, xi_grid: float, fits_out: dict[str, list[float]] | None = None
                   ) -> dict[tuple[str, str], float]:
    """Change of each ensemble C_I when the Jeffery term uses ``xi_grid`` instead of the runs' xi:
    (closure, "steady") for the rate regressions, (closure, "trajectory") for the fits. The
    per-run trajectory fits with ``xi_grid`` go to ``fits_out[closure]`` (in the order of
    ``rep.runs``, NaN where the report has no fit)."""
    from pyfold.ci_estimators import ci_rate_regression
    from pyfold.closures import get_closure
    from pyfold.fast_fit import fit_ci_rk4
    from pyfold.run_results import open_run

    out: dict[tuple[str, str], float] = {}
    regs: dict[str, list[float]] = {c: [] for c in rep.closures}
    for r in rep.runs:
        ds = open_run(r.path)
        t, a2, a4 = ds["time"].values, ds["a2"].values, ds["a4"].values
        ds.close()
        keep = (t >= r.window[0]) & (t <= r.window[1])
        for c in rep.closures:
            a4c = a4[keep] if c == "exact" else np.asarray(get_closure(c, 3)(a2[keep]))
            regs[c].append(ci_rate_regression(t[keep], a2[keep], a4c, rep.L, xi_grid).ci)
    for c in rep.closures:
        out[c, "steady"] = float(np.mean(regs[c])) - float(np.mean([r.ci[c] for r in rep.runs]))
    for c in rep.judged:
        kept = [k for k, v in enumerate(rep.ci_fit_runs[c]) if math.isfinite(v)]
        fits = [fit_ci_rk4(c, rep.runs[k].t, rep.runs[k].a2, rep.L, xi_grid, t_end=rep.fit_window[1]).ci
                for k in kept]
        out[c, "trajectory"] = float(np.mean(fits)) - float(np.mean([rep.ci_fit_runs[c][k] for k in kept]))
        if fits_out is not None:
            per_run = [math.nan] * len(rep.runs)
            for k, v in zip(kept, fits):
                per_run[k] = v
            fits_out[c] = per_run
    return out


def grid_of(path: Path) -> list[int]:
    """The Stokes grid of the run ``path`` (its resolved setup)."""
    from pyfold.run_input import read_setup

    return [int(g) for g in np.ravel(read_setup(path).resolved["stokes_grid"])]


def beta_e_on(grid: list[int], side: float, cache: Path, beta: float = BETA, fibre_radius_scale: float = 1.0) -> float:
    """β_e of one fibre on ``grid`` in the cell ``side`` at the series' κ and tolerance: the orbit
    period of ci_hydrodynamics.py's single-fibre check (the solver's ω(θ) at fixed orientations),
    with its voxelised radius ``fibre_radius_scale`` times the geometric one; cached in ``cache``."""
    import dataclasses

    sys.path.insert(0, str(ROOT / "studies" / "interaction_coefficient"))
    import ci_hydrodynamics as ch  # noqa: E402

    study = dataclasses.replace(ch.SMALL, beta=beta, tolerance=STOKES["tolerance"], kappa=STOKES["kappa"],
                                check_refinements=(1,), max_grid_points=max(ch.SMALL.max_grid_points, math.prod(grid)))
    ds = ch.single_fibre_check(study, grid, side, cache, fibre_radius_scale)
    return float(ds["beta_e_measured"].sel(shape="fibre").values[0])


def grid_xi(out: Path, run: Path, beta: float = BETA) -> tuple[float, float]:
    """(β_e, xi) of one fibre on the grid of the Stokes run ``run``, voxelised at the run's fibre
    radius scale (:func:`beta_e_on`)."""
    from pyfold.kinematics import aspect_ratio_to_xi
    from pyfold.run_input import read_setup

    scale = float(np.ravel(read_setup(run).resolved.get("stokes_fibre_radius_scale", 1.0))[0])
    cache = out / ("single_fibre_check.nc" if scale == 1.0 else f"single_fibre_check_s{scale:.3f}.nc")
    beta_e = beta_e_on(grid_of(run), scene_of(5.0, "stokes", 1, 1.0, beta).side, cache, beta, scale)
    return beta_e, float(aspect_ratio_to_xi(beta_e))


#: The β = 10 resolution check of the calibrated series (ci_resolution_beta10.py: 72³, 96³, 120³)
RESOLUTION_BETA10 = Path("out/interaction_coefficient/resolution_beta10/ci_resolution_beta10.json")
#: ... and with the calibrated radius' shells kept apart (ci_resolution_beta10.py --shells apart): the
#: resolution error of the 96³ grid with that rule
RESOLUTION_BETA10_APART = Path("out/interaction_coefficient/resolution_beta10_apart/ci_resolution_beta10.json")
#: The β = 10 checks whose summaries carry a resolution error of the calibrated series' grid
RESOLUTION_BETA10_FILES = (RESOLUTION_BETA10, RESOLUTION_BETA10_APART)
#: The β = 5 grids with the calibrated radius and its shells apart (ci_resolution.py --calibrated --shells
#: apart, seeds 1-8): the resolution error of the calibrated β = 5 series' 42³ C_I, with the grid fibre's ξ
#: (its keys; Zhang's β_e, which that series records)
RESOLUTION_CALIBRATED_APART = Path("out/interaction_coefficient/resolution_calibrated_apart/ci_resolution.json")
RESOLUTION_GRID_XI_KEYS = ("closure_free_grid", "ibof_trajectory_grid")
#: The rules for the shells of a calibrated radius (numerics.stokes.fibre_shells), the registry's words
SHELL_RULES = registry.setting("numerics.stokes.fibre_shells").choices


def resolution_errors(path: Path, keys: tuple[str, str] = ("closure_free_cox", "ibof_trajectory_cox")
                      ) -> tuple[float, float]:
    """(closure-free, trajectory) resolution error of the 3-voxel C_I: the bias of the coarse grid
    measured by ci_resolution.py (against the Richardson limit; ξ of Cox, as the β = 5 runs here) or,
    with ``keys`` ("closure_free", "ibof_trajectory"), by ci_resolution_beta10.py (against 96³; the
    recorded ξ, as the calibrated runs): |mean| and its s.e. in quadrature, NaN when absent."""
    import json

    if not path.is_file():
        return math.nan, math.nan
    summary = json.loads(path.read_text(encoding="utf-8"))

    def one(key):
        b = summary[key]
        return math.hypot(b["coarse_bias"], b["coarse_bias_stderr"])

    return one(keys[0]), one(keys[1])


def table_rows(n_l3: float, model: str, rep, settings: tuple[float, float], xi_shift: dict,
               resolution: tuple[float, float] = (math.nan, math.nan), beta: float = BETA,
               resolution_unmeasured: bool = False) -> list[dict]:
    """One row per closure and estimator of an ensemble report. ``resolution_unmeasured``: no
    resolution study exists for this β, so a NaN resolution error is left out of the total and
    the row says so (``resolution_in_total`` = 0); otherwise a NaN one (its file missing) makes
    the total NaN, as an unknown error must."""
    from pyfold.correlations import phi_beta, volume_fraction

    rows = []
    stationary = sum(r.stationary for r in rep.runs)
    onsets = [r.onset_time for r in rep.runs if math.isfinite(r.onset_time)]
    strain = float(min(r.t[-1] for r in rep.runs))
    base = {"beta": beta, "n_l3": round(rep.n_l3, 4), "phi": round(volume_fraction(rep.n_l3, beta), 5),
            "phi_beta": round(phi_beta(rep.n_l3, beta), 5), "model": model, "seeds": rep.n,
            "stationary_runs": stationary, "onset_strain_max": max(onsets) if onsets else math.nan,
            "strain": strain,
            # the largest end-of-run drift of a diagonal a2 component over the runs [per unit strain], and
            # the largest in units of its standard error (pyfold.steady_state: > 3 flags a drift)
            "drift_max": max(abs(v[0]) for r in rep.runs for v in r.drift.values()),
            "drift_max_sigma": max(abs(v[0]) / v[1] for r in rep.runs for v in r.drift.values() if v[1] > 0)}
    fluid = model == "stokes"
    for est, table, names in (("steady", rep.ci, rep.closures), ("trajectory", rep.ci_fit, rep.judged)):
        for c in names:
            e = table[c]
            if not math.isfinite(e.mean):  # every seed's fit on its bound or failed: no value (the report says so)
                continue
            set_err = (settings[0] if est == "steady" else settings[1]) if fluid else 0.0
            shape_err = abs(xi_shift.get((c, est), 0.0)) if fluid else 0.0
            res_err = (resolution[0] if est == "steady" else resolution[1]) if fluid else 0.0
            stat = e.error
            known = math.isfinite(res_err) or not resolution_unmeasured
            rows.append({**base, "closure": "closure-free" if c == "exact" else c, "estimator": est,
                         "ci": e.mean, "stat_err": stat, "settings_err": set_err, "shape_err": shape_err,
                         "resolution_err": res_err,
                         "total_err": math.sqrt(stat ** 2 + set_err ** 2 + shape_err ** 2 + (res_err ** 2 if known else 0.0)),
                         "resolution_in_total": int(known)})
    return rows


def write_table(rows: list[dict], stem: Path, attrs: dict) -> None:
    """``stem``.csv (one row per line, header first) and ``stem``.nc (xarray, a row dimension)."""
    import csv

    import xarray as xr

    stem.parent.mkdir(parents=True, exist_ok=True)
    keys = list(rows[0])
    with open(stem.with_suffix(".csv"), "w", newline="", encoding="utf-8") as f:
        for k, v in attrs.items():
            f.write(f"# {k}: {v}\n")
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    units = {"ci": "1", "stat_err": "1", "settings_err": "1", "shape_err": "1", "resolution_err": "1",
             "total_err": "1", "strain": "1",
             "onset_strain_max": "1", "phi": "1", "phi_beta": "1", "n_l3": "1", "drift_max": "1",
             "drift_max_sigma": "1"}
    ds = xr.Dataset({k: ("row", [r[k] for r in rows], {"units": units[k]} if k in units else {}) for k in keys},
                    attrs={k: str(v) for k, v in attrs.items()})
    ds.to_netcdf(stem.with_suffix(".nc"), engine="h5netcdf")


def read_attrs(csv_path: Path) -> dict[str, str]:
    """The ``# key: value`` lines heading a table written by :func:`write_table`."""
    attrs = {}
    with open(csv_path, encoding="utf-8") as f:
        for line in f:
            if not line.startswith("# "):
                break
            key, _, value = line[2:].rstrip("\n").partition(": ")
            attrs[key] = value
    return attrs


def merged_table(rows: list[dict], attrs: dict, beta: float, csv_path: Path) -> tuple[list[dict], dict]:
    """The shipped table at ``csv_path`` with this aspect ratio's rows replaced by ``rows``: the
    other aspect ratios' rows kept, each aspect ratio's header lines prefixed ``beta<β>_`` (a
    table of one aspect ratio has them unprefixed), the columns of ``rows`` (a column an older
    row lacks: ``resolution_in_total`` is whether its resolution error is finite)."""
    import re

    from pyfold.correlations import fluid_coupled_table

    old = fluid_coupled_table(csv_path) if csv_path.is_file() else []
    old_attrs = read_attrs(csv_path) if csv_path.is_file() else {}
    old_betas = sorted({r["beta"] for r in old})
    per_beta: dict[float, dict] = {}
    for key, value in old_attrs.items():
        m = re.fullmatch(r"beta([0-9.]+)_(.+)", key)
        if m:
            per_beta.setdefault(float(m[1]), {})[m[2]] = value
        elif key != "title" and len(old_betas) == 1:
            per_beta.setdefault(old_betas[0], {})[key] = value
    per_beta[beta] = {k: v for k, v in attrs.items() if k != "title"}
    kept = [r for r in old if r["beta"] != beta]
    for r in kept:
        r.setdefault("resolution_in_total", int(math.isfinite(r["resolution_err"])))
    keys = list(rows[0])
    merged = sorted([{k: r[k] for k in keys} for r in kept] + rows, key=lambda r: r["beta"])
    betas = sorted({r["beta"] for r in merged})
    head = {"title": "Fluid-coupled (Stokes + contacts) and contacts-only Folgar-Tucker C_I of beta = "
                     + ", ".join(f"{b:g}" for b in betas) + " fibres"}
    for b in betas:
        head.update({f"beta{b:g}_{k}": v for k, v in per_beta.get(b, {}).items()})
    return merged, head


def figure(rows: list[dict], path: Path) -> None:
    """C_I against φβ: fluid-coupled and contacts-only beside the published values, one colour
    per aspect ratio of ``rows``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pyfold.correlations import CORRELATIONS, FOLGAR_TUCKER_1984, MEYER_2020, SALAHUDDIN_2012_ORDER

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    pb = np.linspace(0.02, 2.6, 200)
    for ax, est in zip(axes, ("trajectory", "steady")):
        for name, (fn, _) in CORRELATIONS.items():
            ax.plot(pb, fn(pb), lw=1, label=name)
        ax.plot([v.phi_beta for v in FOLGAR_TUCKER_1984], [v.ci for v in FOLGAR_TUCKER_1984], "ks",
                label="Folgar & Tucker 1984 (exp.)")
        ax.plot([v.phi_beta for v in MEYER_2020], [v.ci for v in MEYER_2020], "kD", mfc="none",
                label="Meyer et al. 2020 (SPH, β 10, FT fit)")
        ax.axhline(SALAHUDDIN_2012_ORDER, color="grey", ls=":", label="Salahuddin et al. 2012 (LB), order")
        for colour, beta in zip(("tab:blue", "tab:red", "tab:green"), sorted({float(r["beta"]) for r in rows})):
            for model, closure, mk in (("stokes", "ibof", "o"), ("stokes", "closure-free", "^"),
                                       ("jeffery", "ibof", "x"), ("jeffery", "closure-free", "v")):
                sel = [r for r in rows if float(r["beta"]) == beta and r["model"] == model
                       and r["closure"] == closure and r["estimator"] == est]
                if not sel:
                    continue
                word = "fluid-coupled" if model == "stokes" else "contacts only"
                ax.errorbar([r["phi_beta"] for r in sel], [r["ci"] for r in sel], [r["total_err"] for r in sel],
                            fmt=mk, color=colour, capsize=3, label=f"pyfold β {beta:g}, {word}, {closure}")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel("φβ")
        ax.set_ylabel("C_I")
        ax.set_title("trajectory fit (2 Jeffery periods from isotropic)" if est == "trajectory"
                     else "rate regression over the stationary window")
    for ax in axes:
        ax.legend(fontsize=6.5)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def markdown(rows, reps, cost, beta_e_grid, beta: float = BETA, grid: str = "42³") -> str:
    """The tables of ci_fluid_series.md."""
    from pyfold.kinematics import equivalent_aspect_ratio

    lines = [f"# Fluid-coupled C_I of β = {beta:g} fibres against concentration", "",
             f"Single fibre on the {grid} grid: β_e = {beta_e_grid:.3f} from its orbit period "
             f"(Cox: {float(equivalent_aspect_ratio(beta)):.2f}).", ""]
    if any(not r["resolution_in_total"] for r in rows if r["model"] == "stokes"):
        lines += [f"The resolution error was measured for β = {BETA:g} only (ci_resolution.py): at β = {beta:g} "
                  "it is *not measured*, and the total below leaves it out.", ""]
    if beta != BETA:
        lines += [f"The settings error is the one measured on β = {BETA:g} fibres in the same regime "
                  "(pyfold.scene.study_preset.EVIDENCE), not at this β.", ""]
    lines += ["| n L³ | φβ | model | closure | estimator | C_I | stat. | settings | shape | resolution | total |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['n_l3']:.2f} | {r['phi_beta']:.2f} | {r['model']} | {r['closure']} | {r['estimator']} | "
                     f"{r['ci']:+.2e} | {r['stat_err']:.1e} | {r['settings_err']:.1e} | {r['shape_err']:.1e} | "
                     f"{r['resolution_err']:.1e} | {r['total_err']:.1e} |")
    lines += ["", "## Steady state, closure ranking (fluid-coupled a4) and cost", ""]
    for (n_l3, model), rep in sorted(reps.items()):
        onsets = ", ".join(f"{r.onset_time:.0f}" if math.isfinite(r.onset_time) else "none" for r in rep.runs)
        rank = " ".join(f"{e.name} {e.mean:.3g}" + ("" if not math.isfinite(e.p_next) else
                                                     f" {'<' if e.better_than_next else '≈'} (p {e.p_next:.2g})")
                        for e in rep.ranking)
        drift = max(abs(v[0]) for r in rep.runs for v in r.drift.values())
        lines.append(f"* n L³ {n_l3:g}, {model}: stationary {sum(r.stationary for r in rep.runs)}/{rep.n} "
                     f"(onset strains {onsets}; largest end drift of a diagonal a2 component {drift:.1e} per "
                     f"unit strain); a4:D error ranking {rank}; CPU per run "
                     f"{cost.get((n_l3, model), math.nan):.0f} s (mean)")
    return "\n".join(lines) + "\n"


def fit_lines(rows: list[dict], beta: float) -> list[str]:
    """The linear fits in φβ of this series' fluid-coupled rows that pyfold.correlations.fluid_coupled_ci
    quotes (FLUID_COUPLED_QUOTED), one Markdown bullet each, as the shipped table's fit of this β gives them."""
    from pyfold.correlations import FLUID_COUPLED_QUOTED, fluid_coupled_fit

    lines = []
    for closure, est in FLUID_COUPLED_QUOTED:
        try:
            fit = fluid_coupled_fit(closure, est, rows=rows, beta=beta)
        except ValueError:  # fewer than two concentrations with this closure's value
            continue
        (v00, _), (_, v11) = fit.cov
        lines.append(f"* {closure} ({est}): C_I = {fit.c0:.2e} + {fit.c1:.2e} φβ, s.e. {math.sqrt(v00):.1e} / "
                     f"{math.sqrt(v11):.1e}, chi2 {fit.chi2:.2f} ({fit.points - 2} dof), "
                     f"φβ {fit.phi_beta_range[0]:.2f}-{fit.phi_beta_range[1]:.2f}")
    return lines


def cpu_of(path: Path) -> float:
    """CPU time of the sweep run whose run file is ``path`` [s]."""
    from pyfold.sweep import store as sweep_store

    return sweep_store.cpu_seconds(path.parent)


def analyse(done: dict, seeds: tuple[int, ...], out: Path, write_data: bool, resolution_file: Path,
            beta: float = BETA, reuse: dict | None = None, stokes: dict | None = None, dt: float | None = None,
            beta_e_rule: str = "cox") -> None:
    """The tables, report and figure of the finished runs ``done``; ``reuse``: per n L³, the
    (closure-free, trajectory) error of the sweep's solve interval against STOKES' and where it was
    measured (reuse_evidence), added to the settings error in quadrature; ``stokes``: the Stokes
    numerics the sweep runs (STOKES by default); ``dt``: its time step (None: α/(γ̇L)); ``beta_e_rule``:
    the rule of the β_e both models record (equivalent_aspect_ratio), against which the shape error is taken."""
    from pyfold.correlations import fluid_coupled_table
    from pyfold.ensemble import paired_difference
    from pyfold.report import build_report, write_report

    # the β = 5 resolution study measured the β = 5 semi-dilute scene; the calibrated β = 10 series has its own
    # (resolution_file RESOLUTION_BETA10), the geometric β = 10 series none
    if beta == BETA:
        resolution = resolution_errors(resolution_file, RESOLUTION_GRID_XI_KEYS
                                       if resolution_file == RESOLUTION_CALIBRATED_APART else
                                       ("closure_free_cox", "ibof_trajectory_cox"))
    elif resolution_file in RESOLUTION_BETA10_FILES:
        resolution = resolution_errors(resolution_file, ("closure_free", "ibof_trajectory"))
    else:
        resolution = (math.nan, math.nan)
    measured_beta10 = beta != BETA and all(math.isfinite(v) for v in resolution)
    calibrated5 = beta == BETA and resolution_file == RESOLUTION_CALIBRATED_APART
    if beta == BETA and not all(math.isfinite(v) for v in resolution):
        print(f"--resolution: {resolution_file} is missing: the total errors are NaN (run ci_resolution.py)",
              file=sys.stderr)
    if write_data and not all(math.isfinite(v) for v in resolution):
        raise SystemExit(f"--write-data: the shipped table needs the resolution error; run "
                         f"studies/interaction_coefficient/ci_resolution.py first ({resolution_file} is missing)")
    points = sorted({n for (n, _m), _s in done})
    reps, rows, cost, pairs = {}, [], {}, []
    out.mkdir(parents=True, exist_ok=True)
    complete = [n for n in points if sum(all(((n, m), s) in done for m in MODELS) for s in seeds) >= 2]
    if not complete:
        raise SystemExit(f"no concentration has two finished pairs of runs in the sweep yet (seeds {seeds}); "
                         "`pyfold sweep status` shows where the runs are")
    first_stokes = next(p for ((n, m), _s), p in done.items() if m == "stokes" and n in complete)
    beta_e_grid, xi_grid = grid_xi(out, first_stokes, beta)
    for n_l3 in points:
        have = [s for s in seeds if all(((n_l3, m), s) in done for m in MODELS)]
        if len(have) < 2:
            print(f"n L^3 {n_l3:g}: {len(have)} finished pair(s) of runs; left out")
            continue
        settings = settings_errors(n_l3, beta)
        if reuse and reuse.get(n_l3) is not None:
            settings = tuple(math.hypot(a, b) for a, b in zip(settings, reuse[n_l3][0]))
        grid_fits: dict[str, list[float]] = {}  # the Stokes runs' trajectory fits with the grid fibre's ξ
        for model in MODELS:
            paths = [done[(n_l3, model), s] for s in have]
            rep = build_report(paths, None, progress=lambda text: None)
            write_report(rep, out / f"nl3_{n_l3:g}" / model)
            reps[n_l3, model] = rep
            cost[n_l3, model] = float(np.mean([cpu_of(p) for p in paths]))
            shift = xi_sensitivity(rep, xi_grid, grid_fits) if model == "stokes" else {}
            rows += table_rows(n_l3, model, rep, settings, shift, resolution, beta,
                               resolution_unmeasured=beta != BETA and not measured_beta10)
            print(f"n L^3 {n_l3:g} {model}: analysed {len(paths)} runs", flush=True)
        f, j = reps[n_l3, "stokes"], reps[n_l3, "jeffery"]
        d = paired_difference([r.ci["exact"] for r in f.runs], [r.ci["exact"] for r in j.runs])
        line = (f"* n L³ {n_l3:g}: fluid-coupled − contacts-only, closure-free (steady) {d.mean:+.2e} ± "
                f"{d.stderr:.1e} (p = {d.p:.2g})")
        if "ibof" in f.ci_fit_runs and "ibof" in j.ci_fit_runs:
            d = paired_difference(f.ci_fit_runs["ibof"], j.ci_fit_runs["ibof"])
            line += f"; IBOF trajectory fit {d.mean:+.2e} ± {d.stderr:.1e} (p = {d.p:.2g})"
        if "ibof" in grid_fits and "ibof" in j.ci_fit_runs:
            # the twins turn exactly as Jeffery's fibre of Cox's ξ, the Stokes runs' fibres as the grid's:
            # each fitted with the ξ of the fibres it simulates, the difference is the interactions' alone
            d = paired_difference(grid_fits["ibof"], j.ci_fit_runs["ibof"])
            line += (f"; IBOF trajectory fit of the Stokes runs with the grid fibre's ξ (β_e {beta_e_grid:.2f}, "
                     f"C_I {np.nanmean(grid_fits['ibof']):.2e}) {d.mean:+.2e} ± {d.stderr:.1e} (p = {d.p:.2g})")
        pairs.append(line + f"; paired over {d.n} seeds")
    out.mkdir(parents=True, exist_ok=True)
    grid = "x".join(map(str, grid_of(first_stokes)))
    first = scene_of(5.0, "jeffery", 1, 1.0, beta, dt=dt)
    attrs = {"title": f"Fluid-coupled (Stokes + contacts) and contacts-only Folgar-Tucker C_I of beta = {beta:g} fibres",
             "command": (".venv/bin/python studies/interaction_coefficient/ci_fluid_series.py "
                         + (("--calibrated --shells apart --write-data" if calibrated5 else "")
                            if beta == BETA else f"--beta {beta:g}"
                            + (" --calibrated --write-data" if measured_beta10 else ""))).rstrip(),
             "scene": f"pyfold.scene.sheared_fibres, simple shear, isotropic start, alpha = 0.1 d, dt = "
                      f"{first.dt:g}, strain {max(r['strain'] for r in rows):g}, cell {first.side:g} L, "
                      f"Stokes grid {grid}, both models recording {beta_e_rule.capitalize()}'s beta_e",
             "stokes_numerics": f"{stokes or STOKES}, ab2 (setting {SETTING} of studies/speed_accuracy/ci_stokes_settings.py"
                                + (", with the solve interval of studies/speed_accuracy/solve_reuse.py --beta 10)"
                                   if reuse else ")"),
             "estimators": "steady: rate regression over each run's stationary window (MSER-5); trajectory: "
                           "Folgar-Tucker fit to a2(t) over two Jeffery periods (pyfold.report)",
             "errors": "stat: ensemble over seeds; settings: measured change of the Stokes setting"
                       + (" and of its solve interval, in quadrature (measured at "
                          + "; ".join(f"n L^3 {n:g}: {src}" for n, (_v, src) in sorted(reuse.items())) + ")"
                          if reuse else "") + "; shape: change "
                       f"with the grid fibre's beta_e = {beta_e_grid:.3f} instead of the recorded "
                       f"({beta_e_rule.capitalize()}'s); resolution: bias of the "
                       + ("3-voxel C_I against the Richardson limit of 54^3 and 70^3, all calibrated with the "
                          "shells apart, grid fibre's xi (ci_resolution.py --calibrated --shells apart)" if calibrated5 else
                          "3-voxel C_I against the Richardson limit (ci_resolution.py)" if beta == BETA else
                          "96^3 C_I against the Richardson limit of 96^3 and 120^3, all calibrated "
                          "(ci_resolution_beta10.py)" if measured_beta10 else
                          "not measured at this beta")
                       + " (NaN = not measured and left out of the total: resolution_in_total = 0); total: in quadrature",
             "seeds": " ".join(map(str, seeds))}
    write_table(rows, out / "ci_fluid_series", attrs)
    if write_data:  # this aspect ratio's rows replace its old ones; the others' stay
        merged, head = merged_table(rows, attrs, beta, DATA.with_suffix(".csv"))
        write_table(merged, DATA, head)
    # beside the shipped table's other aspect ratios: how the answer moves with β at equal φβ
    shipped = [r for r in (fluid_coupled_table(DATA.with_suffix(".csv")) if DATA.with_suffix(".csv").is_file()
                           else []) if r["beta"] != beta]
    figure(rows + shipped, out / "ci_fluid_series.png")
    text = markdown(rows, reps, cost, beta_e_grid, beta, grid) + "\n## Fluid-coupled against contacts only\n\n" + "\n".join(pairs)
    fits = fit_lines(rows, beta)
    if fits:
        text += "\n\n## The fit in φβ (pyfold.correlations.fluid_coupled_fit)\n\n" + "\n".join(fits)
    (out / "ci_fluid_series.md").write_text(text + "\n", encoding="utf-8")
    print(text)


def main() -> None:
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--np", type=int, default=None, help="MPI ranks per run (default: the sweep file's, 1)")
    ap.add_argument("--seeds", type=int, nargs="+", help="override the sweep's seeds")
    ap.add_argument("--write-data", action="store_true", help="also write the shipped table data/ci_fluid_coupled.*")
    ap.add_argument("--beta", type=float, default=BETA, choices=sorted(SERIES),
                    help="fibre aspect ratio: the sweep of that beta (SERIES)")
    ap.add_argument("--calibrated", action="store_true",
                    help="the series with the Stokes runs' fibres voxelised at the radius calibrated to the "
                         "converged cylinder, both models recording Zhang's beta_e (SERIES[beta]_calibrated.toml, "
                         "beta = 10; at beta = 5 with --shells apart only)")
    ap.add_argument("--shells", choices=SHELL_RULES, default=registry.default("numerics.stokes.fibre_shells"),
                    help="with --calibrated: the series whose Stokes runs keep the added shells of near fibres "
                         "the security zone apart (numerics.stokes.fibre_shells; SERIES[beta]_calibrated_apart.toml)")
    ap.add_argument("--out", type=Path, default=None,
                    help="output folder (default out/interaction_coefficient/fluid_series, "
                         "fluid_series_beta<beta> for another beta, + _calibrated[_apart])")
    ap.add_argument("--resolution", type=Path,
                    default=Path("out/interaction_coefficient/resolution/ci_resolution.json"),
                    help="the resolution study's summary (ci_resolution.py): the resolution error of the C_I "
                         "(beta = 5 only: at another beta it is not measured and not read)")
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    apart = args.shells == "apart"
    if args.write_data and args.beta != BETA and not args.calibrated:
        ap.error(f"--write-data: the shipped table takes the series whose resolution error is measured: "
                 f"--beta {args.beta:g} --calibrated; the geometric --beta {args.beta:g} series is analysed into --out")
    if args.write_data and args.beta == BETA and not (args.calibrated and apart):
        ap.error(f"--write-data: the shipped beta = {BETA:g} rows are the series on the grid numerics.preset = "
                 "\"study\" takes; add --calibrated --shells apart (the geometric series is analysed into --out)")
    if apart and not args.calibrated:
        ap.error("--shells apart: the shells are those of the calibrated radius; add --calibrated")
    if apart and args.write_data and args.beta != BETA:
        ap.error("--write-data: the shipped beta = 10 rows are the series with the overlapping shells (its three "
                 "concentrations); the --shells apart series is analysed into --out")
    if args.calibrated and not apart and args.beta == BETA:
        ap.error(f"--calibrated at beta = {BETA:g}: the calibrated series runs with the shells apart (the grid "
                 "numerics.preset = \"study\" takes); add --shells apart")
    suffix = ("_calibrated" if args.calibrated else "") + ("_apart" if apart else "")
    name = SERIES[args.beta] + suffix
    if not (SWEEPS / f"{name}.toml").is_file():
        ap.error(f"--calibrated: no such series at beta = {args.beta:g} (studies/sweeps/{name}.toml)")
    if args.out is None:
        args.out = Path("out/interaction_coefficient") / (("fluid_series" if args.beta == BETA
                                                           else f"fluid_series_beta{args.beta:g}") + suffix)
    spec = sweep_study.load_form(SWEEPS, name, False, seeds=tuple(args.seeds) if args.seeds else None)
    start = time.perf_counter()
    sweep_dir = args.sweep_dir or args.out / "sweep"
    done = sweep_study.run_sweep(spec, sweep_dir, args.executor, args.np, analyse_only=args.analyse_only)
    keyed = {}
    for values, seed in done:
        point = dict(zip(spec.axes, values))  # point values in the order of spec.axes
        keyed[(float(point["n_l3"]), point["model"]), seed] = done[values, seed]
    resolution = ((RESOLUTION_BETA10_APART if apart else RESOLUTION_BETA10) if args.beta != BETA and args.calibrated
                  else RESOLUTION_CALIBRATED_APART if args.calibrated else args.resolution)
    if resolution in RESOLUTION_BETA10_FILES and resolution.is_file():
        import json

        measured = json.loads(resolution.read_text(encoding="utf-8"))["closure_free"]["coarse_cells_per_diameter"]
        cells = int(spec.arguments.get("cells_per_diameter", STOKES["cells_per_diameter"]))
        if measured != cells:  # the check measured another grid's bias: not this series' resolution error
            print(f"{resolution} holds the bias of {measured} voxels per diameter, the sweep runs {cells}: its "
                  "resolution error is left out as unmeasured", file=sys.stderr)
            resolution = resolution.with_name("not_measured_for_this_grid.json")
    reuse = {}
    for point in spec.points:  # a point may set its own solve interval
        point = dict(point)
        if point["model"] == "stokes":
            n = float(point["n_l3"])
            reuse[n] = reuse_evidence({**spec.arguments, **point}, n_l3=n, point_evidence=REUSE_EVIDENCE_CONCENTRATED,
                                      grid_evidence=resolution if resolution in RESOLUTION_BETA10_FILES else None)
    reuse = {n: v for n, v in reuse.items() if v is not None} or None
    stokes = {**STOKES, **{k: spec.arguments[k] for k in ("solve_every", "reuse", "cells_per_diameter",
                                                          "fibre_radius_scale", "fibre_shells")
                           if k in spec.arguments}}
    analyse(keyed, tuple(spec.seeds), args.out, args.write_data, resolution, args.beta, reuse, stokes,
            spec.arguments.get("dt"), spec.arguments.get("equivalent_aspect_ratio")
            or registry.EQUIVALENT_ASPECT_RATIO_DEFAULT)
    print(f"written: {args.out} ({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
