"""What hydrodynamic interactions add to C_I in a DILUTE fibre suspension (n L^3 < 1).

Question
    studies/interaction_coefficient/ci_hydrodynamics.py measured, in a semi-dilute scene
    (98 fibres, beta = 5, n L^3 = 4.98), that coupling the fibres through the Stokes solver
    changes the closure-free C_I by 8.6e-4 +- 1.1e-4 (paired over 4 seeds). Does neglecting
    hydrodynamics (``hydrodynamics = "jeffery"``, contacts only) change C_I by more than its
    statistical error in the dilute regime too? The answer grounds the choice
    ``hydrodynamics = "auto"`` makes (pyfold/scene/hydrodynamics_evidence.py).

    Same scene family, numerics, estimators and statistics as ci_hydrodynamics.py (its
    functions are reused): pyfold.scene.sheared_fibres at beta = 5, n L^3 = 0.9 requested
    (18 fibres in the 2.7 L cell, n L^3 = 0.914), alpha = 0.1 d, dt = alpha/(gamma_dot L),
    strain 30, seeds 1-4 paired (the two models of a seed start from the same placement);
    Stokes on the same 42^3 grid (3.11 voxels per diameter), kappa = 1e3, CG tolerance 1e-4,
    AB2; C_I by rate regression (own a4: closure-free; IBOF a4), paired t-test over seeds.

Command
    nice -n 10 .venv/bin/python studies/speed_accuracy/ci_dilute.py [--seeds 1 2 3 4] [--analyse-only]
    (--large: 8 seeds, strain 50.)

Cost on 2 cores
    Measured (nice 10, load average 2-4): 331-343 CPU-s per Stokes run (0.22 CPU-s per step,
    42^3, <= 100 CG iterations per solve), 0.3 CPU-s per contacts-only run; 1657 s wall for
    the small form (4 pairs, the single-fibre check and the analysis).

Outputs (out/speed_accuracy/ci_dilute/)
    runs/ (scenes, run files, cost), ci_hydrodynamics.{nc,md,png} in the format of
    ci_hydrodynamics.py.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "studies" / "interaction_coefficient"))

import ci_hydrodynamics as ch  # noqa: E402

# Parameters
DILUTE = dataclasses.replace(ch.SMALL, n_l3=0.9)
DILUTE_LARGE = dataclasses.replace(DILUTE, t_end=50.0, seeds=tuple(range(1, 9)))
OUT = ROOT / "out" / "speed_accuracy" / "ci_dilute"


def run(study: ch.Study, out: Path, simulate: bool = True) -> Path:
    """Simulate (unless finished) and analyse as ci_hydrodynamics.main does; returns the .nc path."""
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    if simulate:
        ch.simulate(study, runs, 1)
    rows = {}
    for seed in study.seeds:
        for model in ch.MODELS:
            _, h5, cost = ch.run_paths(runs, model, seed)
            if ch.reusable(h5, study.scene(model, seed).toml):
                rows[model, seed] = ch.analyse_run(h5, cost)
    seeds = [s for s in study.seeds if all((m, s) in rows for m in ch.MODELS)]
    if len(seeds) < 2:
        raise SystemExit(f"fewer than two finished pairs of runs under {runs}")
    grid = rows["stokes", seeds[0]]["grid"]
    side = study.scene("stokes", seeds[0]).side
    check = ch.single_fibre_check(study, grid, side, out / "single_fibre_check.nc")
    be = float(check["beta_e_measured"].sel(shape="fibre").values[0])
    xi_measured = (be * be - 1.0) / (be * be + 1.0)
    for seed in seeds:
        r = rows["stokes", seed]
        path = ch.run_paths(runs, "stokes", seed)[1]
        r["reg_xi_measured"] = ch.ci_rate_regression(r["t"], r["a2"], ch.open_run(path)["a4"].values,
                                                     ch.run_checks.velocity_gradient_of(path), xi_measured)
    ds = ch._dataset(study, rows, seeds, check, xi_measured)
    ds.attrs["question"] = "C_I with Stokes hydrodynamics + contacts vs contacts only, dilute scene, same seeds"
    nc = out / "ci_hydrodynamics.nc"
    ds.to_netcdf(nc, engine="h5netcdf")
    ch._figure(ds, out / "ci_hydrodynamics.png")
    report = ch._report(ds)
    (out / "ci_hydrodynamics.md").write_text(report)
    print(report)
    return nc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true")
    ap.add_argument("--analyse-only", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    study = DILUTE_LARGE if args.large else DILUTE
    if args.seeds:
        study = dataclasses.replace(study, seeds=tuple(args.seeds))
    t0 = time.perf_counter()
    run(study, args.out, simulate=not args.analyse_only)
    print(f"written: {args.out} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
