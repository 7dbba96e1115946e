"""Speed-accuracy trade of pyfold's settings for three answers: Jeffery period, eta_eff, C_I.

Question
    For each answer a user wants, which settings give the smallest error for a given
    cost? Rows (setting, error against a stated reference, CPU s, wall s, load average)
    over the model level (``jeffery`` kinematics vs ``stokes``), voxels per diameter,
    kappa, CG tolerance, time step and time scheme; the only Stokes backend is ``fft``
    (fortran/stokes: a hypre backend is not built), so there is no backend axis. A row is
    Pareto-optimal when no other row of the same answer (and scene) is at most as costly
    and at most as wrong, one of them strictly.

    (1) Jeffery period of a beta = 3 spheroid in a periodic cell 3 lengths wide, simple
        shear gamma_dot = 1 (the case of benchmarks/bench_speed_accuracy.py, whose
        functions are reused). Reference: Jeffery's T_J = 2 pi (beta + 1/beta) (Jeffery
        1922); the Stokes rows' error includes the box-size effect of the 3 L cell and the
        16-orientation quadrature bias (bench docstring), which no row removes. Stokes rows:
        T by quadrature over fixed orientations (grid, kappa, tolerance sweeps) or by a
        marched half orbit (Euler/AB2, dt sweep); ``jeffery`` rows: the same orbit stepped
        with Jeffery's exact omega (pyfold.native.geometry.jeffery_advance).
    (2) eta_eff of a random sphere suspension, phi = 0.1, 16 spheres in the unit cell,
        seed 1 (placement and solves of studies/rheology/sphere_viscosity.py), one solve
        per setting. Reference: the Richardson extrapolation of the 32^3/48^3/64^3 values
        at kappa = 1e3, tol = 1e-6 (sphere_viscosity.richardson, the rheology study's own
        method); the measured grid values are checked against
        out/rheology/sphere_viscosity.nc when that file exists. The ``jeffery`` row: no
        hydrodynamic interactions, i.e. Einstein's 1 + 2.5 phi.
    (3) C_I of beta = 5 fibres in simple shear, 4 paired seeds, strain 30, by two estimators:
        the closure-free rate regression (pyfold.ci_estimators.ci_rate_regression with the run's
        own a4) and the trajectory fit of Folgar–Tucker + IBOF to a2(t)
        (pyfold.fast_fit.fit_ci_rk4), one answer each: semi-dilute (98 fibres, n L^3 = 4.98;
        the runs of studies/speed_accuracy/ci_stokes_settings.py, one per Stokes setting,
        and of its ranks sweep) and dilute (18 fibres, n L^3 = 0.91; runs of
        studies/speed_accuracy/ci_dilute.py). Reference: the Stokes model (42^3, 3.11 voxels
        per diameter, kappa 1e3, tol 1e-4, AB2, dt = 0.02) on the same seeds; a row's error
        is |paired mean difference| to it, ± the paired s.e.; the reference row's "error" is
        its ensemble s.e. Stokes rows (semi-dilute): each setting of ci_stokes_settings.py
        (tolerance, transform precision, solve reuse, time step, kappa) and its RANKED rows
        (2 MPI ranks; their CPU time counts both ranks); contacts-only rows at dt = 0.04,
        0.02, 0.01, 0.005 (dt = alpha/(gamma_dot L) = 0.02 with alpha = 0.1 d, the rule of
        the studies). The runs are sweeps (pyfold.sweep): re-used when finished, created
        when absent (the Stokes runs then dominate the cost, see Cost).
        Resolution rows (both estimators): the semi-dilute scene at 3 / 4 / 5 voxels per
        diameter, each against the finest, read from
        studies/interaction_coefficient/ci_resolution.py's table when it exists (strain 20,
        tolerance 1e-3, a solve every 4th step; 0.8 CPU-hour to make, so not re-run here).

    The evidence ``hydrodynamics = "auto"`` quotes (pyfold/scene/hydrodynamics_evidence.py)
    is recomputed from the C_I run files (``evidence_check``); any disagreement with the
    module's table is printed and stored, and the exit status is 1.

Command
    nice -n 10 .venv/bin/python studies/speed_accuracy/pareto.py [--large] [--out out/speed_accuracy]

Cost on 2 cores
    Small form with all C_I runs present (measured twice, nice 10): 186 and 206 CPU-s, as much
    wall time, at load averages of 0.7-1.3 (period about 110 CPU-s, eta_eff 10, the C_I analysis with its
    trajectory fits the rest); the 12 contacts-only dt runs add 28 CPU-s when absent;
    ``total_cpu_s`` in pareto.nc and the Cost line of pareto.md give each run's own.
    Re-creating absent C_I Stokes runs adds about 3.5 CPU-hours (ci_stokes_settings.py's
    sweeps, settings, soft penalties and 2 ranks) plus the dilute study's (ci_dilute.py:
    4 x 340 CPU-s measured). --large (not run): grids to 96^3 and ntheta 32 for the period,
    128^3 for eta_eff, dt 0.025 for the marched orbit.

Outputs (out/speed_accuracy/)
    pareto.nc (one row dimension; answer, setting, error, CPU/wall, load, pareto flag),
    pareto.md (the table a user picks settings from), pareto.png (error against CPU time,
    log-log, one panel per answer, the Pareto front drawn; docs/figures/speed_accuracy_pareto.png
    is a copy).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import resource
import subprocess
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import xarray as xr

ROOT = Path(__file__).resolve().parents[2]
for sub in ("benchmarks", "studies/rheology", "studies/interaction_coefficient", "studies/speed_accuracy"):
    sys.path.insert(0, str(ROOT / sub))

import bench_speed_accuracy as bsa  # noqa: E402
import ci_dilute  # noqa: E402
import ci_hydrodynamics as ch  # noqa: E402
import sphere_viscosity as sv  # noqa: E402

from pyfold.cli import main as cli_main  # noqa: E402
from pyfold.command_line import command_line  # noqa: E402
from pyfold.ensemble import ensemble_mean, paired_difference  # noqa: E402
from pyfold.fast_fit import fit_ci_rk4  # noqa: E402
from pyfold.native.stokes import StokesSettings, solve_particles  # noqa: E402
from pyfold.run_input import creator  # noqa: E402
from pyfold.scene import hydrodynamics_evidence as he  # noqa: E402
from pyfold.scene.sheared_fibres import sheared_fibres  # noqa: E402

# Parameters
SMALL = dict(period_grids=[18, 27, 36, 48, 64], ntheta=16, period_kappas=[1e1, 1e2, 1e3, 1e4],
             period_tols=[1e-2, 1e-3, 1e-4, 1e-6], march_dts=[0.4, 0.2, 0.1, 0.05], march_grid=27,
             jeffery_dts=[0.4, 0.2, 0.1, 0.05],
             eta_grids=[24, 32, 48, 64, 96], eta_kappas=[1e1, 1e2, 1e3, 1e4], eta_tols=[1e-2, 1e-3, 1e-4, 1e-6],
             ci_dts=[0.04, 0.02, 0.01, 0.005])
LARGE = dict(SMALL, period_grids=[18, 27, 36, 48, 64, 96], ntheta=32, march_dts=[0.4, 0.2, 0.1, 0.05, 0.025],
             eta_grids=[24, 32, 48, 64, 96, 128])
ETA_PHI, ETA_SPHERES, ETA_SEED = 0.1, 16, 1
ETA_REF_GRIDS = (32, 48, 64)  # the rheology study's grids: its Richardson triple
CI_BASE_DT = 0.02             # alpha/(gamma_dot L) of sheared_fibres at beta = 5
SEMI = ch.SMALL               # the semi-dilute study (98 fibres, n L^3 = 4.98)
DILUTE = ci_dilute.DILUTE     # 18 fibres, n L^3 = 0.91
#: the resolution study's table (studies/interaction_coefficient/ci_resolution.py)
RESOLUTION = ROOT / "out" / "interaction_coefficient" / "resolution" / "ci_resolution.nc"


@dataclasses.dataclass
class Row:
    answer: str          # a key of TITLES
    model: str           # "jeffery" or "stokes"
    backend: str         # "fft" or "-" (no Stokes solve)
    setting: str         # human-readable
    sweep: str           # the factor varied
    value: float
    error: float         # |value - reference| (relative for period and eta_eff, absolute for C_I)
    error_stderr: float  # statistical error of ``error`` (C_I: paired s.e.), nan otherwise
    reference: str       # how the reference was obtained
    source: str          # "measured" or "re-used: <path>"
    cpu_s: float
    wall_s: float
    load: float          # 1-min load average when the row was measured (nan: not recorded)
    vpd: float = math.nan
    kappa: float = math.nan
    tol: float = math.nan
    dt: float = math.nan
    scheme: str = ""
    pareto: bool = False         # on the front of all rows of the answer
    pareto_stokes: bool = False  # on the front of the answer's Stokes rows (when the scene needs Stokes)


def _cpu() -> float:
    """CPU time of this process and its finished children (fold_run) [s]."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def measured(fn):
    """(result, CPU s, wall s, 1-min load average before) of one call."""
    load = os.getloadavg()[0]
    c0, w0 = _cpu(), time.perf_counter()
    out = fn()
    return out, _cpu() - c0, time.perf_counter() - w0, load


# Problem (1): Jeffery period
def period_rows(p: dict) -> list[Row]:
    T_J = bsa.jeffery_period()
    ref = f"Jeffery T_J = 2π(β + 1/β) = {T_J:.4f} (analytic; includes the 3 L cell's box effect)"
    base = StokesSettings(kappa=1e3, tol=1e-6, derivative="fd", mixing="harmonic", subsamples=3, warm_start=False)
    rows = []

    def stokes_row(sweep, n, settings, fn, dt=math.nan, scheme="quadrature"):
        r, cpu, wall, load = measured(fn)
        vpd = n * bsa.VOXELS_PER_DIAMETER
        what = (f"stokes fft {n}^3 ({vpd:.2f} vox/d), κ {settings.kappa:g}, tol {settings.tol:g}, "
                + (f"{p['ntheta']}-orientation quadrature" if scheme == "quadrature" else f"{scheme} dt {dt:g}"))
        rows.append(Row("jeffery_period", "stokes", "fft", what, sweep, r["T"], abs(r["T"] / T_J - 1), math.nan, ref,
                        "measured", cpu, wall, load, vpd, settings.kappa, settings.tol, dt, scheme))
        print(f"  {what}: T = {r['T']:.4f}, {cpu:.1f} CPU-s", flush=True)

    n0 = p["march_grid"]
    for n in p["period_grids"]:
        stokes_row("grid", n, base, lambda: bsa.quadrature_period(n, base, p["ntheta"]))
    for k in p["period_kappas"]:
        if k != base.kappa:
            s = replace(base, kappa=k)
            stokes_row("kappa", n0, s, lambda: bsa.quadrature_period(n0, s, p["ntheta"]))
    for tol in p["period_tols"]:
        if tol != base.tol:
            s = replace(base, tol=tol)
            stokes_row("tol", n0, s, lambda: bsa.quadrature_period(n0, s, p["ntheta"]))
    T_est = next((r.value for r in rows if r.sweep == "grid" and abs(r.vpd - n0 * bsa.VOXELS_PER_DIAMETER) < 1e-9), T_J)
    warm = replace(base, warm_start=True)
    for scheme in ("euler", "ab2"):
        for dt in p["march_dts"]:
            stokes_row("dt", n0, warm, lambda: bsa.marched_period(n0, warm, dt, scheme, T_est), dt, scheme)
    bsa.jeffery_euler_period(p["jeffery_dts"][0])  # loads the extension and compiles xi(beta) once
    for dt in p["jeffery_dts"]:
        r, cpu, wall, load = measured(lambda: bsa.jeffery_euler_period(dt))
        rows.append(Row("jeffery_period", "jeffery", "-", f"jeffery kinematics, exact rotation per step, dt {dt:g}",
                        "dt", r["T"], abs(r["T"] / T_J - 1), math.nan, ref, "measured", cpu, wall, load, dt=dt,
                        scheme="euler"))
    return rows


# Problem (2): eta_eff
def eta_rows(p: dict, out: Path) -> tuple[list[Row], dict]:
    P, R, seed_used = sv.random_configuration(ETA_PHI, ETA_SPHERES, ETA_SEED)
    base = StokesSettings(kappa=sv.KAPPA, tol=sv.TOL)
    solves = {}

    def solve(n, s):
        sol, cpu, wall, load = measured(lambda: solve_particles(P, [1, 1, 1], (n, n, n), settings=s))
        solves[n, s.kappa, s.tol] = (float(sol.eta_eff), cpu, wall, load)
        print(f"  eta_eff {n}^3 κ {s.kappa:g} tol {s.tol:g}: {sol.eta_eff:.5f}, {cpu:.1f} CPU-s", flush=True)

    for n in sorted(set(p["eta_grids"]) | set(ETA_REF_GRIDS)):
        solve(n, base)
    for k in p["eta_kappas"]:
        if k != base.kappa:
            solve(32, replace(base, kappa=k))
    for tol in p["eta_tols"]:
        if tol != base.tol:
            solve(32, replace(base, tol=tol))
    h = [1.0 / n for n in ETA_REF_GRIDS]
    order, eta_ref = sv.richardson(h, [solves[n, base.kappa, base.tol][0] for n in ETA_REF_GRIDS])
    how = "Richardson extrapolation of 32^3/48^3/64^3"
    if not math.isfinite(eta_ref):  # not in the asymptotic range: the finest grid, stated as such
        eta_ref, how = solves[max(ETA_REF_GRIDS), base.kappa, base.tol][0], "finest grid 64^3 (no monotone triple)"
    ref = (f"{how} at κ {base.kappa:g}, tol {base.tol:g}: η_ref = {eta_ref:.4f} η_f"
           + (f" (observed order {order:.2f})" if math.isfinite(order) else ""))
    check = _rheology_cross_check(solves, base, out)
    rows = []
    for (n, k, tol), (eta, cpu, wall, load) in solves.items():
        sweep = "grid" if (k, tol) == (base.kappa, base.tol) else ("kappa" if k != base.kappa else "tol")
        vpd = 2 * R * n
        rows.append(Row("eta_eff", "stokes", "fft", f"stokes fft {n}^3 ({vpd:.1f} vox/d), κ {k:g}, tol {tol:g}",
                        sweep, eta, abs(eta / eta_ref - 1), math.nan, ref, "measured", cpu, wall, load, vpd, k, tol))
    einstein, cpu, wall, load = measured(lambda: float(sv.einstein(ETA_PHI)))
    rows.append(Row("eta_eff", "jeffery", "-", "no hydrodynamic interactions: Einstein 1 + 2.5 φ", "model", einstein,
                    abs(einstein / eta_ref - 1), math.nan, ref, "analytic", cpu, wall, load))
    return rows, dict(eta_ref=eta_ref, eta_order=order, eta_seed_used=seed_used, **check)


def _rheology_cross_check(solves: dict, base: StokesSettings, out: Path) -> dict:
    """The grid values measured here against out/rheology/sphere_viscosity.nc (same placement,
    phi, seed, kappa, tol), when that file exists; they are the same computation, so they agree
    to the CG tolerance (relative tol 1e-6 on the residual: ~1e-5 on eta at worst, allowed 1e-4)."""
    path = ROOT / "out" / "rheology" / "sphere_viscosity.nc"
    if not path.exists():
        return dict(rheology_cross_check="out/rheology/sphere_viscosity.nc absent: not compared")
    ds = xr.open_dataset(path, engine="h5netcdf")
    name = next((v for v in ("random_eta", "random_eta_eff") if v in ds), None)
    if name is None or ETA_PHI not in ds["random_phi"].values:
        return dict(rheology_cross_check=f"{path.name}: no per-seed eta at phi {ETA_PHI}: not compared")
    worst = 0.0
    for n in ETA_REF_GRIDS:
        if n in ds["grid"].values:
            stored = float(ds[name].sel(random_phi=ETA_PHI, seed=ETA_SEED, grid=n))
            worst = max(worst, abs(stored / solves[n, base.kappa, base.tol][0] - 1))
    verdict = "agree" if worst <= 1e-4 else "DISAGREE"
    return dict(rheology_cross_check=f"grid values vs out/rheology/sphere_viscosity.nc: max relative difference "
                                     f"{worst:.1e} ({verdict}, allowed 1e-4)")


# Problem (3): C_I
def _run_info(path: Path) -> dict:
    """Closure-free C_I of one run with its s.e., its a2(t) for the trajectory fit, and its cost."""
    r = ch.analyse_run(path)
    L = ch.run_checks.velocity_gradient_of(path)
    fit = fit_ci_rk4("ibof", r["t"], r["a2"], L, r["xi"])
    return dict(ci=r["regs"]["own_a4"].ci, stderr=r["regs"]["own_a4"].stderr, cpu=r["cpu_s"], wall=r["wall_s"],
                t=r["t"], a2=r["a2"], xi=r["xi"], L=L, load=math.nan, grid=r["grid"],
                ci_trajectory=fit.ci, ci_trajectory_stderr=fit.stderr)


def stokes_settings_runs(out: Path) -> dict:
    """(setting, seed) -> run info of the semi-dilute scene of ci_stokes_settings.py (its sweep run
    here when runs are missing; finished runs are re-used)."""
    from pyfold.sweep import study as sweep_study

    from ci_stokes_settings import ranked_runs

    spec = sweep_study.load_form(ROOT / "studies" / "sweeps", "ci_stokes_settings", False)
    done = sweep_study.run_sweep(spec, out / "ci_stokes_settings" / "sweep")
    runs = {(setting, seed): _run_info(path) for ((scene, setting), seed), path in done.items()
            if scene == "semi-dilute"}
    # the ranks lever: the same scenes on 2 MPI ranks per run (ci_stokes_settings.py's RANKED rows)
    ranked = sweep_study.load_form(ROOT / "studies" / "sweeps", "ci_stokes_settings_ranks", False)
    done = sweep_study.run_sweep(ranked, out / "ci_stokes_settings" / "sweep_ranks")
    runs.update({(row, seed): _run_info(path) for (scene, row, seed), path in
                 ranked_runs(done, ranked.resources.np).items() if scene == "semi-dilute"})
    return runs


def contacts_only_dt_runs(study: ch.Study, dts, out: Path) -> dict:
    """(dt, seed) -> run info of the contacts-only scene of ``study`` at each dt (the scene of
    ci_hydrodynamics.py's "jeffery" model with that step)."""
    runs = out / "ci_dt" / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    result = {}
    for dt in dts:
        for seed in study.seeds:
            scene = sheared_fibres(study.beta, study.n_l3, seed, study.t_end, alpha_over_d=ch.ALPHA_OVER_D, dt=dt)
            name = f"jeffery_dt{dt:g}_seed{seed}"  # "0.01" holds a dot: no Path.with_suffix
            toml, h5, cost = runs / f"{name}.toml", runs / f"{name}.h5", runs / f"{name}.cost.json"
            if not (h5.exists() and toml.exists() and toml.read_text() == scene.toml and cost.exists()):
                toml.write_text(scene.toml)
                load = os.getloadavg()[0]
                c0, w0 = _cpu(), time.perf_counter()
                status = cli_main(["run", str(toml), "-o", str(h5), "--force"])
                if status != 0:
                    raise SystemExit(f"{h5}: pyfold run exited with status {status}")
                cost.write_text(json.dumps({"cpu_s": _cpu() - c0, "wall_s": time.perf_counter() - w0, "load": load}))
            info = _run_info(h5)
            info.update({k: json.loads(cost.read_text())[k] for k in ("load",)},
                        cpu=json.loads(cost.read_text())["cpu_s"], wall=json.loads(cost.read_text())["wall_s"])
            result[dt, seed] = dict(info, source="measured")
    return result


def dilute_runs(out: Path) -> tuple[dict, dict]:
    """seed -> run info of the Stokes and of the contacts-only runs of ci_dilute.py (its sweep)."""
    from pyfold.sweep import study as sweep_study

    done = sweep_study.run_sweep(ci_dilute.sweep_spec(), out / "ci_dilute" / "sweep")
    by_model = {"stokes": {}, "jeffery": {}}
    for ((model,), seed), path in done.items():
        by_model[model][seed] = _run_info(path)
    return by_model["stokes"], by_model["jeffery"]


#: C_I estimators of the Pareto rows: run-info key -> (answer suffix, what it is)
CI_ESTIMATORS = {"ci": ("", "closure-free rate regression"),
                 "ci_trajectory": ("_trajectory", "Folgar–Tucker + IBOF fitted to a2(t)")}


def _lever(keys: dict) -> str:
    """The factor a ci_stokes_settings.py setting varies (the figure's marker)."""
    if "kappa" in keys:
        return "kappa"
    if "solve_every" in keys:
        return "reuse"
    if "fft_precision" in keys:
        return "precision"
    return "tol"


def ci_rows(p: dict, out: Path) -> tuple[list[Row], dict]:
    from ci_stokes_settings import RANKED, REFERENCE, REFERENCE_STOKES, SETTINGS

    rows, extra = [], {}
    settings = stokes_settings_runs(out)
    seeds = sorted(s for (name, s) in settings if name == REFERENCE)
    dil_stokes, dil_jeff = dilute_runs(out)
    for base, study in (("ci_semi_dilute", SEMI), ("ci_dilute", DILUTE)):
        stokes = {s: settings[REFERENCE, s] for s in seeds} if base == "ci_semi_dilute" else dil_stokes
        sd = sorted(stokes)
        if base == "ci_semi_dilute":
            jeff = contacts_only_dt_runs(study, p["ci_dts"], out)
            dts = p["ci_dts"]
        else:
            jeff = {(CI_BASE_DT, s): dict(dil_jeff[s], source="measured") for s in sd}
            dts = [CI_BASE_DT]
        estimators = CI_ESTIMATORS
        for key, (suffix, words_est) in estimators.items():
            answer = base + suffix
            st = np.array([stokes[s][key] for s in sd])
            stderr = [stokes[s]["stderr" if key == "ci" else f"{key}_stderr"] for s in sd]
            ens = ensemble_mean(st, stderr)
            numerics = f"3 cells/d requested (42^3), κ {study.kappa:g}, tol {study.tolerance:g}, AB2"
            ref = (f"{words_est}; stokes fft ({numerics}), dt {CI_BASE_DT:g}, seeds {sd} (C_I_ref = {ens.mean:.2e} ± "
                   f"{ens.error:.1e}); error = |paired mean difference| ± paired s.e.; the reference row: its "
                   "ensemble s.e.")
            rows.append(Row(answer, "stokes", "fft", f"stokes fft 42^3 (3.11 vox/d), κ {study.kappa:g}, tol "
                            f"{study.tolerance:g}, AB2 dt {CI_BASE_DT:g} [reference]", "model", ens.mean, ens.error,
                            math.nan, ref, "measured", float(np.mean([stokes[s]["cpu"] for s in sd])),
                            float(np.mean([stokes[s]["wall"] for s in sd])), math.nan, 3.11, study.kappa,
                            study.tolerance, CI_BASE_DT, "ab2"))
            if base == "ci_semi_dilute":
                levers = {name: (keys, dt, words, _lever(keys)) for name, (keys, dt, words) in SETTINGS.items()}
                levers.update({row: (SETTINGS[setting][0], SETTINGS[setting][1], words, "ranks")
                               for row, (setting, _, words) in RANKED.items()})
                for name, (keys, dt, words, lever) in levers.items():
                    if name == REFERENCE or not all((name, s) in settings for s in sd):
                        continue
                    v = np.array([settings[name, s][key] for s in sd])
                    d = paired_difference(v, st)
                    stokes_keys = {**REFERENCE_STOKES, **keys}
                    rows.append(Row(answer, "stokes", "fft", f"stokes fft, {words}", lever, float(v.mean()),
                                    abs(d.mean), d.stderr, ref, "measured",
                                    float(np.mean([settings[name, s]["cpu"] for s in sd])),
                                    float(np.mean([settings[name, s]["wall"] for s in sd])), math.nan, 3.11,
                                    float(stokes_keys["kappa"]), float(stokes_keys.get("tolerance", math.nan)),
                                    dt=dt or CI_BASE_DT, scheme="ab2"))
            for dt in dts:
                je = np.array([jeff[dt, s][key] for s in sd])
                d = paired_difference(je, st)
                rows.append(Row(answer, "jeffery", "-", f"jeffery kinematics + contacts, dt {dt:g}", "dt",
                                float(je.mean()), abs(d.mean), d.stderr, ref, "measured",
                                float(np.mean([jeff[dt, s]["cpu"] for s in sd])),
                                float(np.mean([jeff[dt, s]["wall"] for s in sd])),
                                float(np.nanmean([jeff[dt, s]["load"] for s in sd])) if any(
                                    math.isfinite(jeff[dt, s]["load"]) for s in sd) else math.nan,
                                dt=dt, scheme="euler"))
        check_dir = (out / "ci_stokes_settings") if base == "ci_semi_dilute" else (out / "ci_dilute")
        # the dilute study's analysis writes its own; made here when that analysis has not run
        if base == "ci_semi_dilute" or not (check_dir / "single_fibre_check.nc").exists():
            ch.single_fibre_check(study, stokes[sd[0]]["grid"], study.scene("stokes", sd[0]).side,
                                  check_dir / "single_fibre_check.nc")
        extra[base] = (stokes, {s: jeff[CI_BASE_DT, s] for s in sd}, check_dir)
    rows += resolution_rows(RESOLUTION)
    return rows, extra


def resolution_rows(path: Path) -> list[Row]:
    """The resolution lever: C_I of the semi-dilute scene at 3 / 4 / 5 voxels per diameter
    (studies/interaction_coefficient/ci_resolution.py's table ``path``; its own 4 paired seeds, strain 20,
    tolerance 1e-3, a solve every 4th step), each grid's error against the finest grid. Read from the
    study's output, not re-run (0.8 CPU-hour): none when it is absent (the report says so)."""
    if not path.exists():
        return []
    ds = xr.open_dataset(path, engine="h5netcdf")
    cpds = [int(c) for c in ds["cells_per_diameter"].values]
    finest = max(cpds)
    rows = []
    for est, suffix, words in (("closure_free", "", "closure-free rate regression"),
                               ("ibof_trajectory", "_trajectory", "Folgar–Tucker + IBOF fitted to a2(t)")):
        values = ds[f"ci_{est}_cox"]
        ref_v = values.sel(cells_per_diameter=finest).values
        ens = ensemble_mean(ref_v, ds[f"ci_{est}_cox_stderr"].sel(cells_per_diameter=finest).values)
        ref = (f"{words}; stokes fft at {finest} cells/d requested, κ 1000, tol 0.001, a solve every 4th step, "
               f"AB2 dt {CI_BASE_DT:g}, strain 20, seeds {[int(s) for s in ds['seed'].values]} (C_I_ref = {ens.mean:.2e} ± "
               f"{ens.error:.1e}); error = |paired mean difference| ± paired s.e.; the reference row: its ensemble s.e.")
        for c in cpds:
            v = values.sel(cells_per_diameter=c).values
            cpu = float(np.mean(ds["cpu_s"].sel(cells_per_diameter=c).values))
            vpd = 1.0 / float(ds["h_over_d"].sel(cells_per_diameter=c))
            if c == finest:
                err, err_se, tag = ens.error, math.nan, " [reference]"
            else:
                d = paired_difference(v, ref_v)
                err, err_se, tag = abs(d.mean), d.stderr, ""
            rows.append(Row("ci_resolution" + suffix, "stokes", "fft",
                            f"stokes fft, {c} cells/d requested ({vpd:.2f} vox/d){tag}", "grid", float(np.mean(v)),
                            err, err_se, ref, f"re-used: {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}",
                            cpu, math.nan, math.nan, vpd, 1e3, 1e-3, CI_BASE_DT, "ab2"))
    ds.close()
    return rows


# Solver: the evidence check and the Pareto front
def _agrees(stored: float, recomputed: float, digits: int = 3) -> bool:
    """The module stores 3 significant digits: agreement is within half a unit of the last one."""
    if not (math.isfinite(stored) and math.isfinite(recomputed)):
        return False
    return abs(stored - recomputed) <= 0.5 * 10 ** (math.floor(math.log10(abs(stored))) - digits + 1) * (1 + 1e-9)


def evidence_check(extra: dict) -> tuple[list[str], list[str], dict]:
    """Recompute the rows of pyfold.scene.hydrodynamics_evidence from the run files.

    Returns (report lines, disagreements, the trajectory-fit (IBOF) paired differences)."""
    lines, bad, traj = [], [], {}
    for answer, regime in (("ci_semi_dilute", "semi-dilute"), ("ci_dilute", "dilute")):
        stokes, jeff, path = extra[answer]
        seeds = sorted(stokes)
        st, je = np.array([stokes[s]["ci"] for s in seeds]), np.array([jeff[s]["ci"] for s in seeds])
        d = paired_difference(st, je)
        ens_s = ensemble_mean(st, [stokes[s]["stderr"] for s in seeds])
        ens_j = ensemble_mean(je, [jeff[s]["stderr"] for s in seeds])
        row = he.EVIDENCE[regime]
        pairs = dict(delta_ci=d.mean, delta_ci_stderr=d.stderr, p=d.p, ci_stokes=ens_s.mean,
                     ci_stokes_stderr=ens_s.error, ci_jeffery=ens_j.mean)
        # Remade runs (another machine, or the same scene in another study's sweep) are other
        # realisations of a chaotic suspension: a value then agrees within twice the combined
        # standard error of the stored and the recomputed one; spreads and p-values are noted.
        spread = dict(delta_ci=(row.delta_ci_stderr, d.stderr), ci_stokes=(row.ci_stokes_stderr, ens_s.error),
                      ci_jeffery=(getattr(row, "ci_jeffery_stderr", ens_j.error), ens_j.error))
        for key, value in pairs.items():
            stored = getattr(row, key)
            if _agrees(stored, value):
                verdict = "ok"
            elif key in spread:
                width = 2.0 * math.hypot(*spread[key])
                verdict = (f"ok within 2 combined s.e. ({width:.2g})" if abs(stored - value) <= width
                           else f"DISAGREES beyond 2 combined s.e. ({width:.2g})")
            else:
                verdict = "differs (a spread or p-value of another realisation)"
            lines.append(f"| {regime} | {key} | {stored:.3g} | {value:.4g} | {verdict} |")
            if verdict.startswith("DISAGREES"):
                bad.append(f"{regime}.{key}: module {stored:.3g}, run files {value:.4g}")
        if row.seeds != len(seeds):
            bad.append(f"{regime}.seeds: module {row.seeds}, run files {len(seeds)}")
        # Trajectory fit of Folgar-Tucker + IBOF to a2(t) (pyfold.fast_fit.fit_ci_rk4): the C_I a
        # moulding code running IBOF needs; stated beside the closure-free headline.
        fits = {m: np.array([r[s]["ci_trajectory"] for s in seeds]) for m, r in (("stokes", stokes), ("jeffery", jeff))}
        dt_ = paired_difference(fits["stokes"], fits["jeffery"])
        traj[regime] = dict(stokes=float(fits["stokes"].mean()), jeffery=float(fits["jeffery"].mean()),
                            delta=dt_.mean, stderr=dt_.stderr, p=dt_.p)
        check = path / "single_fibre_check.nc"  # written by the study's analysis (ci_hydrodynamics.single_fibre_check)
        period_error = math.nan
        if check.exists():
            c = xr.open_dataset(check, engine="h5netcdf")
            period_error = float(c["period"].sel(shape="spheroid").values[0]) / c.attrs["jeffery_period_spheroid"] - 1
        for key, value in (("traj_delta_ci", dt_.mean), ("traj_delta_ci_stderr", dt_.stderr), ("traj_p", dt_.p),
                           ("period_error", period_error)):
            stored = getattr(row, key)
            if _agrees(stored, value):
                verdict = "ok"
            elif key == "traj_delta_ci":
                width = 2.0 * math.hypot(row.traj_delta_ci_stderr, dt_.stderr)
                verdict = (f"ok within 2 combined s.e. ({width:.2g})" if abs(stored - value) <= width
                           else f"DISAGREES beyond 2 combined s.e. ({width:.2g})")
            elif key == "period_error":  # one deterministic single-particle solve: no realisation spread
                verdict = "DISAGREES"
            else:
                verdict = "differs (a spread or p-value of another realisation)"
            lines.append(f"| {regime} | {key} | {stored:.3g} | {value:.4g} | {verdict} |")
            if verdict.startswith("DISAGREES"):
                bad.append(f"{regime}.{key}: module {stored:.3g}, run files {value:.4g}")
    return lines, bad, traj


def _dominated(r: Row, others) -> bool:
    return any(o.cpu_s <= r.cpu_s and o.error <= r.error and (o.cpu_s < r.cpu_s or o.error < r.error)
               for o in others if o is not r)


def mark_pareto(rows: list[Row]) -> None:
    for r in rows:
        same = [o for o in rows if o.answer == r.answer]
        r.pareto = not _dominated(r, same)
        r.pareto_stokes = r.model == "stokes" and not _dominated(r, [o for o in same if o.model == "stokes"])


# Save
TITLES = {"jeffery_period": "Jeffery period, β = 3 spheroid (relative error vs T_J)",
          "eta_eff": "η_eff, random spheres φ = 0.1 (relative error vs extrapolated)",
          "ci_semi_dilute": "C_I closure-free, β = 5, n L³ = 4.98 (|ΔC_I| vs Stokes 42³, tol 1e-4)",
          "ci_semi_dilute_trajectory": "C_I IBOF trajectory fit, β = 5, n L³ = 4.98 (|ΔC_I| vs Stokes 42³, tol 1e-4)",
          "ci_dilute": "C_I closure-free, β = 5, n L³ = 0.91 (|ΔC_I| vs Stokes 42³, tol 1e-4)",
          "ci_dilute_trajectory": "C_I IBOF trajectory fit, β = 5, n L³ = 0.91 (|ΔC_I| vs Stokes 42³, tol 1e-4)",
          "ci_resolution": "C_I closure-free, β = 5, n L³ = 4.98, resolution (|ΔC_I| vs the finest grid)",
          "ci_resolution_trajectory": "C_I IBOF trajectory fit, β = 5, n L³ = 4.98, resolution (|ΔC_I| vs the "
                                      "finest grid)"}
#: figure panels: (title, ((answer, legend label), ...)); the second answer of a panel in other colours
PANELS = (("Jeffery period", (("jeffery_period", ""),)),
          ("η_eff", (("eta_eff", ""),)),
          ("C_I closure-free", (("ci_semi_dilute", "semi-dilute"), ("ci_dilute", "dilute"))),
          ("C_I IBOF trajectory fit", (("ci_semi_dilute_trajectory", "semi-dilute"),
                                       ("ci_dilute_trajectory", "dilute"))),
          ("C_I against resolution, semi-dilute", (("ci_resolution", "closure-free"),
                                                   ("ci_resolution_trajectory", "IBOF trajectory"))))
#: figure markers per factor varied
MARKS = {"grid": "o", "kappa": "s", "tol": "^", "dt": "D", "model": "*", "reuse": "v", "precision": "x",
         "ranks": "P", "setting": "o"}


def figure(rows: list[Row], path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 7.6), layout="constrained")
    axes = fig.subplots(2, 3).ravel()
    for ax, (title, answers) in zip(axes, PANELS):
        for (answer, label), colour_shift in zip(answers, (0, 1)):
            sub = [r for r in rows if r.answer == answer]
            if not sub:
                continue
            floor = 1e-4  # analytic rows (no cost) drawn at 0.1 ms
            for r in sub:
                colour = ("tab:blue" if r.model == "stokes" else "tab:orange") if not colour_shift else \
                    ("tab:purple" if r.model == "stokes" else "tab:red")
                x, y = max(r.cpu_s, floor), max(r.error, 1e-8)
                ax.plot(x, y, MARKS.get(r.sweep, "o"), color=colour, ms=5,
                        mfc=colour if (r.pareto or (len(answers) == 1 and r.pareto_stokes)) else "none")
                if math.isfinite(r.error_stderr):
                    ax.errorbar(x, y, yerr=[[min(r.error_stderr, 0.99 * y)], [r.error_stderr]], color=colour, lw=0.7)
            front = sorted((r for r in sub if r.pareto), key=lambda r: r.cpu_s)
            ax.step([max(r.cpu_s, floor) for r in front], [max(r.error, 1e-8) for r in front], where="post",
                    color="k" if not colour_shift else "grey", lw=1,
                    label="Pareto front" + (f" {label}" if label else ""))
            ref = [r for r in sub if r.setting.endswith("[reference]")]
            if answer.startswith("ci_semi_dilute") and ref:  # the rule of numerics.preset = "study"
                from pyfold.scene.study_preset import ADMISSIBLE_FRACTION

                ax.axhline(ADMISSIBLE_FRACTION * ref[0].error, color="tab:green", ls=":", lw=1,
                           label=f"{ADMISSIBLE_FRACTION:g} × statistical error ({label})")
            front_s = sorted((r for r in sub if r.pareto_stokes), key=lambda r: r.cpu_s)
            if len(answers) == 1 and len(front_s) > 1:
                ax.step([r.cpu_s for r in front_s], [max(r.error, 1e-8) for r in front_s], where="post", color="tab:blue",
                        lw=0.8, ls="--", label="front of the Stokes rows")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU time per answer [s]")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=7)
    axes[-1].set_axis_off()
    axes[0].set_ylabel("relative error (filled: on a front)")
    for ax in axes[2:5]:
        ax.set_ylabel("|ΔC_I| (blue/orange first, purple/red second)", fontsize=8)
    fig.suptitle("speed-accuracy: ○ grid, □ κ, △ tolerance, ▽ solve reuse, × precision, ✚ ranks, ◇ Δt/scheme, "
                 "★ model level; blue Stokes (fft), orange jeffery kinematics", fontsize=9)
    fig.savefig(path, dpi=130)


def _fmt_err(r: Row) -> str:
    if r.answer.startswith("ci"):
        base = f"{r.error:.1e}"
        return base + (f" ± {r.error_stderr:.1e}" if math.isfinite(r.error_stderr) else " (s.e.)")
    return f"{r.error:.1e}"


def report(rows: list[Row], info: dict, ev_lines: list[str], bad: list[str], traj: dict) -> str:
    lines = ["# Speed-accuracy: the Pareto table", "",
             "Error against CPU time for each answer; ★ = Pareto-optimal (no row of that answer is both "
             "cheaper and more accurate); ☆ = Pareto-optimal among the Stokes rows (when the scene needs the "
             "Stokes solver). CPU s per answer (one period, one η_eff, one C_I run); load = 1-min "
             "load average of the 2-core machine when measured (– : re-used run, load not recorded). The only "
             "Stokes backend is `fft` (no hypre backend is built).", ""]
    for answer in TITLES:
        sub = sorted((r for r in rows if r.answer == answer), key=lambda r: r.cpu_s)
        if not sub:
            continue
        lines += [f"## {TITLES[answer]}", "", f"Reference: {sub[0].reference}.", "",
                  "| ★ | model | setting | value | error | CPU s | wall s | load | source |", "|---|---|---|---|---|---|---|---|---|"]
        for r in sub:
            val = f"{r.value:.3e}" if answer.startswith("ci") else f"{r.value:.5g}"
            lines.append(f"| {'★' if r.pareto else ('☆' if r.pareto_stokes else '')} | {r.model} | {r.setting} | {val} | {_fmt_err(r)} | "
                         f"{r.cpu_s:.3g} | {'–' if not math.isfinite(r.wall_s) else f'{r.wall_s:.3g}'} | "
                         f"{'–' if not math.isfinite(r.load) else f'{r.load:.1f}'} | "
                         f"{r.source} |")
        lines.append("")
    lines += [f"η_eff cross-check: {info['rheology_cross_check']}.", "",
              "## Evidence for `hydrodynamics = \"auto\"` recomputed from the run files", "",
              "| regime | quantity | pyfold/scene/hydrodynamics_evidence.py | run files | |", "|---|---|---|---|---|",
              *ev_lines, "",
              "Trajectory fit of Folgar–Tucker + IBOF to a2(t) (pyfold.fast_fit.fit_ci_rk4), same runs:", "",
              "| regime | C_I Stokes | C_I contacts only | paired difference ± s.e. | p |", "|---|---|---|---|---|"]
    for regime, t in traj.items():
        lines.append(f"| {regime} | {t['stokes']:.2e} | {t['jeffery']:.2e} | {t['delta']:+.2e} ± {t['stderr']:.1e} | "
                     f"{t['p']:.3g} |")
    lines += ["", "Disagreements: " + ("none" if not bad else "; ".join(bad)), "",
              f"Cost: {info['total_cpu_s']:.0f} CPU-s, {info['total_wall_s']:.0f} s wall, load average "
              f"{info['load_before']:.1f} → {info['load_after']:.1f}."]
    return "\n".join(lines) + "\n"


# Run
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "speed_accuracy")
    ap.add_argument("--only", choices=("period", "eta", "ci"), nargs="+", default=("period", "eta", "ci"))
    args = ap.parse_args()
    p = LARGE if args.large else SMALL
    args.out.mkdir(parents=True, exist_ok=True)
    load_before, c0, w0 = os.getloadavg()[0], _cpu(), time.perf_counter()
    rows, info, ev_lines, bad, traj = [], {"rheology_cross_check": "not run"}, [], [], {}
    if "period" in args.only:
        print("(1) Jeffery period", flush=True)
        rows += period_rows(p)
    if "eta" in args.only:
        print("(2) eta_eff", flush=True)
        r, info = eta_rows(p, args.out)
        rows += r
    if "ci" in args.only:
        print("(3) C_I", flush=True)
        r, extra = ci_rows(p, args.out)
        rows += r
        ev_lines, bad, traj = evidence_check(extra)
    mark_pareto(rows)
    info.update(total_cpu_s=_cpu() - c0, total_wall_s=time.perf_counter() - w0, load_before=load_before,
                load_after=os.getloadavg()[0])

    fields = [f.name for f in dataclasses.fields(Row)]
    def column(k):
        a = np.array([getattr(r, k) for r in rows])
        return a.astype(np.int8) if a.dtype == bool else a  # netCDF has no boolean type

    ds = xr.Dataset({k: ("row", column(k)) for k in fields})
    for k, u in dict(cpu_s="s", wall_s="s", dt="s", value="1", error="1", error_stderr="1", load="1").items():
        ds[k].attrs["units"] = u
    ds["error"].attrs["long_name"] = "relative error (period, eta_eff) or |C_I - C_I(Stokes reference)|"
    ds["value"].attrs["long_name"] = "period [s, gamma_dot = 1], eta_eff [eta_f] or C_I [1]"
    ds.attrs.update(format="pyfold.study.speed_accuracy", creator=creator(),
                    created=datetime.now(timezone.utc).isoformat(), command=command_line([Path(sys.executable).name, *sys.argv]),
                    form="large" if args.large else "small", evidence_disagreements=json.dumps(bad),
                    trajectory_fit=json.dumps(traj), **{k: v for k, v in info.items()})
    ds.to_netcdf(args.out / "pareto.nc", engine="h5netcdf")
    figure(rows, args.out / "pareto.png")
    text = report(rows, info, ev_lines, bad, traj)
    (args.out / "pareto.md").write_text(text)
    print(text)
    if bad:
        print("evidence table disagrees with the run files: " + "; ".join(bad))
        raise SystemExit(1)


if __name__ == "__main__":
    main()
