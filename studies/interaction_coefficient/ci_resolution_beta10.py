"""Is the calibrated β = 10 C_I converged in resolution at 3 voxels per diameter?

Question
    The calibrated β = 10 series (ci_fluid_series.py --beta 10 --calibrated) runs on 72³, 3 voxels
    per fibre diameter, with the fibres voxelised at the radius that makes one of them turn like
    the converged cylinder. At β = 5 that calibration took the grid dependence out of the
    trajectory C_I but not out of the closure-free one (docs/fluid_coupled_ci.md, "A hydrodynamic
    radius calibrated to the grid"). Does the β = 10 C_I change when the grid is refined to 4
    voxels per diameter (96³, calibrated there), and by how much: the resolution error the
    series' table carries?

Method
    The series' Stokes scene at φβ = 0.5 (n L³ = 6.4, 88 fibres, cell 2.4 L, Zhang's β_e = 7.61
    recorded, κ = 10³, CG tolerance 10⁻³, Δt = 0.02, a solve every 16th step with the Jeffery
    estimate between solves, AB2), seeds 1–4, strain 20 (the transient from the isotropic start,
    where the per-strain information on C_I is largest), on 72³ (fibre radius scale 1.212) and
    96³ (1.100): studies/sweeps/ci_resolution_beta10_calibrated.toml. A seed fixes the initial
    state on both grids (checked: the initial axes are equal bit for bit), so the change is
    paired. Per run, as studies/speed_accuracy/time_step_beta10.py measures them: the closure-free
    C_I (rate regression with the run's own a4) and the IBOF trajectory fit over strain 0–20,
    both with the recorded ξ (Zhang's: the calibration's target on both grids). Per estimator:
    the paired change 72³ − 96³ (pyfold.ensemble.paired_difference) in units of the 72³ ensemble
    error. With two grids there is no observed order: the change itself, |mean| ⊕ its s.e., is
    the resolution error the series carries (a first-order Richardson extrapolation from these
    two grids would put the limit 3 times the change beyond 96³, the table says so).

Command
    .venv/bin/python studies/interaction_coefficient/ci_resolution_beta10.py [--analyse-only]

Cost (2 cores)
    The table gives the CPU time per run of each grid (72³ about 85 CPU-s, 96³ about 2.5 times
    that); the whole sweep about 0.4 CPU-hour. The analysis about a CPU-minute.

Outputs (under out/interaction_coefficient/resolution_beta10/, ``--out``)
    sweep/                      the runs (pyfold sweep folder)
    ci_resolution_beta10.md     per grid and estimator: C_I ± stat., the paired change, CPU time
    ci_resolution_beta10.nc     C_I per grid and seed
    ci_resolution_beta10.json   the resolution error of the 72³ C_I per estimator (coarse_bias and
                                its s.e.), which ci_fluid_series.py --beta 10 --calibrated reads
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import xarray as xr

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "studies" / "speed_accuracy"))
from time_step_beta10 import measure  # noqa: E402

SWEEP = "ci_resolution_beta10_calibrated"
ESTIMATORS = ("closure_free", "ibof_trajectory")


def main() -> None:
    from pyfold.ensemble import ensemble_mean, paired_difference
    from pyfold.sweep import store as sweep_store
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--out", type=Path, default=Path("out/interaction_coefficient/resolution_beta10"))
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    spec = sweep_study.load_form(ROOT / "studies" / "sweeps", SWEEP, False)
    done = sweep_study.run_sweep(spec, args.sweep_dir or args.out / "sweep", args.executor,
                                 analyse_only=args.analyse_only)
    runs: dict[tuple[int, int], dict] = {}
    grids: dict[int, str] = {}
    for (values, seed), path in done.items():
        point = dict(zip(spec.axes, values))
        c = int(point["cells_per_diameter"])
        m = measure(path)
        m["cpu_s"] = sweep_store.cpu_seconds(path.parent)
        m["scale"] = float(point["fibre_radius_scale"])
        runs[c, seed] = m
        with xr.open_dataset(path, group="setup/resolved", engine="h5netcdf") as ds:
            grids[c] = "x".join(str(int(n)) for n in np.atleast_1d(ds["stokes_grid"].values))
    cpds = sorted({c for c, _s in runs})
    if len(cpds) < 2:
        raise SystemExit("need finished runs on both grids")
    coarse, fine = cpds[0], cpds[-1]
    seeds = [s for s in spec.seeds if (coarse, s) in runs and (fine, s) in runs]
    if len(seeds) < 2:
        raise SystemExit("need 2 seeds finished on both grids at least")
    for s in seeds:
        if not np.array_equal(runs[coarse, s]["p0"], runs[fine, s]["p0"]):
            raise SystemExit(f"seed {s}: the initial axes differ between the grids; the runs are not paired")
    lines = [f"# Resolution of the calibrated β = 10 C_I (φβ = 0.5, strain 0–20, seeds {seeds})", "",
             "| voxels per diameter | grid | radius scale | CPU-s per run | CG it./solve | closure-free C_I | "
             "IBOF trajectory C_I |", "|---|---|---|---|---|---|---|"]
    ens = {}
    for c in cpds:
        have = [s for s in seeds if (c, s) in runs]
        e = {est: ensemble_mean([runs[c, s][est][0] for s in have], [runs[c, s][est][1] for s in have])
             for est in ESTIMATORS}
        ens[c] = e
        lines.append(f"| {c} | {grids[c]} | {runs[c, have[0]]['scale']:.3f} | "
                     f"{np.mean([runs[c, s]['cpu_s'] for s in have]):.0f} | "
                     f"{np.median([runs[c, s]['iterations'] for s in have]):.0f} | "
                     + " | ".join(f"{e[est].mean:+.3e} ± {e[est].error:.1e}" for est in ESTIMATORS) + " |")
    lines += ["", f"| estimator | {coarse} − {fine} voxels, paired ± s.e. | in stat. errors of the {coarse}-voxel C_I | "
              "p | resolution error carried (|change| ⊕ s.e.) |", "|---|---|---|---|---|"]
    summary = {"grids": {str(c): grids[c] for c in cpds}, "seeds": seeds, "strain": 20.0}
    for est in ESTIMATORS:
        d = paired_difference([runs[coarse, s][est][0] for s in seeds], [runs[fine, s][est][0] for s in seeds])
        err = math.hypot(d.mean, d.stderr)
        summary[est] = {"coarse_bias": d.mean, "coarse_bias_stderr": d.stderr, "p": d.p,
                        "coarse": ens[coarse][est].mean, "fine": ens[fine][est].mean}
        lines.append(f"| {est} | {d.mean:+.2e} ± {d.stderr:.1e} | {abs(d.mean) / ens[coarse][est].error:.2f} | "
                     f"{d.p:.2g} | {err:.1e} |")
    lines += ["", "Two grids give no observed order: the 72³ C_I's resolution error is taken as the measured change "
              "to 96³ (|mean| and its s.e. in quadrature). Were the error first order in h, the limit would lie 3 "
              "times that change beyond the 96³ value."]
    text = "\n".join(lines) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ci_resolution_beta10.md").write_text(text, encoding="utf-8")
    (args.out / "ci_resolution_beta10.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    ds = xr.Dataset({f"ci_{est}": (("cells_per_diameter", "seed"), [[runs[c, s][est][0] for s in seeds] for c in cpds],
                                   {"units": "1"}) for est in ESTIMATORS},
                    coords={"cells_per_diameter": cpds, "seed": seeds})
    ds.to_netcdf(args.out / "ci_resolution_beta10.nc", engine="h5netcdf")
    print(text)


if __name__ == "__main__":
    main()
