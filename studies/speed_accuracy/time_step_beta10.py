"""Does twice the time step move the fluid-coupled C_I of β = 10 fibres?

Question
    The β = 10 series (studies/interaction_coefficient/ci_fluid_series.py --beta 10, and the
    calibrated one before this study) step at Δt = α/(γ̇L) = 0.01, half the β = 5 step, because the security zone
    is α = 0.1 d and d is half as large; with a Stokes solve every 4th step that is 25 solves per
    unit strain and 7 CPU-hours per point of 4 seeds to strain 200. At β = 5, Δt = 2α/(γ̇L)
    passed the preset's rule (docs/speed_accuracy.md#stokes-numerics-judged-by-c_i-numericspreset--study,
    with a solve every step). Does Δt = 2α/(γ̇L) = 0.02 with the series' solve every 4th step
    keep the β = 10 C_I within half its statistical error, and what does it save?

Method
    The series' Stokes runs at φβ = 0.5 (n L³ = 6.4: 88 fibres, cell 2.4 L, 72³ grid, fibres
    voxelised at 1.212 R, Zhang's β_e = 7.61 recorded, κ = 10³, CG tolerance 10⁻³, a solve every
    4th step, AB2) with Δt = 0.02 (studies/sweeps/time_step_beta10.toml), seeds 1–4, strain 20:
    a seed fixes the initial state (checked: the initial axes are equal bit for bit), so each run
    is compared with the series' run of its seed over the same strain 0–20 (its first 100 records,
    read from the series' sweep folder, finished or interrupted past strain 20). Per run: the
    closure-free C_I (rate regression with the run's own a4) and the IBOF trajectory fit over
    strain 0–20, both with the ξ the runs record; the RMS change of a2(t); the median CG
    iterations per solve; the contacts' smallest gap over α. Per estimator: the paired change
    (pyfold.ensemble.paired_difference) in units of the reference's ensemble error
    (pyfold.ensemble.ensemble_mean over the 4 seeds): admissible at ≤ 0.5, the rule of
    ``numerics.preset = "study"`` (ADMISSIBLE_FRACTION of ci_stokes_settings.py).

Command
    .venv/bin/python studies/speed_accuracy/time_step_beta10.py [--analyse-only] [--series-dir DIR]
    (needs the series' Stokes runs at φβ = 0.5 at Δt = α/(γ̇L) past strain 20, finished or interrupted:
    they are the runs of ci_fluid_series.py --beta 10 --calibrated before its step was doubled; a run
    still being written is locked by HDF5, so analyse after it stops, or with HDF5_USE_FILE_LOCKING=FALSE)

Cost (2 cores)
    The 4 runs at Δt = 0.02: 360–383 CPU-s each (two at a time, the machine shared with two
    low-priority simulations), about 13 min wall; the reference runs cost the series 700–708
    CPU-s each to strain 20. The analysis about a CPU-minute.

Outputs (under out/speed_accuracy/time_step_beta10/, ``--out``)
    sweep/                  the runs (pyfold sweep folder)
    time_step_beta10.md     per seed and in all: C_I of both estimators at both steps, the paired change
    time_step_beta10.nc     the same per seed
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import xarray as xr

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "studies" / "speed_accuracy"))
sys.path.insert(0, str(ROOT / "studies" / "interaction_coefficient"))
import ci_fluid_series as series  # noqa: E402
from ci_stokes_settings import ADMISSIBLE_FRACTION  # noqa: E402

SERIES = "ci_fluid_series_beta10_calibrated"
STRAIN = 20.0
POINT = {"n_l3": 6.4, "model": "stokes"}
#: The series' arguments at its first setting (the step α/(γ̇L), a solve every 4th step extrapolated
#: linearly, the 72³ grid with its calibrated radius), whatever its sweep file now sets: the reference runs
SERIES_AT_FIRST = {"dt": None, "solve_every": None, "reuse": None, "cells_per_diameter": None,
                   "max_grid_points": 400000, "fibre_radius_scale": 1.212}


def series_runs(series_dir: Path, seeds) -> dict[int, Path]:
    """The series' run file of ``POINT`` per seed (run.h5, or run.h5.partial of an interrupted run)."""
    from pyfold.sweep.plan import plan
    from pyfold.sweep.study import load_form

    spec = load_form(ROOT / "studies" / "sweeps", SERIES, False, seeds=tuple(seeds), arguments=SERIES_AT_FIRST)
    found = {}
    for run in plan(spec):
        if all(run.point.get(k) == v for k, v in POINT.items()):
            folder = series_dir / "runs" / run.run_id
            for name in ("run.h5", "run.h5.partial"):
                if (folder / name).exists():
                    found[run.seed] = folder / name
                    break
    return found


def measure(path: Path) -> dict:
    """C_I of both estimators over strain [0, STRAIN] of the run ``path``, its a2 there, initial axes,
    median CG iterations and smallest gap over α."""
    from pyfold import run_checks
    from pyfold.ci_estimators import ci_rate_regression
    from pyfold.fast_fit import fit_ci_rk4
    from pyfold.run_results import open_run

    ds = open_run(path)
    try:
        t, a2, a4 = ds["time"].values, ds["a2"].values, ds["a4"].values
        xi = run_checks.shape_factor_of(ds)
        keep = t <= STRAIN + 1e-9
        if t[keep][-1] < STRAIN - 1e-9:
            raise SystemExit(f"{path}: reaches strain {t[-1]:g}, not {STRAIN:g}")
        iterations = ds["stokes_iterations"].values[keep][1:]
        # records with a solve only: with a solve every k steps some records hold none (0 iterations)
        out = {"p0": ds["initial_p"].values, "a2": a2[keep], "xi": xi,
               "iterations": float(np.median(iterations[iterations > 0])),
               "gap": float(ds["min_gap_over_alpha"].values[keep].min())}
    finally:
        ds.close()
    L = run_checks.velocity_gradient_of(path)
    reg = ci_rate_regression(t[keep], a2[keep], a4[keep], L, xi)
    fit = fit_ci_rk4("ibof", t[keep], a2[keep], L, xi)
    out["closure_free"], out["ibof_trajectory"] = (reg.ci, reg.stderr), (fit.ci, fit.stderr)
    return out


def main() -> None:
    from pyfold.ensemble import ensemble_mean, paired_difference
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--out", type=Path, default=Path("out/speed_accuracy/time_step_beta10"))
    ap.add_argument("--series-dir", type=Path,
                    default=Path("out/interaction_coefficient/fluid_series_beta10_calibrated/sweep"),
                    help="the calibrated β = 10 series' sweep folder (the reference runs)")
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    spec = sweep_study.load_form(ROOT / "studies" / "sweeps", "time_step_beta10", False)
    reference = series_runs(args.series_dir, spec.seeds)
    if set(reference) != set(spec.seeds):
        raise SystemExit(f"the series has no run of seeds {sorted(set(spec.seeds) - set(reference))} at {POINT} "
                         f"in {args.series_dir}; run ci_fluid_series.py --beta 10 --calibrated past strain {STRAIN:g}")
    done = sweep_study.run_sweep(spec, args.sweep_dir or args.out / "sweep", args.executor,
                                 analyse_only=args.analyse_only)
    runs = {seed: path for (_point, seed), path in done.items()}
    seeds = [s for s in spec.seeds if s in runs]
    if len(seeds) < 2:
        raise SystemExit("need 2 finished runs at least")
    ref = {s: measure(reference[s]) for s in seeds}
    new = {s: measure(runs[s]) for s in seeds}
    for s in seeds:
        if not np.array_equal(ref[s]["p0"], new[s]["p0"]):
            raise SystemExit(f"seed {s}: the initial axes differ from the series' run; the runs are not paired")
    dt = float(spec.points[0]["dt"])
    lines = [f"# Δt = {dt:g} against the series' Δt = α/(γ̇L) (β = 10, φβ = 0.5, calibrated radius, strain 0–{STRAIN:g})",
             "", "| seed | estimator | C_I reference | C_I at Δt | change | a2 RMS change | CG it./solve ref → new | "
             "min gap / α |", "|---|---|---|---|---|---|---|---|"]
    data = {}
    for est in ("closure_free", "ibof_trajectory"):
        r = [ref[s][est] for s in seeds]
        n = [new[s][est] for s in seeds]
        data[est] = (r, n)
        for s, a, b in zip(seeds, r, n):
            rms = float(np.sqrt(np.mean((ref[s]["a2"] - new[s]["a2"]) ** 2)))
            lines.append(f"| {s} | {est} | {a[0]:+.3e} | {b[0]:+.3e} | {b[0] - a[0]:+.2e} | {rms:.4f} | "
                         f"{ref[s]['iterations']:.0f} → {new[s]['iterations']:.0f} | {new[s]['gap']:.4f} |")
    lines += ["", "| estimator | reference ± stat. | at Δt ± stat. | paired change ± s.e. | in stat. errors | admissible |",
              "|---|---|---|---|---|---|"]
    for est, (r, n) in data.items():
        e_ref = ensemble_mean([v[0] for v in r], [v[1] for v in r])
        e_new = ensemble_mean([v[0] for v in n], [v[1] for v in n])
        d = paired_difference([v[0] for v in n], [v[0] for v in r])
        frac = abs(d.mean) / e_ref.error
        lines.append(f"| {est} | {e_ref.mean:+.2e} ± {e_ref.error:.1e} | {e_new.mean:+.2e} ± {e_new.error:.1e} | "
                     f"{d.mean:+.2e} ± {d.stderr:.1e} | {frac:.2f} ± {d.stderr / e_ref.error:.2f} | "
                     f"{'yes' if frac <= ADMISSIBLE_FRACTION else 'no'} |")
    text = "\n".join(lines) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "time_step_beta10.md").write_text(text, encoding="utf-8")
    ds = xr.Dataset({f"ci_{est}_{which}": ("seed", [v[0] for v in vals], {"units": "1"})
                     for est, (r, n) in data.items() for which, vals in (("reference", r), ("dt", n))},
                    coords={"seed": seeds})
    ds.attrs.update(dt=dt, reference_dt=float(series.scene_of(**POINT, seed=seeds[0], t_end=STRAIN, beta=10.0).dt),
                    strain=STRAIN)
    ds.to_netcdf(args.out / "time_step_beta10.nc", engine="h5netcdf")
    print(text)


if __name__ == "__main__":
    main()
