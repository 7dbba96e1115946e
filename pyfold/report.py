"""The report on a run, or an ensemble of runs (seeds) of one scene: ``pyfold report`` and ``pyfold main``.

    run files ─► checks (each run, and one scene apart from the seed)
              ─► per run: stationary part (MSER-5 onset, drift test), C_I by rate
                 regression with the run's own a4 and with each closure's a4,
                 closure errors a4:D against the run's a4, C_I by trajectory fit
                 per closure over the first TRAJECTORY_PERIODS Jeffery periods
              ─► over the runs: ensemble means ± standard errors, closure ranking
                 with paired tests, Folgar-Tucker integrated once per closure at
                 its fitted C_I, the published correlations at the scene's phi beta
              ─► figures (PNG), results.nc, summary.txt / summary.md

Why these estimators (docs/physics.md#the-fitted-c_i-depends-on-the-closure): a
moulding code integrates Folgar-Tucker with *its* closure, so the interaction
coefficient it needs is the one fitted with that closure: the trajectory fit
:func:`pyfold.fast_fit.fit_ci_rk4` (the fit of ``pyfold analyse`` too) over the
transient, with its standard error. Beside it, the rate regression
:func:`pyfold.ci_estimators.ci_rate_regression` with the closure's ``a4`` evaluated on
the simulated ``a2`` (no ODE, linear in C_I, cheap over a long run), over the
stationary part of each run. The same regression with the run's own ``a4`` needs no
closure: it measures what the contacts alone do, projected on Folgar-Tucker's
isotropic diffusion.

The measurements on each run and across the runs are :mod:`pyfold.run_analysis`; the
trajectory fits and Folgar-Tucker at the fitted C_I (:data:`PREDICTION_POINTS` times over
the runs) are :mod:`pyfold.fast_fit`; this module composes them (:func:`build_report`)
and writes the outputs. Every program is compiled once per closure and kept by JAX's
persistent cache (:mod:`pyfold._jax`).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from pyfold.errors import InputError, PyfoldError
from pyfold.files import atomic_output, describe_os_error, regular_file
from pyfold.run_analysis import (RANK_LEVEL, RunAnalysis, analyse_run, attach_closure_errors,
                                 check_same_scene, fibre_concentration, ft_departure, measure_redistribution,
                                 rank_one_run, ranking_equivalence)
from pyfold.seed_checks import EQUIVALENCE_MARGIN

#: Output times of the Folgar-Tucker prediction (fixed: one compiled shape).
PREDICTION_POINTS = 256
#: Span of the trajectory fit of C_I, in Jeffery periods ``T = 2 pi (beta_e + 1/beta_e) / gamma_dot``
#: from the start of the runs: the transient in which the contacts damp the ensemble's
#: Jeffery oscillation (MSER onsets at 2-4 periods in the default scene), the strains of a
#: mould filling (10-100). Over longer spans the fit weighs the slowly drifting late state,
#: which Folgar-Tucker's steady states often cannot reach
#: (studies/interaction_coefficient/ci_concentration.py).
TRAJECTORY_PERIODS = 2.0
#: Files a report writes (``--out`` rules refer to these).
REPORT_FILES = ("results.nc", "summary.txt", "summary.md", "a2_dns_vs_fitted_ft.png", "closures_vs_dns.png",
                "ci_vs_correlations.png")


# --------------------------------------------------------------------------- the ensemble


@dataclasses.dataclass
class Report:
    """Everything a report shows (see :func:`build_report`)."""

    runs: list[RunAnalysis]
    closures: tuple[str, ...]
    judged: tuple[str, ...]
    scene: dict
    scene_title: str
    dim: int
    L: np.ndarray
    xi: float
    beta: float
    n_l3: float
    phi_beta: float
    correlations: dict[str, float]
    ci: dict[str, object]  # closure -> pyfold.ensemble.EnsembleMean
    errors: dict[str, object]  # judged closure -> EnsembleMean of the time-mean a4:D error
    ranking: list  # pyfold.ensemble.RankedEntry
    ranking_method: str
    prediction_t: np.ndarray
    prediction: dict[str, np.ndarray]  # closure -> a2 (PREDICTION_POINTS, d, d)
    prediction_ci: dict[str, float]  # the C_I each prediction used (>= 0)
    ci_fit: dict[str, object] = dataclasses.field(default_factory=dict)  # closure -> EnsembleMean (trajectory fit)
    ci_fit_runs: dict[str, list[float]] = dataclasses.field(default_factory=dict)  # closure -> per-run fitted C_I
    ci_fit_stderr: dict[str, list[float]] = dataclasses.field(default_factory=dict)  # closure -> its standard errors
    fit_rms: dict[str, list[float]] = dataclasses.field(default_factory=dict)  # closure -> per-run a2 RMS at the fit
    fit_window: tuple[float, float] = (math.nan, math.nan)  # times of the trajectory fit [s]
    allow_failed: bool = False
    notes: list[str] = dataclasses.field(default_factory=list)
    provenance: object = None  # pyfold.provenance.Provenance of the runs
    fit_flags: dict[str, object] = dataclasses.field(default_factory=dict)  # closure -> pyfold.seed_checks.SeedFlags
    equivalence: dict[str, object] = dataclasses.field(default_factory=dict)  # closure -> Equivalence with the next
    departure: dict[str, tuple[float, float, float]] = dataclasses.field(default_factory=dict)
    # closure -> (largest |FT - simulation| inside the fit window, largest after it, strain where) of a2
    redistribution: dict[str, object] = dataclasses.field(default_factory=dict)  # see measure_redistribution
    warnings: list[str] = dataclasses.field(default_factory=list)  # --force overrides, shown in every output

    @property
    def fit_periods(self) -> float:
        """Jeffery periods spanned by the trajectory fit (from the particles' actual xi)."""
        from pyfold.provenance import jeffery_period_strain

        return (self.fit_window[1] - self.fit_window[0]) * self.gamma_dot / jeffery_period_strain(self.xi)

    @property
    def n(self) -> int:
        return len(self.runs)

    @property
    def error_kind(self) -> str:
        if self.n == 1:
            return ("within-run statistical error (one run: blocking standard error of the time average "
                    "over its stationary part; no seed-to-seed scatter included)")
        return (f"ensemble of {self.n} seeds: the larger of the standard error across seeds (s/sqrt(n)) and the "
                "pooled within-run standard errors")

    @property
    def gamma_dot(self) -> float:
        D = 0.5 * (self.L + self.L.T)
        return math.sqrt(2.0 * float(np.sum(D * D))) or 1.0


def build_report(paths: Sequence[str | Path], closures: Sequence[str] | None, allow_failed: bool = False,
                 progress=None, force: bool = False) -> Report:
    """Check the runs (each by :func:`pyfold.run_checks.open_checked_run`, and that they are
    one scene) and measure everything the report shows.

    Raises
    ------
    InputError
        A run that cannot be analysed (named), runs of different scenes (the file and
        the differing key), closure names not defined in the runs' dimension; unless
        ``force``, runs whose particles have no orientation or shorter than the
        estimators need (:func:`pyfold.provenance.applicability_problems`).

    ``closures`` None: :func:`pyfold.run_checks.default_closures` of the runs' dimension.
    """
    from pyfold import run_checks
    from pyfold.correlations import correlations_at
    from pyfold.ensemble import EnsembleMean, ensemble_mean, rank_paired
    from pyfold.fast_fit import fit_ci_rk4, fit_flags, predict_ft
    from pyfold.seed_checks import FLAG_OK, FLAG_OUTLIER

    say = progress or (lambda text: None)
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("RUN.h5: give at least one run file")
    for p in paths:
        regular_file(p, "RUN.h5")  # a folder, FIFO or device: refused before HDF5 opens it
    from pyfold.provenance import (applicability_problems, enforce, jeffery_period_strain, provenance_of,
                                   shear_rate_of)

    if closures is not None:
        closures = run_checks.check_closures(closures)
    datasets = [run_checks.open_checked_run(p, allow_failed=allow_failed, command="pyfold report") for p in paths]
    seeds = check_same_scene(paths)
    dim = int(datasets[0].sizes["i"])
    closures = run_checks.check_closures(run_checks.default_closures(dim) if closures is None else closures, dim=dim)
    judged = tuple(c for c in closures if c != "exact")
    L = run_checks.velocity_gradient_of(paths[0])[:dim, :dim]
    xi = run_checks.shape_factor_of(datasets[0])
    problems = []
    for p, ds in zip(paths, datasets):
        problems += applicability_problems(p, np.asarray(ds["time"].values), L, xi)
    warnings = enforce(problems, force, "pyfold report")
    runs = []
    for p, ds, seed in zip(paths, datasets, seeds):
        say(f"{p.name} (seed {seed}): steady state, C_I per closure")
        runs.append(analyse_run(p, ds, seed, closures, L, xi))
    say("closure errors a4:D against the runs' own a4")
    attach_closure_errors(runs, judged, L)
    beta, n_l3, pb = fibre_concentration(datasets[0], paths[0], dim)
    corr = correlations_at(pb) if math.isfinite(pb) else {}
    ci = {c: ensemble_mean([r.ci[c] for r in runs], [r.ci_stderr[c] for r in runs]) for c in closures}
    errors = {c: ensemble_mean([r.error_mean[c] for r in runs], [r.error_stderr[c] for r in runs]) for c in judged}
    if not judged:
        ranking, method = [], "no closure judged"
    elif len(runs) == 1:
        ranking = rank_one_run(runs[0], judged)
        method = ("one run: neighbours compared by the blocking standard error of the time mean of their paired "
                  "error difference, Holm-adjusted")
    else:
        ranking = rank_paired({c: [r.error_mean[c] for r in runs] for c in judged}, level=RANK_LEVEL)
        method = (f"paired t-tests over the {len(runs)} seeds between neighbours in the ranking, Holm-adjusted "
                  "(pyfold.ensemble.rank_paired)")
    equivalence = ranking_equivalence(runs, ranking)
    # prediction from the ensemble-mean initial state over the span of the runs
    a2_0 = np.mean([r.a2[0] for r in runs], axis=0)
    a2_0 = 0.5 * (a2_0 + a2_0.T)
    t0 = float(min(r.t[0] for r in runs))
    t1 = float(max(r.t[-1] for r in runs))
    prediction, prediction_ci, notes = {}, {}, []
    pred_t = np.linspace(t0, t1, PREDICTION_POINTS)
    gamma_dot = shear_rate_of(L)
    period = jeffery_period_strain(xi) / gamma_dot
    fit_end = min(t1, t0 + TRAJECTORY_PERIODS * period) if math.isfinite(period) else t1
    ci_fit, ci_fit_runs, ci_fit_stderr, fit_rms, flags, departure = {}, {}, {}, {}, {}, {}
    for c in judged:
        say(f"trajectory fit of C_I with {c} over strain {t0 * gamma_dot:.3g}-{fit_end * gamma_dot:.3g}")
        fits = [fit_ci_rk4(c, r.t, r.a2, L, xi, t_end=min(fit_end, float(r.t[-1]))) for r in runs]
        ci_fit_runs[c] = [f.ci for f in fits]
        ci_fit_stderr[c] = [f.stderr for f in fits]
        fit_rms[c] = [f.residual_rms for f in fits]
        flags[c] = fit_flags(fits)
        # a fit on its bound is not a measurement, a failed one has no value: the mean is
        # over the others (none left: NaN)
        kept = [k for k, f in enumerate(flags[c].flags) if f in (FLAG_OK, FLAG_OUTLIER)]
        ci_fit[c] = (ensemble_mean([ci_fit_runs[c][k] for k in kept], [ci_fit_stderr[c][k] for k in kept]) if kept
                     else EnsembleMean(math.nan, math.nan, math.nan, 0))
        finite = [v for v in ci_fit_runs[c] if math.isfinite(v)]
        used = ci_fit[c].mean if kept else (float(np.mean(finite)) if finite else 0.0)
        say(f"Folgar-Tucker with {c} at the fitted C_I = {used:.3g}")
        prediction[c] = predict_ft(c, used, xi, a2_0, L, pred_t)
        prediction_ci[c] = used
        departure[c] = ft_departure(runs, pred_t, prediction[c], fit_end, gamma_dot)
    for ds in datasets:
        ds.close()
    scene = json.loads(datasets[0].attrs.get("scene", "{}"))
    provenance = provenance_of(paths[0], np.array([t0, t1]), L, xi)
    return Report(runs=runs, closures=tuple(closures), judged=judged, scene=scene,
                  scene_title=str(scene.get("title", "")), dim=dim, L=np.asarray(L), xi=xi, beta=beta, n_l3=n_l3,
                  phi_beta=pb, correlations=corr, ci=ci, errors=errors, ranking=ranking, ranking_method=method,
                  prediction_t=pred_t, prediction=prediction, prediction_ci=prediction_ci,
                  allow_failed=allow_failed, notes=notes, ci_fit=ci_fit, ci_fit_runs=ci_fit_runs,
                  ci_fit_stderr=ci_fit_stderr, fit_rms=fit_rms,
                  fit_window=(t0, fit_end), provenance=provenance, fit_flags=flags, equivalence=equivalence,
                  departure=departure, redistribution=measure_redistribution(runs, fit_end), warnings=warnings)


# --------------------------------------------------------------------------- outputs


#: Name of the C_I a moulding code should use in results.nc (attribute ``recommended_ci``).
RECOMMENDED_CI = "ci_recommended"


def _run_references(rep: Report, out: Path | None) -> list[str]:
    """The run files as results.nc names them: relative to ``out`` when they lie in it (the
    main job moves its folder, with its runs, into place after writing), else absolute."""
    refs = []
    for r in rep.runs:
        path = Path(r.path).resolve()
        if out is not None:
            try:
                refs.append(str(path.relative_to(Path(out).resolve())))
                continue
            except ValueError:
                pass
        refs.append(str(path))
    return refs


def results_dataset(rep: Report, out: Path | None = None) -> xr.Dataset:
    """The report's numbers as one Dataset (written as results.nc into ``out``).

    Every variable and coordinate has ``long_name`` and ``units``
    (:func:`pyfold.run_checks.check_described`); the C_I to use is ``ci_recommended`` (the
    trajectory fit, also named by the attribute ``recommended_ci``); ``ci_rate_regression``
    is the closure-free diagnostic and its closure counterparts."""
    from pyfold.run_checks import check_described
    from pyfold.seed_checks import EQUIVALENCE_MARGIN, FLAG_MEANINGS

    seeds = [r.seed for r in rep.runs]
    closures = list(rep.closures)
    judged = list(rep.judged)
    nt = max(len(r.t) for r in rep.runs)
    d = rep.dim
    labels = ["x", "y", "z"][:d]
    a2 = np.full((rep.n, nt, d, d), np.nan)
    for k, r in enumerate(rep.runs):
        a2[k, : len(r.t)] = r.a2
    t = max((r.t for r in rep.runs), key=len)

    def per_seed(attr, names):
        return np.array([[getattr(r, attr)[c] for c in names] for r in rep.runs], dtype=float).reshape(rep.n, len(names))

    def one(long_name, units="1", **more):
        return {"long_name": long_name, "units": units, **more}

    ens = {c: rep.ci[c] for c in closures}
    rr = "Folgar-Tucker C_I by rate regression over the stationary window ('exact': the runs' own a4, closure-free)"
    out_ds = xr.Dataset(
        {
            "ci_rate_regression": ("closure", [ens[c].mean for c in closures],
                                   one(rr + ", mean over the runs", recommended="no: a diagnostic; use "
                                       + RECOMMENDED_CI)),
            "ci_rate_regression_error": ("closure", [ens[c].error for c in closures],
                                         one("standard error quoted for ci_rate_regression",
                                             description=rep.error_kind)),
            "ci_rate_regression_stderr_across": ("closure", [ens[c].stderr_across for c in closures],
                                                 one("standard error across seeds of ci_rate_regression, s/sqrt(n) "
                                                     "(NaN for one run)")),
            "ci_rate_regression_stderr_pooled": ("closure", [ens[c].stderr_pooled for c in closures],
                                                 one("pooled within-run standard error of ci_rate_regression, "
                                                     "sqrt(sum se^2)/n")),
            "ci_rate_regression_seed": (("seed", "closure"), per_seed("ci", closures), one(rr + ", per run")),
            "ci_rate_regression_seed_stderr": (("seed", "closure"), per_seed("ci_stderr", closures),
                                               one("within-run standard error of ci_rate_regression_seed (blocking)")),
            "onset_time": ("seed", [r.onset_time for r in rep.runs],
                           one("start of the stationary part (MSER-5, not before one Jeffery period; NaN: the run "
                               "ends inside the first period)", "s")),
            "stationary": ("seed", np.array([r.stationary for r in rep.runs], dtype=np.int8),
                           one("stationary part found and not drifting (1) or not (0)")),
            "steady_message": ("seed", [r.steady_message for r in rep.runs],
                               one("verdict of the steady-state detection (pyfold.steady_state)", "")),
            "window_start": ("seed", [r.window[0] for r in rep.runs], one("first time used by the estimators", "s")),
            "window_end": ("seed", [r.window[1] for r in rep.runs], one("last time used by the estimators", "s")),
            "a2_drift": (("seed", "i"), [[v for v, _ in r.drift.values()] for r in rep.runs],
                         one("slope of the diagonal of a2 over the last half of the stationary part "
                             "(pyfold.steady_state drift test)", "1/s")),
            "a2_drift_stderr": (("seed", "i"), [[se for _, se in r.drift.values()] for r in rep.runs],
                                one("standard error of a2_drift", "1/s")),
            "a2": (("seed", "time", "i", "j"), a2, one("orientation tensor a2 of the direct simulation")),
            "a2_ft": (("closure_predicted", "time_ft", "i", "j"),
                      np.stack([rep.prediction[c] for c in rep.prediction]) if rep.prediction
                      else np.zeros((0, PREDICTION_POINTS, d, d)),
                      one("a2 of Folgar-Tucker with the closure at its recommended C_I (ci_recommended)")),
            "ci_ft": ("closure_predicted", [rep.prediction_ci[c] for c in rep.prediction], one("C_I used by a2_ft")),
        },
        coords={"seed": ("seed", seeds, one("random seed of the run", "")),
                "closure": ("closure", closures, one("closure of Folgar-Tucker ('exact': the runs' own a4)", "")),
                "time": ("time", t, one("time of the simulation's records", "s")),
                "time_ft": ("time_ft", rep.prediction_t, one("time of the Folgar-Tucker prediction", "s")),
                "closure_predicted": ("closure_predicted", list(rep.prediction),
                                      one("closure of the Folgar-Tucker prediction a2_ft", "")),
                "i": ("i", labels, one("first index of a2 (x flow, y gradient, z vorticity)", "")),
                "j": ("j", labels, one("second index of a2", ""))},
    )
    if judged:
        out_ds["a4D_error"] = ("judged_closure", [rep.errors[c].mean for c in judged],
                               one("time mean of ||(closure(a2) - a4):D|| / ||a4:D|| over the stationary window, "
                                   "mean over the runs"))
        out_ds["a4D_error_error"] = ("judged_closure", [rep.errors[c].error for c in judged],
                                     one("standard error quoted for a4D_error", description=rep.error_kind))
        out_ds["a4D_error_stderr_across"] = ("judged_closure", [rep.errors[c].stderr_across for c in judged],
                                             one("standard error across seeds of a4D_error (NaN for one run)"))
        out_ds["a4D_error_seed"] = (("seed", "judged_closure"), per_seed("error_mean", judged),
                                    one("a4D_error per run"))
        rank = {e.name: e for e in rep.ranking}
        out_ds["closure_rank"] = ("judged_closure", np.array([rank[c].rank for c in judged], dtype=np.int32),
                                  one("rank of the closure by a4D_error, 1 = smallest"))
        out_ds["p_next"] = ("judged_closure", [rank[c].p_next for c in judged],
                            one("Holm-adjusted p of the test against the next in the ranking",
                                method=rep.ranking_method))
        eq = [rep.equivalence.get(c) for c in judged]
        nan = math.nan
        out_ds["a4D_difference_next"] = ("judged_closure", [e.difference if e else nan for e in eq],
                                         one("effect size: a4D_error of the next closure in the ranking minus this "
                                             "one's (paired mean)"))
        out_ds["a4D_difference_next_low"] = ("judged_closure", [e.low if e else nan for e in eq],
                                             one("lower end of the 90 % confidence interval of a4D_difference_next"))
        out_ds["a4D_difference_next_high"] = ("judged_closure", [e.high if e else nan for e in eq],
                                              one("upper end of the 90 % confidence interval of a4D_difference_next"))
        out_ds["equivalent_to_next"] = ("judged_closure",
                                        np.array([{"equivalent": 1, "different": 0}.get(e.verdict, -1) if e else -1
                                                  for e in eq], dtype=np.int8),
                                        one("two one-sided tests: 1 equivalent to the next closure within the margin, "
                                            "0 different beyond it, -1 inconclusive or no next",
                                            margin=EQUIVALENCE_MARGIN))
        out_ds = out_ds.assign_coords(judged_closure=("judged_closure", judged,
                                                      one("closure judged against the runs' own a4", "")))
    if rep.ci_fit:
        fitted = [c for c in judged if c in rep.ci_fit]
        f0, f1 = rep.fit_window
        tf = ("C_I of Folgar-Tucker with the closure by trajectory fit to a2(t) (pyfold.fast_fit.fit_ci_rk4) "
              f"over strain {f0 * rep.gamma_dot:.4g}-{f1 * rep.gamma_dot:.4g}")
        out_ds[RECOMMENDED_CI] = ("judged_closure", [rep.ci_fit[c].mean if c in rep.ci_fit else np.nan for c in judged],
                                  one(tf + ", mean over the seeds not on a bound (the C_I to use with that closure)",
                                      recommended="yes", fit_window_start=f0, fit_window_end=f1,
                                      fit_window_periods=rep.fit_periods))
        out_ds[RECOMMENDED_CI + "_error"] = ("judged_closure",
                                             [rep.ci_fit[c].error if c in rep.ci_fit else np.nan for c in judged],
                                             one("standard error of ci_recommended: the larger of the one "
                                                 "across the seeds used and their pooled fit standard errors"))
        out_ds[RECOMMENDED_CI + "_n_seeds"] = ("judged_closure",
                                               np.array([rep.ci_fit[c].n if c in rep.ci_fit else 0 for c in judged],
                                                        dtype=np.int32),
                                               one("seeds averaged in ci_recommended (fits on a bound or failed "
                                                   "excluded)"))
        out_ds["ci_trajectory_fit_seed"] = (("seed", "judged_closure"),
                                            np.array([[rep.ci_fit_runs[c][k] if c in fitted else np.nan
                                                       for c in judged] for k in range(rep.n)]),
                                            one(tf + ", per run"))
        out_ds["ci_trajectory_fit_seed_stderr"] = (("seed", "judged_closure"),
                                                   np.array([[rep.ci_fit_stderr[c][k] if c in fitted else np.nan
                                                              for c in judged] for k in range(rep.n)]),
                                                   one("standard error of ci_trajectory_fit_seed (least squares: "
                                                       "s^2 / (J.J), pyfold.fast_fit)"))
        out_ds["ci_trajectory_fit_seed_flag"] = (("seed", "judged_closure"),
                                                 np.array([[rep.fit_flags[c].flags[k] if c in fitted else -1
                                                            for c in judged] for k in range(rep.n)], dtype=np.int8),
                                                 one("verdict on ci_trajectory_fit_seed: " + FLAG_MEANINGS))
        out_ds["ci_trajectory_fit_rms_seed"] = (("seed", "judged_closure"),
                                                np.array([[rep.fit_rms[c][k] if c in fitted else np.nan
                                                           for c in judged] for k in range(rep.n)]),
                                                one("RMS a2 error of the trajectory fit per run"))
    for name, value in rep.correlations.items():
        out_ds.attrs[f"ci_correlation {name}"] = value
    if rep.correlations:
        out_ds.attrs["ci_pyfold_fluid_coupled_fit"] = fluid_coupled_words(rep)
    out_ds.attrs.update(format="pyfold.report", format_version="2.0",
                        runs=json.dumps(_run_references(rep, out)), n_runs=rep.n, error_kind=rep.error_kind,
                        ranking_method=rep.ranking_method, xi=rep.xi, beta=rep.beta, n_L3=rep.n_l3,
                        phi_beta=rep.phi_beta, scene=json.dumps(rep.scene), recommended_ci=RECOMMENDED_CI,
                        equivalence_margin=EQUIVALENCE_MARGIN,
                        estimator=f"{RECOMMENDED_CI}: trajectory fit over the first {rep.fit_periods:.3g} Jeffery "
                        "periods (pyfold.fast_fit.fit_ci_rk4), the value a moulding code running that closure "
                        "should use; ci_rate_regression: pyfold.ci_estimators.ci_rate_regression over the stationary "
                        "window, 'exact' = the runs' own a4 (closure-free)",
                        warnings=json.dumps(rep.warnings))
    if rep.provenance is not None:
        out_ds.attrs.update(rep.provenance.attrs())
    check_described(out_ds)
    return out_ds


def _fmt(x: float, spec: str = ".2e") -> str:
    return "n/a" if not math.isfinite(x) else format(x, spec)


def redistribution_words(rep: Report) -> str:
    """What the simulated state did between the fit window and the stationary windows, as
    measured (:func:`measure_redistribution`): broadened or narrowed, and which diagonal
    components of a2 gained (flow x, gradient y, vorticity z)."""
    m = rep.redistribution
    if not m:
        return ""
    early, late = m["early"], m["late"]
    d = early.shape[-1]
    axes = ("flow", "gradient", "vorticity")[:d]
    change = np.diag(late) - np.diag(early)
    gained = [axes[i] for i in range(d) if change[i] > 0]
    lost = [axes[i] for i in range(d) if change[i] < 0]
    widen = "broadens" if m["anisotropy_late"] < m["anisotropy_early"] else "narrows"
    diag = ", ".join(f"a{i + 1}{i + 1} {early[i, i]:.2f} -> {late[i, i]:.2f}" for i in range(d))
    g = rep.gamma_dot
    return (f"from the fit window (strain up to {m['early_end'] * g:.3g}) to the stationary windows the state {widen} "
            f"(|a2 - I/{d}| {m['anisotropy_early']:.2f} -> {m['anisotropy_late']:.2f}; {diag}): orientation moves "
            f"from the {'/'.join(lost) or '-'} towards the {'/'.join(gained) or '-'} direction")


def interpretation(rep: Report) -> list[str]:
    """Which C_I a moulding code should use, and what the closure-free one means (from the numbers)."""
    from pyfold.seed_checks import FLAG_LOWER_BOUND

    lines = ["Which C_I to use: a moulding code should take the trajectory-fitted C_I of the closure it runs (C_I "
             "is not a material constant: each closure's a4:D error is absorbed into its C_I, docs/physics.md); "
             f"results.nc: {RECOMMENDED_CI}."]
    if rep.provenance is not None and rep.provenance.hydrodynamics == "jeffery":
        lines.append("These C_I come from Jeffery kinematics + contacts without hydrodynamic interactions: expect "
                     "them below the published correlations, which are fitted to real suspensions "
                     "(docs/physics.md#what-contacts-alone-do).")
    at_zero = [c for c, f in rep.fit_flags.items() if all(x == FLAG_LOWER_BOUND for x in f.flags)]
    if at_zero:
        lines.append(f"The trajectory fit ends at C_I = 0 for every seed with {', '.join(at_zero)}: Folgar-Tucker "
                     "with that closure follows the simulation best without any diffusion.")
    if "exact" in rep.ci:
        e = rep.ci["exact"]
        coupled = rep.provenance is not None and rep.provenance.hydrodynamics == "stokes"
        agent = "the hydrodynamic interactions and contacts" if coupled else "the contacts"
        significant = math.isfinite(e.error) and abs(e.mean) > 2.0 * e.error
        moved = redistribution_words(rep)
        if not significant:
            sign = "not distinguishable from 0"
        elif e.mean < 0:
            sign = (f"negative: {agent} do not act as isotropic diffusion; they redistribute orientation "
                    "anisotropically" + (f" ({moved})" if moved else "") + ", and that redistribution projected on "
                    "isotropic diffusion has a negative coefficient")
        else:
            sign = f"positive: projected on isotropic diffusion {agent} spread orientations" + (
                f" ({moved})" if moved else "")
        lines.append(f"The closure-free C_I (rate regression with the runs' own a4) = {e.mean:+.2e} ± "
                     f"{_fmt(e.error, '.1e')} is what {agent if coupled else 'the contacts alone'} do, projected on Folgar-Tucker's isotropic "
                     "diffusion; " + sign + ". The difference from "
                     "the fitted values is the closure's error plus the memory of the initial orbits that "
                     "Folgar-Tucker's diffusion stands in for (docs/physics.md#what-contacts-alone-do).")
    return lines


def flagged_fit_lines(rep: Report) -> list[str]:
    """Per-seed trajectory fits on a bound (excluded from the mean) or outside the other
    seeds' prediction interval (kept), one line per closure with any; and rate regressions
    whose seeds disagree beyond their within-run errors (:func:`pyfold.seed_checks.consistency`)."""
    from pyfold.seed_checks import consistency

    seeds = [r.seed for r in rep.runs]
    lines = []
    for c, flags in rep.fit_flags.items():
        notes = flags.describe(seeds, (0.0, math.inf))
        if notes:
            values = ", ".join(f"{v:.3g}" for v in flags.values)
            lines.append(f"{c}: per-seed fits {values}; " + "; ".join(notes))
    for c in rep.closures:
        test = consistency([r.ci[c] for r in rep.runs], [r.ci_stderr[c] for r in rep.runs])
        if test.disagree:
            values = ", ".join(f"{r.ci[c]:+.2e} ± {r.ci_stderr[c]:.1e}" for r in rep.runs)
            lines.append(f"{c} (rate regression): the seeds disagree beyond their within-run errors (chi2 = "
                         f"{test.chi2:.3g} for {test.dof} degrees of freedom, p = {test.p:.2g}): {values}; the error "
                         "quoted is the larger, across-seed one")
    return lines


def ranking_verdict(rep: Report, e) -> str:
    """The 'vs next' text of one ranked closure: p-value, effect size and equivalence."""
    if not math.isfinite(e.p_next):
        return "" if e.rank == len(rep.ranking) else "no test (one value per closure)"
    q = rep.equivalence.get(e.name)
    test = f"{'differs' if e.better_than_next else 'not distinguishable'} (p = {e.p_next:.2g})"
    return f"{test}; {q.text()}" if q is not None else test


def fluid_coupled_words(rep: Report) -> str:
    """pyfold's own fluid-coupled C_I at the scene's beta and phi beta (pyfold.correlations.fluid_coupled_ci),
    or why it is not given."""
    from pyfold.correlations import fluid_coupled_ci

    return fluid_coupled_ci(rep.beta, rep.phi_beta)[1]


def summary_lines(rep: Report) -> list[str]:
    """The summary as plain-text lines (also the body of summary.md)."""
    g = rep.gamma_dot
    lines = [f"scene: {rep.scene_title}" if rep.scene_title else "scene: (untitled)",
             f"runs: {rep.n} ({', '.join(f'{r.path.name} seed {r.seed}' for r in rep.runs)})"]
    if math.isfinite(rep.phi_beta):
        lines.append(f"fibres: beta = {rep.beta:.3g}, n L^3 = {rep.n_l3:.3g}, phi beta = {rep.phi_beta:.3g}, "
                     f"xi = {rep.xi:.4f}")
    t_end = max(float(r.t[-1]) for r in rep.runs)
    if rep.provenance is not None:
        lines.append(rep.provenance.line())
    lines.append(f"error bars: {rep.error_kind}")
    lines += rep.warnings
    if rep.allow_failed:
        lines.append("WARNING: --allow-failed: runs that did not finish are used up to their last good state")
    lines += ["", f"Steady state (MSER-5 onset and drift test, pyfold.steady_state; run to strain {t_end * g:.4g}):"]
    n_ok = sum(r.stationary for r in rep.runs)
    for r in rep.runs:
        verdict = "stationary" if r.stationary else "NOT judged stationary"
        drift = ", ".join(f"{k} {v / g:+.1e} ± {se / g:.0e}" for k, (v, se) in r.drift.items())
        msg = r.steady_message if len(r.steady_message) <= 160 else r.steady_message[:157] + "..."
        lines.append(f"  seed {r.seed}: onset strain {_fmt(r.onset_time * g, '.4g')}, {verdict}; window strain "
                     f"{r.window[0] * g:.4g}-{r.window[1] * g:.4g}; drift per unit strain over its last half: {drift}")
        if not r.stationary:
            lines.append(f"    ({msg})")
    lines.append(f"  reached in {n_ok} of {rep.n} runs" + (
        "" if n_ok == rep.n else "; the numbers below are averages over the window after the onset of runs still "
        "drifting slowly: read them as effective values over that strain range"))
    f0, f1 = rep.fit_window
    lines += ["", f"Folgar-Tucker C_I per closure. fitted (recommended): trajectory fit to each run's a2(t) over "
              f"strain {f0 * g:.3g}-{f1 * g:.3g} ({rep.fit_periods:.2g} Jeffery periods of the particles' xi; "
              "pyfold.fast_fit.fit_ci_rk4), mean over the seeds whose fit is not on a bound or failed; "
              "rate regr.: regression of da2/dt on the diffusion term over the stationary window "
              "(pyfold.ci_estimators.ci_rate_regression):",
              f"  {'closure':<10} {'fitted C_I':>11} {'± error':>9} {'seeds':>5} {'a2 RMS':>8}   {'rate regr.':>11} "
              f"{'± error':>9}"]
    for c in rep.closures:
        e = rep.ci[c]
        label = "exact*" if c == "exact" else c
        if c in rep.ci_fit:
            f = rep.ci_fit[c]
            rms = float(np.mean(rep.fit_rms[c]))
            fitted = f"{_fmt(f.mean, '11.3e')} {_fmt(f.error, '9.1e')} {f'{f.n}/{rep.n}':>5} {rms:8.1e}"
        else:
            fitted = f"{'-':>11} {'':>9} {'':>5} {'':>8}"
        lines.append(f"  {label:<10} {fitted}   {e.mean:+11.3e} {_fmt(e.error, '9.1e')}")
    flagged = flagged_fit_lines(rep)
    if flagged:
        lines.append("  flagged per-seed values (a fit on its bound is a bound, not a measurement):")
        lines += [f"    {x}" for x in flagged]
    if "exact" in rep.closures:
        lines.append("  * exact: the runs' own a4 (closure-free; no trajectory fit: that a4 exists only along the "
                     "simulated path)")
    if rep.correlations:
        lines.append(f"  published correlations at phi beta = {rep.phi_beta:.3g} (pyfold.correlations): "
                     + ", ".join(f"{k} {v:.2e}" for k, v in rep.correlations.items()))
    else:
        lines.append("  published correlations: not applicable (they are for one family of 3-D fibres)")
    if rep.correlations:
        lines.append(f"  {fluid_coupled_words(rep)}")
    lines += [f"  {line}" for line in interpretation(rep)]
    if rep.judged:
        lines += ["", "Closures against the runs' own a4 (time mean of ||(closure(a2) - a4):D|| / ||a4:D|| over the "
                  "window; pyfold.closure_check):",
                  f"  {'rank':<5}{'closure':<10} {'a4:D error':>11} {'± error':>9}   vs next"]
        for e in rep.ranking:
            err = rep.errors[e.name].error  # as in results.nc: the larger of across-seed and pooled
            lines.append(f"  {e.rank:<5}{e.name:<10} {e.mean:11.3e} {_fmt(err, '9.1e')}   {ranking_verdict(rep, e)}")
        lines.append(f"  significance: {rep.ranking_method}, level {RANK_LEVEL}")
        lines.append(f"  {EQUIVALENCE_WORDS}")
    departed = departure_lines(rep)
    if departed:
        lines += ["", "Folgar-Tucker at the fitted C_I against the simulation (largest |a2_FT - a2| of a component, "
                  "mean of the seeds):"] + [f"  {x}" for x in departed]
    return lines


#: How the ranking's equivalence verdict reads (margin and why; pyfold.seed_checks).
EQUIVALENCE_WORDS = (f"equivalence: two one-sided tests at level 0.05 (90 % interval of the paired difference) against "
                     f"a margin of +-{EQUIVALENCE_MARGIN:g} in the a4:D error, i.e. {100 * EQUIVALENCE_MARGIN:g} % of "
                     "||a4:D||: the closure enters Folgar-Tucker only through 2 xi a4:D, so errors closer than that "
                     f"change the flow term by less than {100 * EQUIVALENCE_MARGIN:g} %, below the a2 misfit of any "
                     "fitted C_I (pyfold.seed_checks.EQUIVALENCE_MARGIN)")


def provenance_words(rep: Report) -> str:
    """The physics model and strain range, short enough for a figure's title."""
    if rep.provenance is None:
        return ""
    p = rep.provenance
    words = f"{p.model}; {p.resolution}; strain {p.strain[0]:.3g}-{p.strain[1]:.3g}; {rep.n} seed(s)"
    return words + ("; " + "; ".join(rep.warnings) if rep.warnings else "")


def departure_note(rep: Report) -> list[str]:
    """One line for the a2 figure: the closures whose Folgar-Tucker departs from the data past the fit window."""
    g = rep.gamma_dot
    gone = [(c, after, where) for c, (inside, after, where) in rep.departure.items()
            if math.isfinite(after) and after > inside]
    if not gone:
        return []
    return [f"past the fit window (strain > {rep.fit_window[1] * g:.3g}) Folgar-Tucker departs from the data: "
            + ", ".join(f"{c} by up to {after:.2g} (strain {where:.3g})" for c, after, where in gone)]


def departure_lines(rep: Report) -> list[str]:
    """Where Folgar-Tucker departs from the simulation past the fit window, per closure."""
    g = rep.gamma_dot
    lines = []
    for c, (inside, after, where) in rep.departure.items():
        if math.isfinite(after):
            lines.append(f"{c}: up to {inside:.2g} inside the fit window (strain <= {rep.fit_window[1] * g:.3g}); "
                         f"past it up to {after:.2g} (at strain {where:.3g})"
                         + (": Folgar-Tucker departs from the data beyond the fitted range" if after > inside
                            else ""))
    return lines


def summary_markdown(rep: Report, extra: Sequence[str] = ()) -> str:
    """summary.md: the summary as Markdown (tables for C_I and the ranking)."""
    g = rep.gamma_dot
    md = [f"# pyfold report: {rep.scene_title or 'untitled scene'}", "",
          f"{rep.n} run(s): " + ", ".join(f"`{r.path.name}` (seed {r.seed})" for r in rep.runs) + ".  ",
          f"Error bars: {rep.error_kind}.", ""]
    if math.isfinite(rep.phi_beta):
        md += [f"Fibres: β = {rep.beta:.3g}, nL³ = {rep.n_l3:.3g}, φβ = {rep.phi_beta:.3g}, ξ = {rep.xi:.4f}.", ""]
    if rep.provenance is not None:
        md += [f"Physics: {rep.provenance.line()}.", ""]
    md += [f"**{w}**" for w in rep.warnings] + ([""] if rep.warnings else [])
    md += ["## Steady state", "", "| seed | onset strain | stationary | window (strain) | message |", "|---|---|---|---|---|"]
    for r in rep.runs:
        md.append(f"| {r.seed} | {_fmt(r.onset_time * g, '.4g')} | {'yes' if r.stationary else 'no'} | "
                  f"{r.window[0] * g:.4g}–{r.window[1] * g:.4g} | {r.steady_message.replace('|', '/')} |")
    f0, f1 = rep.fit_window
    md += ["", "## C_I per closure", "",
           f"Fitted (recommended, `{RECOMMENDED_CI}` in results.nc): trajectory fit to each run's a2(t) over strain "
           f"{f0 * g:.3g}–{f1 * g:.3g} ({rep.fit_periods:.2g} Jeffery periods), mean over the seeds not on a bound; "
           "rate regression: over the stationary window.", "",
           "| closure | fitted C_I | ± error | seeds | a2 RMS | rate regression C_I | ± error |",
           "|---|---|---|---|---|---|---|"]
    for c in rep.closures:
        e = rep.ci[c]
        label = "exact (the runs' own a4, closure-free)" if c == "exact" else c
        if c in rep.ci_fit:
            f = rep.ci_fit[c]
            fitted = f"{_fmt(f.mean, '.3e')} | {_fmt(f.error)} | {f.n}/{rep.n} | {float(np.mean(rep.fit_rms[c])):.1e}"
        else:
            fitted = "– | | | "
        md.append(f"| {label} | {fitted} | {e.mean:+.3e} | {_fmt(e.error)} |")
    for k, v in rep.correlations.items():
        md.append(f"| correlation {k} at φβ = {rep.phi_beta:.3g} | {v:.3e} | | | | | |")
    if rep.correlations:
        md += ["", fluid_coupled_words(rep)]
    flagged = flagged_fit_lines(rep)
    if flagged:
        md += ["", "Flagged per-seed values (a fit on its bound is a bound, not a measurement):", ""]
        md += [f"* {x}" for x in flagged]
    md += [""] + [f"* {line}" for line in interpretation(rep)]
    if rep.judged:
        md += ["", "## Closure ranking (a4:D error against the runs' own a4)", "",
               "| rank | closure | a4:D error | ± error | vs next: test, effect size, equivalence |",
               "|---|---|---|---|---|"]
        for e in rep.ranking:
            md.append(f"| {e.rank} | {e.name} | {e.mean:.3e} | {_fmt(rep.errors[e.name].error)} | "
                      f"{ranking_verdict(rep, e)} |")
        md += ["", f"Significance: {rep.ranking_method}, level {RANK_LEVEL}.", "", EQUIVALENCE_WORDS[0].upper()
               + EQUIVALENCE_WORDS[1:] + "."]
    departed = departure_lines(rep)
    if departed:
        md += ["", "## Folgar–Tucker past the fit window", ""] + [f"* {x}" for x in departed]
    if extra:
        md += ["", "## Also", "", "```", *extra, "```"]
    md += ["", "Figures: `a2_dns_vs_fitted_ft.png`, `closures_vs_dns.png`, `ci_vs_correlations.png`; "
           "numbers: `results.nc`."]
    return "\n".join(md) + "\n"


#: Per-record solver diagnostics of a Stokes run that the main job's summary reports; each is a
#: variable fold_run writes (``fortran/io/fold_output.f90``; a test checks the names
#: against a real run, so a renamed record cannot drop out of the summary unseen).
STOKES_SUMMARY_RECORDS: tuple[str, ...] = ("stokes_iterations", "stokes_residual", "rigidity_max")


def stokes_summary(run_path: Path) -> str:
    """Summary lines of a Stokes run: effective viscosity and solver records."""
    from pyfold import run_checks
    from pyfold.provenance import provenance_of
    from pyfold.run_results import open_run

    ds = open_run(run_path)
    lines = [f"Stokes run {run_path.name}: status {ds.attrs.get('status', '?')}"]
    if "time" in ds.dims and ds.sizes["time"] > 1 and "particle_xi" in ds:
        xi = float(np.max(np.abs(np.asarray(ds["particle_xi"].values))))
        lines.append("  " + provenance_of(run_path, np.asarray(ds["time"].values), run_checks.velocity_gradient_of(run_path),
                                          xi).line())
    if "effective_viscosity" in ds:
        eta = np.asarray(ds["effective_viscosity"].values)
        eta_f = float(ds.attrs.get("viscosity", 1.0))
        lines.append(f"  effective viscosity / fluid viscosity: mean {np.nanmean(eta) / eta_f:.4f} "
                     f"(min {np.nanmin(eta) / eta_f:.4f}, max {np.nanmax(eta) / eta_f:.4f})")
    missing = [name for name in STOKES_SUMMARY_RECORDS if name not in ds]
    if missing:
        raise PyfoldError(f"{run_path}: not a complete Stokes run file, records {missing} are missing")
    for name in STOKES_SUMMARY_RECORDS:
        values = np.asarray(ds[name].values)
        lines.append(f"  {name}: median {np.nanmedian(values):.3g}, max {np.nanmax(values):.3g}")
    return "\n".join(lines)


def check_report_folder(out: Path, force: bool = False) -> Path:
    """Refuse to replace report files in ``out`` without ``force``; make sure it can be
    written (:func:`pyfold.run_checks.check_output_folder`), before any analysis."""
    from pyfold import run_checks

    out = Path(out)
    if out.is_dir() and not force:
        present = [name for name in REPORT_FILES if (out / name).exists()]
        if present:
            raise InputError(f"--out: {out} already holds a report ({', '.join(present)}); give another --out, or "
                             "--force to replace those files")
    return run_checks.check_output_folder(out)


def write_report(rep: Report, out: Path, extra_summary: Sequence[str] = ()) -> list[Path]:
    """Write figures, results.nc, summary.txt and summary.md into ``out``.

    The files are written into a hidden folder inside ``out``, each whole
    (:func:`pyfold.files.atomic_output`: flushed to disk), and moved into place when
    all are complete, so an interrupted report leaves the earlier files (if any) or
    the new ones, never a mixture of half-written files. A failed write (a full disk)
    removes the hidden folder and raises :class:`PyfoldError` naming the file and the
    cause (``No space left on device (ENOSPC)``).
    """
    from pyfold import plotting

    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=".report-", dir=out))
    except OSError as exc:
        raise PyfoldError(f"cannot write the report in {out}: {describe_os_error(exc)}") from None
    try:
        g = rep.gamma_dot
        dns = {r.seed: (r.t * g, r.a2) for r in rep.runs}
        where = provenance_words(rep)
        plotting.plot_report_a2(dns, rep.prediction_t * g, rep.prediction, rep.prediction_ci,
                                [r.onset_time * g for r in rep.runs if math.isfinite(r.onset_time)],
                                work / "a2_dns_vs_fitted_ft.png",
                                fit_window=(rep.fit_window[0] * g, rep.fit_window[1] * g), provenance=where,
                                notes=departure_note(rep))
        errors_t = {c: [(r.error_t * g, r.error_contracted[c]) for r in rep.runs] for c in rep.judged}
        # the C_I shown per closure: its trajectory fit; for the runs' own a4 the rate regression
        shown = {c: ((rep.ci_fit[c].mean, rep.ci_fit[c].error) if c in rep.ci_fit else (rep.ci[c].mean, rep.ci[c].error))
                 for c in rep.closures}
        plotting.plot_closure_report(errors_t, shown,
                                     rep.correlations, rep.ranking, work / "closures_vs_dns.png", provenance=where)
        plotting.plot_ci_vs_correlations(rep.phi_beta, shown,
                                         work / "ci_vs_correlations.png", provenance=where)
        with atomic_output(work / "results.nc") as tmp:
            results_dataset(rep, out).to_netcdf(tmp, engine="h5netcdf")
        text = "\n".join(summary_lines(rep) + ([""] + list(extra_summary) if extra_summary else [])) + "\n"
        with atomic_output(work / "summary.txt") as tmp:
            tmp.write_text(text, encoding="utf-8")
        with atomic_output(work / "summary.md") as tmp:
            tmp.write_text(summary_markdown(rep, extra_summary), encoding="utf-8")
        written = []
        for name in REPORT_FILES:
            try:
                os.replace(work / name, out / name)
            except OSError as exc:
                raise PyfoldError(f"cannot write {out / name}: {describe_os_error(exc)}") from None
            written.append(out / name)
    except PyfoldError as exc:  # name the report file, not its temporary in the hidden folder
        raise PyfoldError(str(exc).replace(f"{work}{os.sep}", f"{out}{os.sep}")) from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return written


def report(paths: Sequence[str | Path], out: Path, closures: Sequence[str], allow_failed: bool = False,
           force: bool = False, extra_summary: Sequence[str] = (), progress=None) -> tuple[Report, list[Path]]:
    """Check, measure and write: what ``pyfold report`` and ``pyfold main`` do."""
    check_report_folder(out, force=force)
    rep = build_report(paths, closures, allow_failed=allow_failed, progress=progress, force=force)
    return rep, write_report(rep, out, extra_summary)
