"""Which closure of a4 in terms of a2 is best for fibres sheared from isotropy, judged by direct simulations?

Question
    A direct simulation of a contacts-only fibre suspension in simple shear gives both
    a2(t) and its population's own, exact a4(t). Against those, which closure
    a4 ≈ f(a2) (docs/physics.md#closure-approximations) is best, and which
    differences between closures are statistically significant across an ensemble of
    independent seeds? Three measures per closure and run:

    1. e_trans: the time mean of the relative a4:D error ||(f(a2) − a4):D|| / ||a4:D||
       over the transient, strain 0 .. T_J/2, with T_J = (2π/γ̇)(β_e + 1/β_e) the Jeffery
       period of the fibres' equivalent aspect ratio β_e (from the run's shape factor ξ;
       docs/physics.md#jeffery-period). Why a fixed half period rather than the onset
       that pyfold.steady_state.detect_steady_state (MSER-5) finds: the semi-dilute
       runs keep tumbling almost undamped with period T_J/2 over the whole run (see
       a2_vs_dns.png), so they have no stationary part and MSER puts its "onset" at an
       arbitrary point of the first swings (strain 5 to 47 over four seeds); a window
       of the same strain for every seed keeps the paired comparison like with like,
       and the first half period holds the whole overshoot from isotropy, where the
       distribution changes fastest. e_stat: the same over the late part, from the
       MSER onset but not before T_J/2, with its blocking standard error (a true
       steady state only where detect_steady_state says so: `stationary` in the
       outputs); and the late time mean of each signed component of
       (f(a2) − a4):D / γ̇ (pyfold.closure_check.window_means): which components a
       closure gets wrong, and in which direction, beyond the noise of the population.
    2. a2_rms: the a2(t) the closure predicts. C_I per closure by a trajectory fit of
       Folgar–Tucker with that closure to the run's whole a2(t)
       (pyfold.fast_fit.fit_ci_rk4: fixed-step RK4, C_I >= 0; the closure error is
       absorbed into C_I as in docs/physics.md#the-fitted-c_i-depends-on-the-closure);
       --ci regression uses the rate regression with the closure's a4 on the run's a2
       instead (no ODE, clipped at C_I = 0 where negative, which leaves Folgar–Tucker
       tumbling like Jeffery's: the prediction then ranks the closures' own damping);
       then Folgar–Tucker (docs/physics.md#folgar-tucker-model) with that closure and C_I
       is integrated from
       the run's initial a2, and a2_rms = sqrt(mean_t ||a2_FT(t) − a2_DNS(t)||_F^2) over
       the whole run. C_I by the rate regression with the run's own a4 ("dns_a4") is
       listed as the reference value, free of closure error. Folgar–Tucker driven by
       that tabulated a4 is *not* used as an a2 reference over these long runs: it is
       open loop (a4 does not respond to a2), so a deviation of a2 is stretched by
       ξ(D·a2 + a2·D) without the −2ξ a4:D feedback that bounds it in a closed model,
       and it grew beyond a2_xx = 2 within strain 150 in a trial.
    3. A ranking per scene and measure with pyfold.ensemble.rank_paired: ensemble mean ±
       standard error over seeds; neighbours compared by paired t-tests over the same
       seeds (every closure is judged on the same runs), p-values adjusted together by
       Holm's rule, significant at 5 %. With few seeds a chain of neighbour tests
       separates little, so each closure is also compared with the first rank
       (paired t-tests, Holm-adjusted over the closures): "worse than the first".

    The exact closure "fec" (the fourth moment of the angular central Gaussian with the
    given a2: exact for fibres that start isotropic and follow Jeffery's equation) is
    the "best possible closure given a2" line only if the population stays in that
    family; the contacts may move it out, and the ranking says whether it does so
    measurably. A finite population of N fibres has sampling noise of order N^-1/2 in
    its a4, so even a perfect closure shows an error against it:
    pyfold.closure_check.exact_closure_sampling_floor draws populations of the same N
    from the angular central Gaussian with the run's a2 and measures fec against them
    ("floor" in the tables). A transient or late a4:D error near the floor is
    indistinguishable from the population's noise; the signed component means and the
    a2 prediction average that noise down.

Command
    Small form (default: β = 10 at n L³ ≈ 4 (semi-dilute, 55 fibres) and ≈ 15
    (concentrated, 207 fibres), 4 seeds each, strain 150, scenes from
    pyfold.scene.sheared_fibres; the runs are the sweep studies/sweeps/closure_verdict.toml,
    kept in out/closures_vs_dns/sweep/ (pyfold sweep, docs/cluster.md): each computed once,
    re-used, and resumed from its checkpoint when interrupted, so a killed study continues
    where it stopped):

        nice -n 5 .venv/bin/python studies/closures_vs_dns/closure_verdict.py [--np 1]

    --np N runs each simulation on N MPI ranks (pyfold run --np N). Large form (β = 5,
    10, 20 at n L³ ≈ 4 and 15, 8 seeds, strain 300):

        nice -n 5 .venv/bin/python studies/closures_vs_dns/closure_verdict.py --large

    --ci fit replaces the default trajectory fit (fixed-step RK4) by one through the
    adaptive solver (pyfold.fit.fit_parameters, C_I >= 0; about a minute per closure and
    run, so meant for a few closures: --closures fec,ibof,hybrid); outputs then go to
    out/closures_vs_dns/ci_fit/ (--ci regression: out/closures_vs_dns/ci_regression/).

    Judging runs made elsewhere (e.g. by studies/interaction_coefficient/ci_concentration.py
    under out/interaction_coefficient/runs/): scenes are formed from what the files say
    (β, n L³, fibre count, model, α, time step, record times), not from their names;
    unfinished or 2-D files and scenes with a single seed are skipped with a message;
    outputs go to out/closures_vs_dns/given_runs/:

        .venv/bin/python studies/closures_vs_dns/closure_verdict.py --runs 'out/interaction_coefficient/runs/*.h5'

    On a Slurm cluster the same command runs the simulations as job arrays and waits for
    them (cancelled or timed-out runs are resubmitted and resume from their checkpoints):

        .venv/bin/python studies/closures_vs_dns/closure_verdict.py --large --executor slurm

    For another batch scheduler every simulation is an independent `pyfold run`: write the scenes and
    one command per line, submit them as an array job of a batch scheduler (Slurm
    shown; any scheduler that runs line i in task i will do), then run the study, which
    finds the finished runs and only analyses. Each line calls the pyfold beside the
    python that wrote it (pyfold.command_line.pyfold_executable), every argument
    shell-quoted, so `sh` runs that pyfold with exactly the paths given, whatever
    characters --run-folder holds (a line break is refused: one command per line):

        .venv/bin/python studies/closures_vs_dns/closure_verdict.py --large --write-scenes
        sbatch --array=1-$(wc -l < out/closures_vs_dns/runs/commands.txt) \\
            --wrap 'sed -n "${SLURM_ARRAY_TASK_ID}p" out/closures_vs_dns/runs/commands.txt | sh'
        .venv/bin/python studies/closures_vs_dns/closure_verdict.py --large

    Measured cost of the small form on 2 shared cores, with other jobs keeping the load
    average at 5 to 9 throughout: the 8 simulations 4 × 3 s (55 fibres, 15 000 steps)
    and 40, 59, 59, 72 s (207 fibres), ~4 min; the analysis (15 closures evaluated on
    every record, rate regressions, the sampling floor, one batched Folgar–Tucker solve
    per closure and scene) about 1.6 min of CPU time, 5 to 6 min wall in invocations that
    re-used the runs and 14 min in one that shared the machine with a --ci fit run;
    ~9 min in all when the machine is not crowded further. The first process compiles
    the closures and solves; later ones read JAX's persistent cache. The "Cost" section
    of closure_verdict.md gives the times of the invocation that wrote it.
    --ci fit with 5 closures (fec, ibof, orw3, hybrid, quadratic) on the small form's
    runs: 20 min wall (3 min CPU), the 40 trajectory fits dominating.

Outputs (under out/closures_vs_dns/, or --out)
    closure_verdict.nc      per scene (dim scene), seed (dim member, values in seed)
                            and closure: e_trans, e_stat (± blocking s.e.), the signed
                            late component errors (± s.e.), C_I per closure and for the
                            DNS's own a4 (dim model) ± s.e., a2_rms, solver success and
                            admissibility, the sampling floors, MSER onsets; the DNS and
                            predicted a2 over record (time(scene, record)); per measure the
                            ranking (rank, mean, error, Holm p to the next and to the
                            first); xarray.open_dataset readable
    closure_errors.png      e_trans, e_stat and a2_rms per closure (seeds, and ensemble
                            mean ± s.e.), with the sampling floor
    closure_components.png  late signed components of (f(a2) − a4):D / γ̇ per closure
    a2_vs_dns.png           a2(t) of the DNS (seed mean and range) against Folgar–Tucker
                            with the four best closures by a2_rms, fec, hybrid, quadratic
    closure_verdict.md      the verdict in words, the ranked tables with significance,
                            C_I per closure, the component table, the cost
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

from pyfold import run_checks
from pyfold.ci_estimators import ci_rate_regression
from pyfold.closure_check import (
    COMPONENTS,
    closure_a4,
    closure_errors,
    exact_closure_sampling_floor,
    window_means,
)
from pyfold.command_line import check_single_line, job_line, write_job_file
from pyfold.ensemble import ensemble_mean, holm, paired_difference, rank_paired
from pyfold.errors import InadmissibleOrientationWarning, InputError
from pyfold.fast_fit import fit_ci_rk4
from pyfold.fit import fit_parameters
from pyfold.models import FolgarTucker, solve_batch
from pyfold.run_results import open_run
from pyfold.scene.sheared_fibres import sheared_fibres
from pyfold.steady_state import detect_steady_state

# Parameters
#: The sweep files of the forms (betas, n L^3, seeds, strain): studies/sweeps/closure_verdict[_large].toml.
SWEEPS = Path(__file__).resolve().parents[1] / "sweeps"


def sweep_spec(large: bool, seeds=None, t_end=None):
    """The sweep (pyfold.sweep.spec.SweepSpec) of a form, narrowed to ``seeds`` / ``t_end`` when given."""
    from pyfold.sweep.study import load_form

    return load_form(SWEEPS, "closure_verdict", large, seeds=tuple(seeds) if seeds else None,
                     arguments={"t_end": float(t_end)} if t_end else None)


def params_of(spec) -> dict:
    """betas, n_l3, seeds, t_end of a sweep."""
    return dict(betas=tuple(spec.axes["beta"]), n_l3=tuple(spec.axes["n_l3"]), seeds=tuple(spec.seeds),
                t_end=float(spec.arguments["t_end"]))
#: Every 3-D closure of pyfold.closures.available(3) once ("sihyb" is an alias of
#: "implicit_hybrid").
CLOSURES = ("fec", "ibof", "orw3", "orf", "orl", "orw", "ore", "ors", "natural",
            "hybrid", "implicit_hybrid", "siq", "sqc", "quadratic", "linear")
REFERENCE = "dns_a4"  # C_I by rate regression with the run's own a4: no closure error
MEASURES = {
    "e_trans": "transient a4:D error (time mean over strain 0 .. T_J/2)",
    "e_stat": "late a4:D error (time mean from the MSER onset, not before T_J/2)",
    "a2_rms": "RMS a2 error of Folgar-Tucker with the closure's own C_I",
}
LEVEL = 0.05
CI_LONG_NAME = {
    "trajectory": "C_I by a trajectory fit of Folgar-Tucker's a2(t) per closure, fixed-step RK4 "
                  "(dns_a4: rate regression, own a4)",
    "regression": "C_I by rate regression with the closure's a4 on the DNS a2 (dns_a4: the DNS's own a4)",
    "fit": "C_I by a trajectory fit of Folgar-Tucker's a2(t) per closure (dns_a4: rate regression, own a4)",
}
#: Folgar–Tucker tolerances: the a2 errors compared are >= 1e-2 (RMS over a run), so an
#: integration error of order 1e-6 leaves them and their differences untouched.
RTOL, ATOL = 1e-6, 1e-8
#: Sampling floor: every FLOOR_STRIDE-th record, FLOOR_DRAWS populations each.
FLOOR_STRIDE, FLOOR_DRAWS = 10, 32


# Problem: the runs
def run_name(beta: float, n_l3: float, seed: int, t_end: float) -> str:
    return f"beta{beta:g}_nl3-{n_l3:g}_seed{seed}_t{t_end:g}"


def is_finished(path: Path) -> bool:
    """A complete, successful run file (anything else is re-run or resumed)."""
    if not path.is_file():
        return False
    try:
        return open_run(path).attrs.get("status") == "ok"
    except InputError:
        return False


def write_scenes(params: dict, folder: Path, ranks: int) -> Path:
    """Scenes and one `pyfold run` command per line, for a batch scheduler."""
    lines = []
    for beta in params["betas"]:
        for n_l3 in params["n_l3"]:
            for seed in params["seeds"]:
                name = run_name(beta, n_l3, seed, params["t_end"])
                scene = folder / f"{name}.toml"
                scene.write_text(sheared_fibres(beta, n_l3, seed, params["t_end"]).toml)
                out = folder / f"{name}.h5"
                if not is_finished(out):
                    resume = ["--resume"] if out.with_name(out.name + ".partial").exists() else []
                    lines.append(job_line(["run", scene, "-o", out, "--np", str(ranks), *resume]))
    return write_job_file(folder / "commands.txt", lines)


def describe(path: Path) -> dict:
    """β, n L³, count, seed and record times of a run file (read from the file)."""
    ds = open_run(path)
    if ds.attrs.get("status") != "ok":
        raise InputError(f"{path}: run status {ds.attrs.get('status')!r}; only finished runs are judged")
    if int(ds.attrs["dim"]) != 3:
        raise InputError(f"{path}: a 3-D run is needed (the closures judged are 3-D)")
    scene = json.loads(ds.attrs["scene"])
    length = float(np.max(ds["particle_length"].values))
    radius = float(np.max(ds["particle_radius"].values))
    volume = float(np.prod(scene["cell"]["size"]))
    count = int(ds.sizes["particle"])
    return dict(path=path, beta=round(length / (2.0 * radius), 6), n_l3=count * length**3 / volume,
                count=count, seed=int(ds.attrs["seed"]), time=np.asarray(ds["time"].values, dtype=np.float64),
                alpha=float(ds.attrs["alpha"]), dt=float(ds.attrs["dt"]),
                collisions=scene["model"].get("collisions", "?"), hydrodynamics=scene["model"].get("hydrodynamics", "?"))


def group_scenes(paths: list[Path]) -> dict[str, list[dict]]:
    """Runs of one scene: same β, n L³, count, model, security zone, time step and record
    times; one run per seed."""
    groups: dict[tuple, list[dict]] = {}
    for path in paths:
        try:
            info = describe(path)
        except InputError as exc:  # a failed, 2-D or foreign file among the given ones
            print(f"skipped: {exc}")
            continue
        t = info["time"]
        key = (info["beta"], round(info["n_l3"], 3), info["count"], info["collisions"], info["hydrodynamics"],
               info["alpha"], info["dt"], t.size, round(float(t[0]), 9), round(float(t[-1]), 9))
        groups.setdefault(key, []).append(info)
    scenes = {}
    for key, runs in sorted(groups.items()):
        runs.sort(key=lambda r: r["seed"])
        seeds = [int(r["seed"]) for r in runs]
        if len(set(seeds)) != len(seeds):
            raise InputError(f"scene {key}: the same seed twice among {[str(r['path']) for r in runs]}")
        label = f"beta{key[0]:g}_nl3-{key[1]:.3g}_{key[3]}"
        if label in scenes:  # the same β and n L³ with another step, zone or record times
            label += f"_dt{key[6]:g}_t{key[9]:g}"
        scenes[label] = runs
    return scenes


# Solver: the closure test of one run
def half_jeffery_period(xi: float, L: np.ndarray) -> float:
    """T_J / 2 = (π/γ̇)(β_e + 1/β_e), β_e from ξ = (β_e² − 1)/(β_e² + 1)
    (docs/physics.md#jeffery-period), γ̇ = sqrt(2 D:D)."""
    D = 0.5 * (L + L.T)
    gamma_dot = math.sqrt(2.0 * float(np.sum(D * D)))
    beta_e = math.sqrt((1.0 + xi) / (1.0 - xi))
    return math.pi / gamma_dot * (beta_e + 1.0 / beta_e)


def judge_run(info: dict, closures: tuple[str, ...], ci_method: str = "trajectory") -> dict:
    """Closure errors, C_I per closure (rate regression, or a trajectory fit), sampling floor of one run."""
    path = info["path"]
    ds = open_run(path)
    L = run_checks.velocity_gradient_of(path)
    xi = run_checks.shape_factor_of(ds)
    t = np.asarray(ds["time"].values, dtype=np.float64)
    a2 = np.asarray(ds["a2"].values, dtype=np.float64)
    a4 = np.asarray(ds["a4"].values, dtype=np.float64)
    steady = detect_steady_state(t, a2)
    half = half_jeffery_period(xi, L)
    late = max(steady.onset_time, t[0] + half)
    errors = closure_errors(ds, closures, velocity_gradient=L)
    trans = window_means(errors, t[0], t[0] + half, stderr=False)
    stat = window_means(errors, late, t[-1], stderr=True)
    ci, ci_se = [], []
    for name in closures:
        if ci_method == "trajectory":
            # Folgar-Tucker with the closure fitted to the run's whole a2(t) by the fixed-step
            # RK4 of pyfold.fast_fit (C_I >= 0; the C_I a moulding code running it would use)
            fit = fit_ci_rk4(name, t, a2, L, xi)
            ci.append(fit.ci)
            ci_se.append(fit.stderr)
            continue
        if ci_method == "fit":
            ci.append(0.0)
            ci_se.append(math.nan)
            continue
        r = ci_rate_regression(t, a2, closure_a4(name, a2), L, xi)
        ci.append(r.ci)
        ci_se.append(r.stderr)
    if ci_method == "fit":
        # Least squares of the Folgar–Tucker a2(t) against the run's on every 2nd
        # record (strain 0.4 apart: the a2 swings last ~T_J/2 = 26), C_I >= 0 by
        # the fit's bounds; ODE tolerances as for the predictions (RTOL), the fit's
        # termination above that error floor.
        data = xr.Dataset({"a2": (("time", "i", "j"), a2[::2])},
                          coords={"time": ("time", t[::2], {"units": "s"})})
        for k, name in enumerate(closures):
            res = fit_parameters(data, FolgarTucker(ci=1e-3, xi=xi, closure=name), params=("ci",), L=L,
                                 rtol=RTOL, atol=ATOL, fit_rtol=1e-6, fit_atol=1e-5)
            ci[k], ci_se[k] = float(res.values["ci"]), float(res.stderr["ci"])
    r = ci_rate_regression(t, a2, a4, L, xi)
    ci.append(r.ci)
    ci_se.append(r.stderr)
    floor = exact_closure_sampling_floor(a2[::FLOOR_STRIDE], info["count"], L, draws=FLOOR_DRAWS,
                                         seed=info["seed"])
    floor_t = t[::FLOOR_STRIDE]
    return dict(
        t=t, a2=a2, a4=a4, L=L, xi=xi, steady=steady, errors=errors, half=half, late=late,
        e_trans=np.asarray(trans["error_contracted"].values),
        e_stat=np.asarray(stat["error_contracted"].values),
        e_stat_se=np.asarray(stat["error_contracted_stderr"].values),
        comp=np.asarray(stat["error_components"].values),
        comp_se=np.asarray(stat["error_components_stderr"].values),
        a4D=np.asarray(stat["a4_D"].values),
        ci=np.array(ci), ci_se=np.array(ci_se),
        floor_trans=float(floor[floor_t <= t[0] + half].mean()),
        floor_stat=float(floor[floor_t >= late].mean()),
    )


def predict_a2(runs: list[dict], closures: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Folgar–Tucker a2(t) per closure, batched over the seeds (one compiled solve per closure).

    Returns ``a2_pred (closure, seed, time, i, j)``, ``ok (closure, seed)`` (solver
    success), ``admissible (closure, seed)``.
    """
    t = runs[0]["t"]
    L = runs[0]["L"]
    xi = runs[0]["xi"]
    a2_0 = np.stack([r["a2"][0] for r in runs])
    preds, ok, adm = [], [], []
    for k, name in enumerate(closures):
        ci = np.array([max(r["ci"][k], 0.0) for r in runs])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InadmissibleOrientationWarning)  # recorded in `admissible`
            sol = solve_batch((FolgarTucker(ci=1e-3, xi=xi, closure=name), {"ci": ci}), a2_0, L, t,
                              rtol=RTOL, atol=ATOL)
        preds.append(np.asarray(sol.a2))
        ok.append(np.asarray(sol.status) == 0)
        adm.append(np.asarray(sol.admissible))
    return np.stack(preds), np.stack(ok), np.stack(adm)


def judge_scene(label: str, runs: list[dict], closures: tuple[str, ...], ci_method: str = "trajectory") -> xr.Dataset:
    """Every measure of one scene, over its seeds and closures, with the rankings."""
    judged = [judge_run(r, closures, ci_method) for r in runs]
    pred, ok, adm = predict_a2(judged, closures)
    a2_dns = np.stack([j["a2"] for j in judged])
    diff = pred - a2_dns[None]
    with np.errstate(invalid="ignore", over="ignore"):
        a2_rms = np.sqrt(np.mean(np.sum(diff**2, axis=(-2, -1)), axis=-1))  # (model, seed)
    a2_rms = np.where(ok & np.isfinite(a2_rms), a2_rms, np.nan)
    models = list(closures) + [REFERENCE]
    half = judged[0]["half"]
    t = judged[0]["t"]
    comps = list(COMPONENTS[3])
    seeds = [int(r["seed"]) for r in runs]
    ds = xr.Dataset(
        {
            "e_trans": (("seed", "closure"), np.stack([j["e_trans"] for j in judged]),
                        {"units": "1", "long_name": MEASURES["e_trans"]}),
            "e_stat": (("seed", "closure"), np.stack([j["e_stat"] for j in judged]),
                       {"units": "1", "long_name": MEASURES["e_stat"]}),
            "e_stat_stderr": (("seed", "closure"), np.stack([j["e_stat_se"] for j in judged]),
                              {"units": "1", "long_name": "blocking s.e. of e_stat"}),
            "component_error": (("seed", "closure", "component"), np.stack([j["comp"] for j in judged]),
                                {"units": "1", "long_name": "stationary time mean of (f(a2) - a4):D / gamma_dot"}),
            "component_error_stderr": (("seed", "closure", "component"), np.stack([j["comp_se"] for j in judged]),
                                       {"units": "1", "long_name": "blocking s.e. of component_error"}),
            "a4D_stationary": (("seed", "component"), np.stack([j["a4D"] for j in judged]),
                               {"units": "1", "long_name": "stationary time mean of a4:D / gamma_dot (DNS)"}),
            "ci": (("seed", "model"), np.stack([j["ci"] for j in judged]),
                   {"units": "1", "long_name": CI_LONG_NAME[ci_method]}),
            "ci_stderr": (("seed", "model"), np.stack([j["ci_se"] for j in judged]),
                          {"units": "1", "long_name": "standard error of C_I (regression: blocking of the scores; "
                                                      "fit: linearised)"}),
            "a2_rms": (("seed", "closure"), a2_rms.T,
                       {"units": "1", "long_name": MEASURES["a2_rms"] + " (NaN: the solve failed)"}),
            "solve_ok": (("seed", "closure"), ok.T.astype(np.int8), {"long_name": "Folgar-Tucker solve succeeded"}),
            "admissible": (("seed", "closure"), adm.T.astype(np.int8),
                           {"long_name": "predicted a2 stayed an orientation tensor"}),
            "onset_time": ("seed", [j["steady"].onset_time for j in judged],
                           {"units": "s", "long_name": "start of the stationary part (MSER-5 on a2)"}),
            "late_start": ("seed", [j["late"] for j in judged],
                           {"units": "s", "long_name": "start of the late window (onset, not before T_J/2)"}),
            "stationary": ("seed", np.array([j["steady"].stationary for j in judged], dtype=np.int8),
                           {"long_name": "stationary part found and not drifting (see steady_message)"}),
            "steady_message": ("seed", [j["steady"].message for j in judged]),
            "floor_trans": ("seed", [j["floor_trans"] for j in judged],
                            {"units": "1", "long_name": "fec a4:D error against ACG samples of the run's N, transient"}),
            "floor_stat": ("seed", [j["floor_stat"] for j in judged],
                           {"units": "1", "long_name": "fec a4:D error against ACG samples of the run's N, stationary"}),
            "a2_dns": (("seed", "time", "i", "j"), a2_dns, {"units": "1", "long_name": "a2 of the DNS"}),
            "a2_pred": (("closure", "seed", "time", "i", "j"), pred,
                        {"units": "1", "long_name": "a2 of Folgar-Tucker with the closure's C_I (clipped at 0)"}),
            "run_file": ("seed", [str(r["path"]) for r in runs]),
        },
        coords={"seed": seeds, "closure": list(closures), "model": models, "component": comps,
                "time": ("time", t, {"units": "s", "long_name": "time (strain at gamma_dot = 1 1/s)"}),
                "i": ["x", "y", "z"], "j": ["x", "y", "z"]},
        attrs={"scene": label, "beta": runs[0]["beta"], "n_L3": float(np.mean([r["n_l3"] for r in runs])),
               "count": runs[0]["count"], "xi": judged[0]["xi"], "half_jeffery_period": half,
               "collisions": runs[0]["collisions"],
               "hydrodynamics": runs[0]["hydrodynamics"], "ci_method": ci_method},
    )
    return ds


# Statistics: rankings
def rankings(ds: xr.Dataset) -> dict[str, list]:
    """rank_paired per measure (a2_rms only over the closures solved for every seed),
    plus each entry's Holm-adjusted paired p against the first rank."""
    out, vs_first = {}, {}
    for measure in MEASURES:
        per_seed = {c: ds[measure].sel(closure=c).values for c in ds["closure"].values
                    if np.all(np.isfinite(ds[measure].sel(closure=c).values))}
        rows = rank_paired(per_seed, level=LEVEL)
        first = rows[0].name
        raw = [paired_difference(per_seed[r.name], per_seed[first]).p for r in rows[1:]]
        vs_first[measure] = dict(zip([r.name for r in rows[1:]], holm(raw)))
        out[measure] = rows
    return out, vs_first


def ranking_dataset(label: str, ranks: dict[str, list], vs_first: dict[str, dict], closures: list[str]) -> xr.Dataset:
    """The rankings of one scene as variables over (scene, closure)."""
    models = closures
    data = {}
    for measure, rows in ranks.items():
        table = {m: (np.nan, np.nan, np.nan, np.nan, 0, np.nan) for m in models}
        for row in rows:
            table[row.name] = (row.rank, row.mean, row.error, row.p_next, int(row.better_than_next),
                               vs_first[measure].get(row.name, np.nan))
        arr = np.array([table[m] for m in models], dtype=float)
        data[f"{measure}_rank"] = (("scene", "closure"), arr[None, :, 0], {"long_name": f"rank by {measure} (1 best)"})
        data[f"{measure}_mean"] = (("scene", "closure"), arr[None, :, 1], {"units": "1", "long_name": MEASURES[measure]})
        data[f"{measure}_error"] = (("scene", "closure"), arr[None, :, 2],
                                    {"units": "1", "long_name": f"s.e. over seeds of {measure}"})
        data[f"{measure}_p_next"] = (("scene", "closure"), arr[None, :, 3],
                                     {"long_name": "Holm-adjusted p of the paired t-test against the next rank"})
        data[f"{measure}_better_than_next"] = (("scene", "closure"), arr[None, :, 4].astype(np.int8),
                                               {"long_name": f"better than the next rank at level {LEVEL}"})
        data[f"{measure}_p_first"] = (("scene", "closure"), arr[None, :, 5],
                                      {"long_name": "Holm-adjusted p of the paired t-test against the first rank"})
    return xr.Dataset(data, coords={"scene": [label], "closure": models})


# Save: tables and the verdict
def t_crit(n: int) -> float:
    """Two-sided Student-t quantile at LEVEL for the mean of n seeds (n - 1 degrees of freedom)."""
    from scipy import stats

    return float(stats.t.ppf(1.0 - LEVEL / 2.0, max(n - 1, 1)))


def table(rows, vs_first: dict, floor: float | None = None) -> list[str]:
    lines = ["| rank | closure | mean ± s.e. (seeds) | Holm p to next | better than next | "
             "Holm p vs first | worse than first |",
             "|---:|---|---|---:|:---:|---:|:---:|"]
    for row in rows:
        p = f"{row.p_next:.3g}" if math.isfinite(row.p_next) else "—"
        sig = "**yes**" if row.better_than_next else ("no" if math.isfinite(row.p_next) else "")
        pf = vs_first.get(row.name, math.nan)
        worse = ("**yes**" if pf < LEVEL else "no") if math.isfinite(pf) else ""
        pf_text = f"{pf:.3g}" if math.isfinite(pf) else "—"
        lines.append(f"| {row.rank} | {row.name} | {row.mean:.4g} ± {row.error:.2g} | {p} | {sig} | {pf_text} | {worse} |")
    if floor is not None:
        lines.append(f"| | *sampling floor (fec vs ACG populations of this N)* | {floor:.4g} | | |")
    return lines


def scene_report(ds: xr.Dataset, ranks: dict[str, list], vs_first: dict[str, dict]) -> tuple[list[str], list[str]]:
    """Markdown section of one scene and its verdict sentences."""
    label = ds.attrs["scene"]
    n = ds.sizes["seed"]
    lines = [f"## {label}: β = {ds.attrs['beta']:g}, n L³ = {ds.attrs['n_L3']:.3g}, "
             f"{ds.attrs['count']} fibres, {n} seeds {[int(x) for x in ds['seed'].values]}", ""]
    onset = ds["onset_time"].values
    lines.append(f"Transient window: strain 0 .. T_J/2 = {ds.attrs['half_jeffery_period']:.3g}. "
                 f"MSER-5 onset on a2 at strain {', '.join(f'{x:g}' for x in onset)}; late window from "
                 f"{', '.join(f'{x:g}' for x in ds['late_start'].values)}; a true steady state (no drift, "
                 f"trustworthy MSER minimum) in {int(ds['stationary'].sum())} of {n} seeds "
                 "(see `steady_message` in the NetCDF).")
    lines.append("")
    floor_t = ensemble_mean(ds["floor_trans"].values).mean if np.all(np.isfinite(ds["floor_trans"].values)) else None
    floor_s = ensemble_mean(ds["floor_stat"].values).mean
    for measure, floor in (("e_trans", floor_t), ("e_stat", floor_s), ("a2_rms", None)):
        lines += [f"### {measure}: {MEASURES[measure]}", ""] + table(ranks[measure], vs_first[measure], floor) + [""]
    failed = [m for m in ds["closure"].values if not np.all(np.isfinite(ds["a2_rms"].sel(closure=m).values))]
    if failed:
        lines.append(f"Not ranked by a2_rms (the Folgar–Tucker solve failed for some seed): {', '.join(failed)}.")
    inadm = [m for m in ds["closure"].values if not np.all(ds["admissible"].sel(closure=m).values)]
    if inadm:
        lines.append(f"Predicted a2 left the orientation tensors (trace or a negative eigenvalue) for: "
                     f"{', '.join(inadm)}.")
    lines.append("")
    # C_I per closure
    lines += [f"### C_I per closure ({CI_LONG_NAME[ds.attrs['ci_method']]}; mean ± s.e. over seeds)", "",
              "| closure | C_I | clipped at 0 in seeds |", "|---|---|---:|"]
    for m in ds["model"].values:
        v = ds["ci"].sel(model=m).values
        e = ensemble_mean(v)
        lines.append(f"| {m} | {e.mean:.3e} ± {e.error:.1e} | {int(np.sum(v < 0))} |")
    lines.append("")
    # stationary components of the best and of fec
    comps = list(ds["component"].values)
    lines += ["### Late-window signed components of (f(a2) − a4):D / γ̇ (mean ± s.e. over seeds; "
              f"`*`: nonzero by a t-test over the seeds at {LEVEL:g}, i.e. |mean| > {t_crit(n):.3g} s.e.)", "",
              "| closure | " + " | ".join(comps) + " |", "|---|" + "---|" * len(comps)]
    scale = ds["a4D_stationary"].mean("seed").values
    lines.append("| *DNS a4:D / γ̇* | " + " | ".join(f"{x:+.4f}" for x in scale) + " |")
    for c in ds["closure"].values:
        cells = []
        for k in range(len(comps)):
            e = ensemble_mean(ds["component_error"].sel(closure=c).values[:, k])
            star = "*" if abs(e.mean) > t_crit(n) * e.error else ""
            cells.append(f"{e.mean:+.4f}±{e.error:.4f}{star}")
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    lines.append("")
    # verdict sentences
    verdict = []

    def not_worse(measure):
        rows = ranks[measure]
        return [rows[0].name] + [r.name for r in rows[1:] if not vs_first[measure].get(r.name, 0.0) < LEVEL]

    def worse(measure):
        return [r.name for r in ranks[measure][1:] if vs_first[measure].get(r.name, 1.0) < LEVEL]

    for measure, what in (("e_trans", "a4:D error over the transient"), ("e_stat", "a4:D error over the late part"),
                          ("a2_rms", "a2(t) predicted with the closure's own C_I")):
        rows = ranks[measure]
        verdict.append(
            f"**{label}**, {what}: first {rows[0].name} ({rows[0].mean:.3g} ± {rows[0].error:.2g}); "
            f"not significantly worse than it: {', '.join(not_worse(measure)[1:]) or 'none'}; "
            f"significantly worse: {', '.join(worse(measure)) or 'none'}"
            + (f"; neighbour steps significant after {', '.join(r.name for r in rows if r.better_than_next)}"
               if any(r.better_than_next for r in rows) else "; no neighbour step significant") + ".")
    fec_s = next(r for r in ranks["e_stat"] if r.name == "fec")
    fec_t = next(r for r in ranks["e_trans"] if r.name == "fec")
    lead_s = ranks["e_stat"][0]
    lead_t = ranks["e_trans"][0]
    parts = []
    for tag, lead, fec_row, measure in (("transient", lead_t, fec_t, "e_trans"), ("late", lead_s, fec_s, "e_stat")):
        if lead.name == "fec":
            parts.append(f"fec ranks first over the {tag} part")
        else:
            d = paired_difference(ds[measure].sel(closure="fec").values, ds[measure].sel(closure=lead.name).values)
            parts.append(f"over the {tag} part fec ranks {fec_row.rank} ({fec_row.mean:.3g}), {lead.name} first "
                         f"({lead.mean:.3g}; fec − {lead.name} = {d.mean:+.3g} ± {d.stderr:.2g}, paired p = {d.p:.2g}, "
                         "unadjusted)")
    verdict.append("Is the exact closure best? " + "; ".join(parts) + ".")
    verdict.append(
        f"Sampling floor (fec against populations of {ds.attrs['count']} fibres drawn from the angular central "
        f"Gaussian with the run's a2): {floor_t if floor_t is not None else float('nan'):.3g} transient, "
        f"{floor_s:.3g} late, against fec's {fec_t.mean:.3g} and {fec_s.mean:.3g} on the DNS"
        + (": the a4:D norm errors of the best closures are at the level of the population's own sampling noise, "
           "so their order among themselves is not a property of the closures."
           if floor_s is not None and fec_s.mean < 1.5 * floor_s else "."))
    # Does the population leave the ACG family? fec's late signed components, beyond 2 s.e.
    comp = ds["component_error"].sel(closure="fec").values  # (seed, component)
    means = comp.mean(axis=0)
    errs = comp.std(axis=0, ddof=1) / math.sqrt(comp.shape[0]) if comp.shape[0] > 1 else np.full(means.shape, np.nan)
    scale = float(np.linalg.norm(ds["a4D_stationary"].mean("seed").values))
    biased = [f"{c} {m:+.2g} ± {e:.1g}" for c, m, e in zip(ds["component"].values, means, errs)
              if abs(m) > t_crit(n) * e]
    if biased:
        verdict.append(
            f"fec has a systematic late bias (t-test over seeds at {LEVEL:g}) in {', '.join(biased)} (in units of γ̇; "
            f"||time-mean a4:D||/γ̇ of the DNS is {scale:.3g}): the contacts move the population measurably out of "
            "the angular central Gaussian family, and closures fitted to that family (orthotropic fits, IBOF, "
            "natural) share the same bias (see the component table).")
    else:
        verdict.append(f"fec shows no late signed bias (t-test over seeds at {LEVEL:g}) in any component: within this ensemble the "
                       "population is not distinguishable from the angular central Gaussian family.")
    clipped = [str(m) for m in ds["closure"].values if np.sum(ds["ci"].sel(model=m).values < 0) > ds.sizes["seed"] / 2]
    if clipped:
        verdict.append(
            f"C_I ({ds.attrs['ci_method']}) came out negative for most seeds with {', '.join(clipped)} and was "
            "clipped to 0: their Folgar–Tucker a2 then keeps tumbling like Jeffery's (a2_vs_dns.png). Where the "
            "DNS damps its tumbling, closures that damp it by their own error (hybrid, quadratic) can rank well by "
            "a2_rms although their a4 is the worst: a2_rms then ranks the damping, not the closure (`--ci fit` "
            "fits C_I to a2(t) instead).")
    return lines, verdict


def overall(scene_ranks: dict[str, tuple[dict, dict]]) -> list[str]:
    """Closures never significantly worse than the first rank, over every scene and measure."""
    names = None
    worse_somewhere: dict[str, list[str]] = {}
    for label, (ranks, vs_first) in scene_ranks.items():
        for measure, rows in ranks.items():
            ok = {rows[0].name} | {r.name for r in rows[1:] if not vs_first[measure].get(r.name, 0.0) < LEVEL}
            names = ok if names is None else names & ok
            for r in rows[1:]:
                if vs_first[measure].get(r.name, 1.0) < LEVEL:
                    worse_somewhere.setdefault(r.name, []).append(f"{label} {measure}")
    firsts = [f"{label} {m}: {ranks[m][0].name}" for label, (ranks, _) in scene_ranks.items() for m in ranks]
    # In short: which closures are never separated from the first by their a4:D error, which always are
    a4_good, a4_bad = None, None
    for ranks, vs_first in scene_ranks.values():
        for measure in ("e_trans", "e_stat"):
            rows = ranks[measure]
            good = {rows[0].name} | {r.name for r in rows[1:] if not vs_first[measure].get(r.name, 0.0) < LEVEL}
            bad = {r.name for r in rows[1:] if vs_first[measure].get(r.name, 1.0) < LEVEL}
            a4_good = good if a4_good is None else a4_good & good
            a4_bad = bad if a4_bad is None else a4_bad & bad
    short = ("**In short.** Judged by their a4:D error against the simulations' own a4, "
             + (f"{', '.join(sorted(a4_good))} are never significantly worse than the best closure of a scene "
                "(transient and late part, every scene): among them the data do not pick a winner, their "
                "differences being a fraction of the populations' sampling noise. " if a4_good else
                "no closure is within the best group in every scene and window. ")
             + (f"{', '.join(sorted(a4_bad))} are significantly worse in every scene and window. " if a4_bad else "")
             + ("fec, the exact closure for Jeffery's equation, is in that best group but not measurably better "
                "than the closures fitted to it; where the contacts move the population out of the family for which "
                "it is exact, its signed bias per scene below says so." if a4_good and "fec" in a4_good else
                "fec, the exact closure for Jeffery's equation, is not in the best group everywhere.")
             + " The a2(t) ranking depends on how C_I is estimated (see each scene).")
    return [short, "", "**Overall.** First ranks: " + "; ".join(firsts) + ".",
            "Never significantly worse than the first rank, in every scene and measure: "
            + (", ".join(sorted(names)) if names else "none") + ".",
            "Significantly worse than the first somewhere: "
            + ("; ".join(f"{k} ({', '.join(v)})" for k, v in sorted(worse_somewhere.items())) or "none") + ".", ""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", nargs="+", help="judge these run files (globs allowed) instead of running the "
                        "study's own ensemble")
    parser.add_argument("--large", action="store_true", help="β 5, 10, 20; n L³ 4, 15; 8 seeds; strain 300")
    parser.add_argument("--seeds", type=int, nargs="+", help="override the seeds of the chosen form")
    parser.add_argument("--t-end", type=float, help="override the strain of the chosen form")
    parser.add_argument("--np", type=int, default=1, help="MPI ranks per simulation (pyfold run --np)")
    parser.add_argument("--closures", default=",".join(CLOSURES), help="comma-separated closures to judge")
    parser.add_argument("--write-scenes", action="store_true",
                        help="only write the scenes and runs/commands.txt (one pyfold run per line) and stop")
    parser.add_argument("--ci", choices=("trajectory", "regression", "fit"), default="trajectory",
                        help="C_I per closure for the a2 prediction: trajectory fit by pyfold.report's fixed-step "
                        "RK4 (default: seconds per closure and run, FEC ~1 min), rate regression (cheap; a "
                        "negative C_I is clipped to 0, so the prediction then ranks the closures' damping, not "
                        "their a4) or a trajectory fit by the adaptive solver (pyfold.fit.fit_parameters; ~1 min "
                        "per closure and run)")
    parser.add_argument("--out", type=Path, help="output folder (default out/closures_vs_dns; with --runs "
                        "out/closures_vs_dns/given_runs, with --ci fit out/closures_vs_dns/ci_fit)")
    parser.add_argument("--run-folder", type=Path, default=Path("out/closures_vs_dns/runs"),
                        help="where --write-scenes writes the scenes and commands.txt")
    from pyfold.sweep import study as sweep_study

    sweep_study.add_arguments(parser)
    args = parser.parse_args()
    if args.write_scenes:
        try:  # before anything is written: commands.txt holds one command per line
            check_single_line("--run-folder", args.run_folder)
        except InputError as exc:
            parser.error(str(exc))
    if args.out is None:
        args.out = Path("out/closures_vs_dns") / ("given_runs" if args.runs else "") / (
            {"fit": "ci_fit", "regression": "ci_regression"}.get(args.ci, ""))
    closures = tuple(c for c in run_checks.check_closures(args.closures, dim=3) if c != "exact")
    if "fec" not in closures:
        raise InputError("--closures: fec is needed (the verdict compares every closure with it)")
    spec = sweep_spec(args.large, args.seeds, args.t_end)
    params = params_of(spec)
    args.out.mkdir(parents=True, exist_ok=True)
    run_folder = args.run_folder
    run_folder.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    cost: dict[str, float] = {}

    if args.write_scenes:
        commands = write_scenes(params, run_folder, args.np)
        print(f"written: scenes in {run_folder}, commands (one independent run per line) in {commands}")
        return

    # Run
    if args.runs:
        paths = sorted({Path(p) for pattern in args.runs for p in (glob.glob(pattern) or [pattern])})
        if not paths:
            raise InputError("--runs: no files")
    else:
        # the sweep (pyfold.sweep), locally or on Slurm: each run once, resumed when interrupted
        done = sweep_study.run_sweep(spec, args.sweep_dir or run_folder.parent / "sweep", args.executor, args.np)
        paths = list(done.values())
    cost["simulations (or re-use)"] = time.perf_counter() - start
    scenes = group_scenes(paths)
    for label in list(scenes):
        if len(scenes[label]) < 2:
            print(f"skipped scene {label}: {len(scenes.pop(label))} run; the paired tests need at least 2 seeds")
    if not scenes:
        raise InputError("no scene with at least 2 finished runs (seeds) to judge")

    # Analyse
    results, rank_sets, md, verdicts, scene_ranks = {}, [], [], [], {}
    for label, runs in scenes.items():
        t0 = time.perf_counter()
        ds = judge_scene(label, runs, closures, args.ci)
        ranks, vs_first = rankings(ds)
        scene_ranks[label] = (ranks, vs_first)
        results[label] = ds
        rank_sets.append(ranking_dataset(label, ranks, vs_first, list(ds["closure"].values)))
        lines, verdict = scene_report(ds, ranks, vs_first)
        md += lines
        verdicts += verdict + [""]
        cost[f"analysis {label}"] = time.perf_counter() - t0
        print(f"scene {label}: analysed in {cost[f'analysis {label}']:.0f} s", flush=True)
        print("\n".join(lines), flush=True)

    verdicts = overall(scene_ranks) + verdicts

    # Save
    t0 = time.perf_counter()
    combined = combine(results, rank_sets)
    combined.attrs.update(question=__doc__.splitlines()[0], closures=",".join(closures), level=LEVEL,
                          ci_method=args.ci,
                          form="large" if args.large else ("runs given" if args.runs else "small"),
                          rtol=RTOL, atol=ATOL)
    nc = args.out / "closure_verdict.nc"
    combined.to_netcdf(nc, engine="h5netcdf")
    figures(results, args.out)
    cost["figures and NetCDF"] = time.perf_counter() - t0
    total = time.perf_counter() - start
    header = ["# Closure verdict against direct simulations", "",
              "Generated by `studies/closures_vs_dns/closure_verdict.py` (question, method and definitions in its "
              "docstring). Contacts-only fibres (Jeffery kinematics, the collision strategy) in simple shear from "
              "isotropy; every closure judged on the same seeds; Holm-adjusted paired t-tests between neighbours "
              f"at {LEVEL:g}. Smaller is better in every table.", "", "## Verdict", ""]
    footer = ["## Cost", "", f"Wall time on this machine (2 shared cores): {total:.0f} s in all."] + [
        f"* {k}: {v:.0f} s" for k, v in cost.items()] + [""]
    (args.out / "closure_verdict.md").write_text("\n".join(header + verdicts + md + footer))
    print("\n".join(["", "Verdict:"] + verdicts))
    print(f"written: {nc}, {args.out / 'closure_verdict.md'}, figures ({total:.0f} s)")


def combine(results: dict[str, xr.Dataset], rank_sets: list[xr.Dataset]) -> xr.Dataset:
    """One flat Dataset over ``scene``: seeds as ``member`` (the seed values in ``seed``),
    times as ``record`` (``time(scene, record)``), padded with NaN where scenes differ."""
    members = max(ds.sizes["seed"] for ds in results.values())
    records = max(ds.sizes["time"] for ds in results.values())
    parts = []
    for label, ds in results.items():
        d = ds.rename({"seed": "member", "time": "record"})
        d = d.assign_coords(member=np.arange(d.sizes["member"]), record=np.arange(d.sizes["record"]))
        d["seed"] = ("member", ds["seed"].values)
        d["time"] = ("record", ds["time"].values, ds["time"].attrs)
        d = d.reindex(member=np.arange(members), record=np.arange(records))
        for key in ("beta", "n_L3", "count", "xi"):
            d[key] = float(ds.attrs[key])
        d.attrs = {}
        parts.append(d.expand_dims(scene=[label]))
    out = xr.concat(parts, dim="scene", data_vars="all", join="outer")
    ranks = xr.concat(rank_sets, dim="scene", join="outer")
    out = xr.merge([out, ranks], join="outer")
    out["beta"].attrs.update(units="1", long_name="fibre aspect ratio L/d")
    out["n_L3"].attrs.update(units="1", long_name="number density times L^3")
    out["count"].attrs.update(units="1", long_name="fibres in the cell")
    out["xi"].attrs.update(units="1", long_name="Jeffery shape factor of the fibres")
    return out


def figures(results: dict[str, xr.Dataset], folder: Path) -> None:
    from matplotlib.figure import Figure

    labels = list(results)
    # closure errors per closure, with error bars
    fig = Figure(figsize=(13, 3.4 * len(labels)), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(labels), 3, squeeze=False))
    for row, label in enumerate(labels):
        ds = results[label]
        for col, measure in enumerate(("e_trans", "e_stat", "a2_rms")):
            ax = axes[row, col]
            names = list(ds["closure"].values)
            values = ds[measure].transpose(..., "seed").values  # (name, seed)
            means = np.nanmean(values, axis=1)
            order = np.argsort(np.where(np.isfinite(means), means, np.inf))
            x = np.arange(len(names))
            for rank, k in enumerate(order):
                v = values[k]
                finite = np.isfinite(v)
                ax.plot(np.full(finite.sum(), rank) + np.linspace(-0.15, 0.15, finite.sum()), v[finite], ".",
                        color="grey", alpha=0.6, ms=4)
                if finite.all():
                    e = ensemble_mean(v)
                    ax.errorbar(rank, e.mean, yerr=e.error, fmt="o", color="k", capsize=3, ms=4)
            if measure != "a2_rms":
                floor = np.nanmean(ds["floor_trans" if measure == "e_trans" else "floor_stat"].values)
                ax.axhline(floor, color="tab:red", lw=0.8, ls="--", label="sampling floor (fec vs ACG, same N)")
                ax.legend(frameon=False, fontsize=7)
            ax.set_xticks(x, [names[k] for k in order], rotation=45, ha="right", fontsize=7)
            ax.set_yscale("log")
            ax.set_title(f"{label}: {measure}", fontsize=9)
            ax.set_ylabel({"e_trans": "||(f−a4):D|| / ||a4:D||, transient",
                           "e_stat": "||(f−a4):D|| / ||a4:D||, stationary",
                           "a2_rms": "RMS ||a2_FT − a2_DNS||_F"}[measure], fontsize=8)
            if measure == "e_stat":
                ax.set_ylabel("||(f−a4):D|| / ||a4:D||, late part", fontsize=8)
    fig.savefig(folder / "closure_errors.png", dpi=120)

    # stationary components
    fig = Figure(figsize=(13, 3.2 * len(labels)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(labels), 1, squeeze=False)[:, 0])
    for ax, label in zip(axes, labels):
        ds = results[label]
        names = list(ds["closure"].values)
        comps = list(ds["component"].values)
        width = 0.8 / len(comps)
        for k, comp in enumerate(comps):
            v = ds["component_error"].sel(component=comp).transpose("closure", "seed").values
            means = v.mean(axis=1)
            errs = v.std(axis=1, ddof=1) / math.sqrt(v.shape[1])
            ax.bar(np.arange(len(names)) + (k - len(comps) / 2 + 0.5) * width, means, width, yerr=errs,
                   capsize=1.5, label=comp)
        ax.axhline(0.0, color="k", lw=0.6)
        # linear near zero, logarithmic beyond: the linear closure's xy error is ~100x the best ones'
        ax.set_yscale("symlog", linthresh=1e-3)
        ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("(f(a2) − a4):D / γ̇, late part")
        ax.set_title(label, fontsize=9)
        ax.legend(ncols=6, fontsize=7, frameon=False)
    fig.savefig(folder / "closure_components.png", dpi=120)

    # a2(t) per closure against the DNS
    comps = [((0, 0), "a_xx"), ((1, 1), "a_yy"), ((2, 2), "a_zz"), ((0, 1), "a_xy")]
    fig = Figure(figsize=(14, 3.2 * len(labels)), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(labels), len(comps), squeeze=False))
    for row, label in enumerate(labels):
        ds = results[label]
        rms = ds["a2_rms"].mean("seed").to_series().dropna().sort_values()
        shown = list(rms.index[:4])
        for extra in ("fec", "hybrid", "quadratic"):
            if extra not in shown and extra in rms.index:
                shown.append(extra)
        t = ds["time"].values
        for col, ((i, j), name) in enumerate(comps):
            ax = axes[row, col]
            dns = ds["a2_dns"].values[:, :, i, j]
            ax.fill_between(t, dns.min(axis=0), dns.max(axis=0), color="grey", alpha=0.3, lw=0, label="DNS seeds")
            ax.plot(t, dns.mean(axis=0), color="k", lw=1.4, label="DNS mean")
            for m in shown:
                ax.plot(t, ds["a2_pred"].sel(closure=m).values[:, :, i, j].mean(axis=0), lw=0.9, label=f"FT, {m}")
            ax.set_title(f"{label}: {name}", fontsize=9)
            ax.set_xlabel("strain γ̇t")
        axes[row, 0].legend(fontsize=6, frameon=False)
    fig.savefig(folder / "a2_vs_dns.png", dpi=120)


if __name__ == "__main__":
    main()
