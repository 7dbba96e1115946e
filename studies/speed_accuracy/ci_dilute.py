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
    [--executor slurm]   (the sweep studies/sweeps/ci_hydrodynamics.toml with form = "dilute")

Cost on 2 cores
    Measured (nice 10, load average 2-4): 331-343 CPU-s per Stokes run (0.22 CPU-s per step,
    42^3, <= 100 CG iterations per solve), 0.3 CPU-s per contacts-only run; 1657 s wall for
    the small form (4 pairs, the single-fibre check and the analysis).

Outputs (out/speed_accuracy/ci_dilute/)
    sweep/ (the runs, pyfold sweep folder), ci_hydrodynamics.{nc,md,png} in the format of
    ci_hydrodynamics.py.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "studies" / "interaction_coefficient"))

import ci_hydrodynamics as ch  # noqa: E402

# Parameters
DILUTE = ch.DILUTE
OUT = ROOT / "out" / "speed_accuracy" / "ci_dilute"


def sweep_spec(seeds=None):
    """The dilute form of ci_hydrodynamics' sweep, narrowed to ``seeds`` when given."""
    from pyfold.sweep.study import load_form

    return load_form(ch.SWEEPS, "ci_hydrodynamics", False, seeds=tuple(seeds) if seeds else None,
                     arguments={"form": "dilute"})


def run(out: Path, seeds=None, simulate: bool = True, executor: str = "local", sweep_dir: Path | None = None) -> Path:
    """Simulate (what is not finished, unless ``simulate`` is False) and analyse as
    ci_hydrodynamics does; returns the .nc path."""
    import dataclasses

    from pyfold.sweep import study as sweep_study

    spec = sweep_spec(seeds)
    root = sweep_dir or out / "sweep"
    done = sweep_study.run_sweep(spec, root, executor, None, analyse_only=not simulate)
    study = dataclasses.replace(DILUTE, seeds=tuple(spec.seeds))
    nc = ch.analyse_and_write(study, {(model, seed): p for ((model,), seed), p in done.items()}, out, root)
    import xarray as xr

    with xr.open_dataset(nc, engine="h5netcdf") as ds:
        ds.load()
    ds.attrs["question"] = "C_I with Stokes hydrodynamics + contacts vs contacts only, dilute scene, same seeds"
    ds.to_netcdf(nc, engine="h5netcdf")
    return nc


def main() -> None:
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+")
    ap.add_argument("--out", type=Path, default=OUT)
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    t0 = time.perf_counter()
    run(args.out, args.seeds, simulate=not args.analyse_only, executor=args.executor, sweep_dir=args.sweep_dir)
    print(f"written: {args.out} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
