"""How much strain a β = 5 fibre suspension needs to reach its steady state.

Question
    The fluid-coupled series (ci_fluid_series.py) runs every scene to a strain of 200 from
    an isotropic start, and MSER-5 finds 1 of its 24 runs stationary there. Is that a
    transient that ends — at which strain — or a drift that goes on? What does it change in
    the closure-free C_I read over the stationary window? The contacts-only twins of the
    series (the same scenes, seeds and initial states, Jeffery kinematics + contacts) cost
    seconds per run, so they are run to a strain of 1000 and the question is asked of each
    prefix: the records up to strain T, for T = 200, 400, ..., 1000.

Method
    Scenes: ci_fluid_series.scene_of(n_l3, "jeffery", seed, 1000): β = 5, n L³ = 2.49 /
    4.98 / 7.98 (49 / 98 / 157 fibres in the 2.7 L cell), α = 0.1 d, Δt = 0.02, records every
    0.2 strain, seeds 1–4 (studies/sweeps/steady_state_strain.toml). Per run and prefix T:
    pyfold.steady_state.detect_steady_state on a2(t) over [0, T] (MSER-5 onset, the latest
    over the components; stationary unless the MSER minimum lies in the second half or a
    diagonal component drifts by more than 3 s.e. over the last half of the kept part); the
    end drift of the diagonal components [per unit strain]; the closure-free C_I by rate
    regression (pyfold.ci_estimators.ci_rate_regression with the run's own a4, Cox's ξ) over
    the window [onset, T]. Per n L³ and T: the number of stationary runs, the largest onset
    and drift, and the ensemble C_I (pyfold.ensemble.ensemble_mean: the larger of the scatter
    over seeds and the pooled regression errors).
    The fluid-coupled runs (--fluid N_L3 ...): the series' finished Stokes runs at those
    concentrations are copied (the series' own files stay as they are) and extended to
    --fluid-t-end with ``pyfold run --resume`` (pyfold.extend: the same steps as a run made in
    one go), and the same question is asked of every prefix. Without --fluid the
    contacts-only strain is only the estimate the fluid-coupled cost is planned with.
    Warm start (--warm N_L3 ...): the series' Stokes scene of each seed, its fibres placed
    at the centres and axes of the last snapshot of that seed's contacts-only run of this
    study (strain 1000, where the sheared lattice is back at its unsheared offset, so the
    state is one of a cell at t = 0), run to --warm-t-end; the same question is asked of its
    prefixes 50, 100, ... Does a fluid-coupled run started near the contacts-only steady state
    reach its own steady state within a strain the trajectory runs already pay, and does its
    closure-free C_I equal the one the extended isotropic-start runs (--fluid) find?

Command
    .venv/bin/python studies/interaction_coefficient/steady_state_strain.py [--executor slurm]
        [--seeds 1 2] [--t-end 1000] [--analyse-only]
        [--fluid 8 --fluid-t-end 400]   # also extend the series' Stokes runs at n L³ 8 to strain 400
        [--warm 8 --warm-t-end 150]     # also run n L³ 8 from the contacts-only runs' end state
    (--fluid needs the series' finished runs: ci_fluid_series.py, its --out or --series-dir)

Cost (2 cores)
    Measured: the sweep's 12 contacts-only runs 948 CPU-s in all (17 / 58–59 / 161–163 CPU-s
    per run at n L³ 2.49 / 4.98 / 7.98), about 8 min wall two at a time; the analysis about a
    CPU-minute. --fluid 8 --fluid-t-end 400: 812–843 CPU-s per Stokes run for its extra strain
    200, 3315 CPU-s for the four (about 28 min wall two at a time on the idle machine).
    --warm 8 --warm-t-end 150: 652–678 CPU-s per Stokes run, 2656 CPU-s for the four (about
    24 min wall two at a time).

Outputs (under out/interaction_coefficient/steady_state_strain/, ``--out``)
    sweep/                     the runs (pyfold sweep folder)
    steady_state_strain.nc     per n L³, prefix strain and seed: stationary, onset, drift, C_I ± s.e.
    steady_state_strain.md     the table per n L³ and prefix strain
    steady_state_strain.png    a2_xx(t) of every run with its onsets, and C_I against the prefix strain
    fluid/nl3_<n>/seed<k>/     the extended fluid-coupled runs (scene.toml, run.h5, cost.json)
    fluid.md, fluid.nc, fluid.png  their table, data and figure (--fluid)
    warm/nl3_<n>/seed<k>/      the warm-started runs (scene.toml, positions.npy, orientations.npy, run.h5, cost.json)
    warm.md, warm.nc, warm.png     their table, data and figure (--warm)
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import xarray as xr

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))

import ci_fluid_series as series  # noqa: E402

#: prefix strains at which the steady-state question is asked
PREFIXES = (200.0, 400.0, 600.0, 800.0, 1000.0)
DIAGONAL = ((0, 0), (1, 1), (2, 2))


def analyse_run(path: Path, prefixes) -> dict:
    """Per prefix strain: stationary, onset, largest diagonal end drift, closure-free C_I ± s.e."""
    from pyfold import run_checks
    from pyfold.ci_estimators import ci_rate_regression
    from pyfold.run_results import open_run
    from pyfold.steady_state import detect_steady_state

    ds = open_run(path)
    L = run_checks.velocity_gradient_of(path)
    xi = run_checks.shape_factor_of(ds)
    t, a2, a4 = ds["time"].values, ds["a2"].values, ds["a4"].values
    ds.close()
    out = {"t": t, "a2_xx": a2[:, 0, 0]}
    for T in prefixes:
        keep = t <= T + 1e-9
        if t[keep][-1] < T - 1e-6:
            continue  # the run is shorter than this prefix
        ss = detect_steady_state(t[keep], a2[keep])
        drift = ss.drift_slope.reshape(3, 3)
        reg = ci_rate_regression(t[keep], a2[keep], a4[keep], L, xi, window=(ss.onset_time, T))
        window = keep & (t >= ss.onset_time)
        out[T] = {"stationary": bool(ss.stationary), "onset": float(ss.onset_time),
                  "drift": float(max(abs(drift[i, j]) for i, j in DIAGONAL)), "ci": reg.ci, "stderr": reg.stderr,
                  "a2_diag": [float(a2[window, i, i].mean()) for i in range(3)]}
    return out


def extended_scene(n_l3: float, seed: int, t_end: float) -> str:
    """The series' Stokes scene of ``n_l3`` and ``seed`` with the later end ``t_end`` and every
    other key as the series ran it (its snapshot interval included: pyfold.extend keeps the
    recorded intervals and refuses a scene that sets another)."""
    import re

    text = series.scene_of(n_l3, "stokes", seed, series_t_end()).toml
    text, n = re.subn(r"(?m)^t_end = .*$", f"t_end = {t_end!r}", text)
    if n != 1:
        raise SystemExit(f"the series' scene has {n} t_end lines, expected one")
    return text


def series_t_end() -> float:
    """The strain the fluid-coupled series ran to (its sweep file)."""
    from pyfold.sweep.study import load_form

    return float(load_form(series.SWEEPS, "ci_fluid_series", False).arguments["t_end"])


def extend_fluid(concentrations, seeds, t_end: float, series_dir: Path, out: Path, parallel: int = 2) -> dict:
    """Copy the series' finished Stokes runs at ``concentrations`` into ``out`` and extend each to
    ``t_end`` (two ``pyfold run --resume`` at a time; a finished extension is kept). Returns
    ``{(n_l3, seed): run file}`` and writes each run's CPU and wall time to its cost.json."""
    import shutil

    from pyfold.sweep import study as sweep_study

    spec = sweep_study.load_form(series.SWEEPS, "ci_fluid_series", False, seeds=tuple(seeds))
    done = sweep_study.run_sweep(spec, series_dir, analyse_only=True)
    waiting, result = [], {}
    for n_l3 in concentrations:
        for seed in seeds:
            source = done.get(((n_l3, "stokes"), seed))
            if source is None:
                raise SystemExit(f"--fluid {n_l3:g}: the series has no finished Stokes run of seed {seed} in "
                                 f"{series_dir}; run ci_fluid_series.py first")
            folder = out / "fluid" / f"nl3_{n_l3:g}" / f"seed{seed}"
            folder.mkdir(parents=True, exist_ok=True)
            run, scene, cost = folder / "run.h5", folder / "scene.toml", folder / "cost.json"
            result[n_l3, seed] = run
            text = extended_scene(n_l3, seed, t_end)
            if cost.exists() and scene.exists() and scene.read_text() == text:
                continue  # extended already
            if not run.exists() and not (folder / "run.h5.partial").exists():
                shutil.copyfile(source, run)
            scene.write_text(text)
            waiting.append(folder)
    run_folders(waiting, parallel, resume=True)
    return result


def run_folders(waiting: list[Path], parallel: int, resume: bool) -> None:
    """``pyfold run`` of each folder's scene.toml to its run.h5 (``--resume`` when ``resume`` or when a
    killed run left its run.h5.partial), ``parallel`` at a time, each run's CPU and wall time to its
    cost.json; SystemExit naming the folder on a failure."""
    import json
    import os
    import subprocess
    import time

    pyfold = str(Path(sys.executable).with_name("pyfold"))
    live: dict = {}
    waiting = list(waiting)
    while waiting or live:
        while waiting and len(live) < parallel:
            folder = waiting.pop(0)
            log = open(folder / "log.txt", "a")
            proc = subprocess.Popen([pyfold, "run", str(folder / "scene.toml"), "-o", str(folder / "run.h5")]
                                    + (["--resume"] if resume or (folder / "run.h5.partial").exists() else []),
                                    stdout=log, stderr=subprocess.STDOUT)
            live[proc.pid] = (proc, folder, log, time.perf_counter())
        pid, status, usage = os.wait4(-1, 0)
        if pid not in live:
            continue
        proc, folder, log, start = live.pop(pid)
        log.close()
        if os.waitstatus_to_exitcode(status) != 0:
            raise SystemExit(f"{folder}: pyfold run failed (exit {os.waitstatus_to_exitcode(status)}); "
                             f"see {folder / 'log.txt'}; rerun to continue it")
        (folder / "cost.json").write_text(json.dumps({"cpu_s": usage.ru_utime + usage.ru_stime,
                                                      "wall_s": time.perf_counter() - start}))
        print(f"finished {folder}", flush=True)


def warm_scene(n_l3: float, seed: int, t_end: float) -> str:
    """The series' Stokes scene of ``n_l3`` and ``seed`` to ``t_end``, its fibres placed at the
    given centres and axes of positions.npy / orientations.npy (beside the scene file)."""
    import re

    text = series.scene_of(n_l3, "stokes", seed, t_end).toml
    text, n = re.subn(r'(?m)^orientation = "isotropic"$',
                      'orientation = "given"\norientations = "orientations.npy"\npositions = "positions.npy"', text)
    if n != 1:
        raise SystemExit(f"the series' scene has {n} isotropic orientation lines, expected one")
    return text


def twin_end_state(path: Path, side: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Centres (wrapped into the cubic cell of ``side``) and axes of the last snapshot of the contacts-only run
    ``path``, and its strain. The snapshot must lie at a strain where the sheared lattice is
    back to its unsheared offset (γ̇ t L_y a multiple of L_x), so that the centres are a state
    of a cell starting at t = 0."""
    from pyfold import run_checks
    from pyfold.run_results import open_run

    ds = open_run(path)
    try:
        t = float(ds["snapshot_time"].values[-1])
        x, p = ds["x"].values[-1], ds["p"].values[-1]
    finally:
        ds.close()
    L = run_checks.velocity_gradient_of(path)
    shift = L[0, 1] * t  # lattice offset over L_x in the cubic cell
    if abs(shift - round(shift)) > 1e-9 or np.count_nonzero(L) != 1:
        raise SystemExit(f"{path}: its last snapshot (strain {t:g}) is not at an unsheared lattice offset")
    return np.mod(x, side), p, t


def warm_fluid(n_l3: float, seeds, t_end: float, twins: dict, out: Path, parallel: int = 2) -> dict:
    """Stokes runs of the series' scene at ``n_l3`` started from the end state of each seed's
    contacts-only twin (``twins``: {seed: run file}) and run to ``t_end`` (a finished run is kept).
    Returns ``{(n_l3, seed): run file}``."""
    waiting, result = [], {}
    for seed in seeds:
        folder = out / "warm" / f"nl3_{n_l3:g}" / f"seed{seed}"
        folder.mkdir(parents=True, exist_ok=True)
        x, p, t0 = twin_end_state(twins[seed], series.scene_of(n_l3, "stokes", seed, t_end).side)
        text = warm_scene(n_l3, seed, t_end)
        result[n_l3, seed] = folder / "run.h5"
        if (folder / "cost.json").exists() and (folder / "scene.toml").read_text() == text:
            continue
        np.save(folder / "positions.npy", x)
        np.save(folder / "orientations.npy", p)
        (folder / "scene.toml").write_text(text)
        (folder / "started_from.txt").write_text(f"{twins[seed]} at strain {t0:g}\n")
        waiting.append(folder)
    run_folders(waiting, parallel, resume=False)
    return result


def analyse(done: dict, seeds: list[int], out: Path, prefixes=PREFIXES, name: str = "steady_state_strain",
            model: str = "jeffery kinematics + contacts") -> str:
    from pyfold.ensemble import ensemble_mean

    runs = {(n_l3, seed): analyse_run(path, prefixes) for ((n_l3, _model), seed), path in done.items()}
    concentrations = sorted({n for n, _ in runs})
    shape = (len(concentrations), len(prefixes), len(seeds))
    fields = {k: np.full(shape, np.nan) for k in ("stationary", "onset", "drift", "ci", "ci_stderr")}
    lines = ["| n L³ | strain T | stationary runs | onsets (strain) | largest end drift [1/strain] | "
             "C_I closure-free over [onset, T] ± s.e. | a2 xx, yy, zz over [onset, T] |", "|---|---|---|---|---|---|---|"]
    for i, n in enumerate(concentrations):
        for j, T in enumerate(prefixes):
            have = [s for s in seeds if (n, s) in runs and T in runs[n, s]]
            if not have:
                continue
            rows = [runs[n, s][T] for s in have]
            for s, r in zip(have, rows):
                k = (i, j, seeds.index(s))
                fields["stationary"][k], fields["onset"][k], fields["drift"][k] = r["stationary"], r["onset"], r["drift"]
                fields["ci"][k], fields["ci_stderr"][k] = r["ci"], r["stderr"]
            ens = ensemble_mean([r["ci"] for r in rows], [r["stderr"] for r in rows])
            lines.append(f"| {n:g} | {T:g} | {sum(r['stationary'] for r in rows)}/{len(rows)} | "
                         f"{', '.join(format(r['onset'], '.0f') for r in rows)} | {max(r['drift'] for r in rows):.1e} | "
                         f"{ens.mean:+.2e} ± {ens.error:.1e} | "
                         + ", ".join(f"{np.mean([r['a2_diag'][i] for r in rows]):.3f}" for i in range(3)) + " |")
    dims = ("n_l3", "strain", "seed")
    units = {"stationary": "1", "onset": "1", "drift": "1", "ci": "1", "ci_stderr": "1"}
    names = {"stationary": "1 when detect_steady_state finds the prefix stationary",
             "onset": "MSER-5 onset strain (latest over the components)",
             "drift": "largest end drift of a diagonal a2 component per unit strain",
             "ci": "closure-free C_I by rate regression over [onset, strain]", "ci_stderr": "its standard error"}
    ds = xr.Dataset({k: (dims, v, {"units": units[k], "long_name": names[k]}) for k, v in fields.items()},
                    coords={"n_l3": concentrations, "strain": list(prefixes), "seed": seeds})
    ds.attrs.update(beta=series.BETA, alpha_over_d=series.ALPHA_OVER_D, model=model)
    out.mkdir(parents=True, exist_ok=True)
    ds.to_netcdf(out / f"{name}.nc", engine="h5netcdf")
    _figure(runs, concentrations, seeds, ds, prefixes, out / f"{name}.png")
    text = f"{model}:\n\n" + "\n".join(lines) + "\n"
    (out / f"{name}.md").write_text(text)
    return text


def _figure(runs: dict, concentrations, seeds, ds: xr.Dataset, prefixes, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(concentrations), figsize=(4.2 * len(concentrations), 6.5), squeeze=False)
    for i, n in enumerate(concentrations):
        ax = axes[0, i]
        for s in seeds:
            if (n, s) in runs:
                r = runs[n, s]
                line, = ax.plot(r["t"], r["a2_xx"], lw=0.6)
                final = max((T for T in prefixes if T in r), default=None)
                if final is not None:
                    ax.axvline(r[final]["onset"], color=line.get_color(), ls=":", lw=0.8)
        ax.set_title(f"n L³ = {n:g}: a2_xx (dotted: onset over the whole run)", fontsize=9)
        ax.set_xlabel("strain")
        ax = axes[1, i]
        ci = ds["ci"].sel(n_l3=n)
        mean = ci.mean("seed").values
        err = ci.std("seed", ddof=1).values / math.sqrt(ci.sizes["seed"])
        ax.errorbar(list(prefixes), mean, yerr=err, fmt="o-")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel("prefix strain T")
        ax.set_ylabel("closure-free C_I over [onset, T]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--seeds", type=int, nargs="+", help="override the sweep's seeds")
    ap.add_argument("--t-end", type=float, help="override the sweep's strain")
    ap.add_argument("--out", type=Path, default=Path("out/interaction_coefficient/steady_state_strain"))
    ap.add_argument("--fluid", type=float, nargs="+", metavar="N_L3",
                    help="also extend the fluid-coupled series' Stokes runs at these n L^3 (see the docstring)")
    ap.add_argument("--fluid-t-end", type=float, default=400.0, help="strain of the extended fluid-coupled runs")
    ap.add_argument("--series-dir", type=Path, default=Path("out/interaction_coefficient/fluid_series/sweep"),
                    help="the fluid-coupled series' sweep folder")
    ap.add_argument("--warm", type=float, nargs="+", metavar="N_L3",
                    help="also run the series' Stokes scene at these n L^3 from the end state of each seed's "
                         "contacts-only twin of this study (see the docstring)")
    ap.add_argument("--warm-t-end", type=float, default=150.0, help="strain of the warm-started Stokes runs")
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    spec = sweep_study.load_form(series.SWEEPS, "steady_state_strain", False,
                                 seeds=tuple(args.seeds) if args.seeds else None,
                                 arguments={"t_end": args.t_end} if args.t_end else None)
    done = sweep_study.run_sweep(spec, args.sweep_dir or args.out / "sweep", args.executor,
                                 analyse_only=args.analyse_only)
    print(analyse(done, list(spec.seeds), args.out))
    if args.fluid:
        first = series_t_end()
        if not args.fluid_t_end > first:
            raise SystemExit(f"--fluid-t-end: must exceed the series' strain {first:g}, got {args.fluid_t_end:g}")
        runs = extend_fluid(args.fluid, list(spec.seeds), args.fluid_t_end, args.series_dir, args.out)
        prefixes = tuple(T for T in np.arange(first, args.fluid_t_end + 1e-9, 100.0))
        done_fluid = {((n, "stokes"), seed): path for (n, seed), path in runs.items()}
        print(analyse(done_fluid, list(spec.seeds), args.out, prefixes, "fluid",
                      "Stokes-coupled with contacts (the series' runs extended)"))
    if args.warm:
        runs = {}
        for n in args.warm:
            twins = {seed: path for ((n_l3, _m), seed), path in done.items() if n_l3 == n}
            if set(twins) != set(spec.seeds):
                raise SystemExit(f"--warm {n:g}: this study has no contacts-only run of n L^3 {n:g} for every seed")
            runs.update(warm_fluid(n, list(spec.seeds), args.warm_t_end, twins, args.out))
        prefixes = tuple(T for T in np.arange(50.0, args.warm_t_end + 1e-9, 50.0))
        done_warm = {((n, "stokes"), seed): path for (n, seed), path in runs.items()}
        print(analyse(done_warm, list(spec.seeds), args.out, prefixes, "warm",
                      "Stokes-coupled with contacts, started from the contacts-only twins' end state"))


if __name__ == "__main__":
    main()
