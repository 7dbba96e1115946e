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
    96³ (1.100) and 120³ (1.091): studies/sweeps/ci_resolution_beta10_calibrated.toml, which also runs
    96³ with a solve every 4th step (linear) as the control of the solve interval on the finer grid
    (solve_reuse.py measured it on 72³). A seed fixes the initial
    state on both grids (checked: the initial axes are equal bit for bit), so the change is
    paired. Per run, as studies/speed_accuracy/time_step_beta10.py measures them: the closure-free
    C_I (rate regression with the run's own a4) and the IBOF trajectory fit over strain 0–20,
    both with the recorded ξ (Zhang's: the calibration's target on both grids). Per estimator:
    the paired change 72³ − 96³ (pyfold.ensemble.paired_difference) in units of the 72³ ensemble
    error. With three grids: the observed order from the three ensemble means
    (ci_resolution.observed_order) and a Richardson limit per seed from the two finest grids
    (order 1 assumed where none is observed: with these grids the largest extrapolation); the
    bias of the series' grid (SERIES_CELLS, 96³) against that limit, |mean| ⊕ its s.e., is the
    resolution error the series carries.

    ``--shells apart`` (studies/sweeps/ci_resolution_beta10_apart.toml): the same three grids with the
    shells the calibrated radius adds kept the security zone α apart (numerics.stokes.fibre_shells =
    "apart"; on 72³, s = 1.212, two fibres nearer than 2 (s − 1) R = 0.42 R otherwise overlap in the
    solve and move as one body). Its carried grid is the series' 96³ too (SHELLS_SERIES_CELLS: the grid
    of ci_fluid_series.py --beta 10 --calibrated --shells apart); the preset's stored rows are the
    overlapping shells', so this form checks none of them.

Command
    .venv/bin/python studies/interaction_coefficient/ci_resolution_beta10.py [--shells apart] [--analyse-only]

Cost (2 cores)
    The table gives the CPU time per run of each grid (72³ about 85 CPU-s, 96³ 185, 120³ 370 at a
    solve every 16th step; 96³ every 4th step about 730); the whole sweep about 1.5 CPU-hours. The
    analysis about a CPU-minute.

Outputs (under out/interaction_coefficient/resolution_beta10[_apart]/, ``--out``)
    sweep/                      the runs (pyfold sweep folder)
    ci_resolution_beta10.md     per grid and estimator: C_I ± stat., the paired change, CPU time; the
                                solve-interval control
    ci_resolution_beta10.nc     C_I per grid and seed
    ci_resolution_beta10.json   the resolution error of the series' grid's C_I (SERIES_CELLS) per estimator
                                (coarse_bias and its s.e.) and the change its solve interval makes on that
                                grid (solve_interval), which ci_fluid_series.py --beta 10 --calibrated reads
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
sys.path.insert(0, str(ROOT / "studies" / "interaction_coefficient"))
import ci_fluid_series as series  # noqa: E402
from ci_resolution import ASSUMED_ORDER, observed_order  # noqa: E402
from time_step_beta10 import measure  # noqa: E402

#: The sweep of each rule for the shells of the calibrated radius (numerics.stokes.fibre_shells)
SWEEPS = {"overlap": "ci_resolution_beta10_calibrated", "apart": "ci_resolution_beta10_apart"}
#: The calibrated series' solves (ci_fluid_series_beta10_calibrated.toml); a grid's runs with other solves
#: are the control of that interval on that grid
SERIES_SOLVES = series.solve_label(16, "jeffery")
#: The calibrated series' grid in voxels per diameter (96³): the grid whose bias the summary carries
SERIES_CELLS = 4
#: The grid whose bias the summary carries for each rule (the grid of that rule's series: 96³ for both;
#: 72³ fails the rule for the trajectory fit even with the shells apart)
SHELLS_SERIES_CELLS = {"overlap": SERIES_CELLS, "apart": SERIES_CELLS}
ESTIMATORS = ("closure_free", "ibof_trajectory")


def _evidence_lines(runs: dict, ens: dict, seeds: list[int], cpds: list[int], fine: int) -> list[str]:
    """The grids' changes as the preset holds them (pyfold.scene.study_preset.RESOLUTION), checked
    against its copy."""
    from pyfold.ensemble import paired_difference
    from pyfold.scene.study_preset import GridMeasured, evidence_check_lines, resolution_check

    cpu = {c: np.mean([runs[c, s]["cpu_s"] for s in seeds]) for c in cpds}
    rows = []
    for c in cpds:
        ch = {}
        for est in ESTIMATORS:
            d = paired_difference([runs[c, s][est][0] for s in seeds], [runs[fine, s][est][0] for s in seeds])
            ch[est] = (0.0, 0.0) if c == fine else (round(abs(d.mean) / ens[c][est].error, 2),
                                                     round(d.stderr / ens[c][est].error, 2))
        rows.append(GridMeasured(c, "", runs[c, seeds[0]]["scale"], closure_free=ch["closure_free"][0],
                                 closure_free_stderr=ch["closure_free"][1], trajectory=ch["ibof_trajectory"][0],
                                 trajectory_stderr=ch["ibof_trajectory"][1],
                                 cpu_ratio=round(cpu[c] / cpu[cpds[0]], 2)))
    return evidence_check_lines("RESOLUTION", *resolution_check(10.0, rows), "the changes agree with the stored rows")


def _control_evidence_lines(interval: dict | None) -> list[str]:
    """The control on the series' grid (``interval``: the summary's ``solve_interval``) against its
    row in pyfold.scene.study_preset.BETA_EVIDENCE (the series' solves measured on that grid), in
    the control's statistical errors."""
    from pyfold.scene.study_preset import BETA_EVIDENCE, Measured, compare_changes, evidence_check_lines

    if not interval:
        return []
    ev = BETA_EVIDENCE[("semi-dilute", 10.0)]
    stored = next(m for m in ev.settings if m.measured_on and m.stokes.get("cells_per_diameter") == SERIES_CELLS)
    new = {est: (round(abs(v["change"]) / v["error"], 2), round(v["stderr"] / v["error"], 2))
           for est, v in ((est, interval[est]) for est in ESTIMATORS)}
    recomputed = Measured(name=stored.name, stokes=stored.stokes, dt_factor=stored.dt_factor,
                          closure_free=new["closure_free"][0], closure_free_stderr=new["closure_free"][1],
                          trajectory=new["ibof_trajectory"][0], trajectory_stderr=new["ibof_trajectory"][1],
                          cpu_ratio=stored.cpu_ratio)
    return evidence_check_lines("BETA_EVIDENCE", *compare_changes(stored.name, stored, recomputed),
                                f"{stored.name}: the changes agree with the stored row")


def main() -> None:
    from pyfold.ensemble import ensemble_mean, paired_difference
    from pyfold.sweep import store as sweep_store
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--shells", choices=sorted(SWEEPS), default="overlap",
                    help="numerics.stokes.fibre_shells of the runs: its sweep (default: overlap, the series')")
    ap.add_argument("--out", type=Path, default=None,
                    help="output folder (out/interaction_coefficient/resolution_beta10[_apart])")
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    args.out = args.out or Path("out/interaction_coefficient/resolution_beta10"
                                + ("" if args.shells == "overlap" else f"_{args.shells}"))
    series_cells = SHELLS_SERIES_CELLS[args.shells]
    spec = sweep_study.load_form(ROOT / "studies" / "sweeps", SWEEPS[args.shells], False)
    done = sweep_study.run_sweep(spec, args.sweep_dir or args.out / "sweep", args.executor,
                                 analyse_only=args.analyse_only)
    runs: dict[tuple[int, int], dict] = {}  # the series' solves on each grid: (cells per diameter, seed)
    controls: dict[tuple[int, str, int], dict] = {}  # other solves: (cells per diameter, setting, seed)
    grids: dict[int, str] = {}
    for (values, seed), path in done.items():
        point = dict(zip(spec.axes, values))
        c = int(point["cells_per_diameter"])
        m = measure(path)
        m["cpu_s"] = sweep_store.cpu_seconds(path.parent)
        m["scale"] = float(point["fibre_radius_scale"])
        solves = {**spec.arguments, **point}  # a sweep may give the solves to every point at once
        setting = series.solve_label(solves["solve_every"], solves["reuse"])
        if setting == SERIES_SOLVES:
            runs[c, seed] = m
        else:
            controls[c, setting, seed] = m
        grids[c] = "x".join(map(str, series.grid_of(path)))
    cpds = sorted({c for c, _s in runs})
    seeds = [s for s in spec.seeds if all((c, s) in runs for c in cpds)]
    if len(seeds) < 2:  # a grid still running is left out, so that the seeds are paired on every grid kept
        cpds = [c for c in cpds if sum((c, s) in runs for s in spec.seeds) >= len(spec.seeds)] or cpds
        seeds = [s for s in spec.seeds if all((c, s) in runs for c in cpds)]
    if len(cpds) < 2 or len(seeds) < 2:
        raise SystemExit("need 2 grids with 2 seeds finished on each at least")
    coarse, fine = cpds[0], cpds[-1]
    for s in seeds:
        for c in cpds[1:]:
            if not np.array_equal(runs[coarse, s]["p0"], runs[c, s]["p0"]):
                raise SystemExit(f"seed {s}: the initial axes differ between the grids; the runs are not paired")
    lines = [f"# Resolution of the calibrated β = 10 C_I (φβ = 0.5, strain 0–20, seeds {seeds}, "
             f"shells: {args.shells})", "",
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
    h = {c: 1.0 / c for c in cpds}  # voxel size over the fibre diameter (cells_per_diameter exact here)
    lines += ["", "| estimator | grid | change against the finest, paired ± s.e. | in stat. errors |", "|---|---|---|---|"]
    for est in ESTIMATORS:
        for c in cpds[:-1]:
            d = paired_difference([runs[c, s][est][0] for s in seeds], [runs[fine, s][est][0] for s in seeds])
            lines.append(f"| {est} | {grids[c]} | {d.mean:+.2e} ± {d.stderr:.1e} (p {d.p:.2g}) | "
                         f"{abs(d.mean) / ens[c][est].error:.2f} |")
    if args.shells == "overlap":  # the preset's rows (pyfold.scene.study_preset.RESOLUTION) are these runs'
        lines += _evidence_lines(runs, ens, seeds, cpds, fine)
    lines += ["", "## Order and Richardson extrapolation", ""]
    summary = {"grids": {str(c): grids[c] for c in cpds}, "seeds": seeds, "strain": 20.0, "shells": args.shells}
    for est in ESTIMATORS:
        means = [ens[c][est].mean for c in cpds]
        p = observed_order(means[-3:], [h[c] for c in cpds[-3:]]) if len(cpds) >= 3 else math.nan
        p_used = p if math.isfinite(p) else ASSUMED_ORDER
        mid = cpds[-2]
        r = (h[mid] / h[fine]) ** p_used
        v = {c: np.array([runs[c, s][est][0] for s in seeds]) for c in cpds}
        c_inf = v[fine] + (v[fine] - v[mid]) / (r - 1.0)  # per seed: the grids of a seed share its initial state
        e_inf = ensemble_mean(c_inf)
        carried = series_cells if series_cells in cpds[:-1] else coarse
        bias = paired_difference(v[carried], c_inf)
        summary[est] = {"coarse_cells_per_diameter": carried, "coarse": float(v[carried].mean()),
                        "richardson": e_inf.mean, "richardson_err": e_inf.error, "coarse_bias": bias.mean,
                        "coarse_bias_stderr": bias.stderr, "p": bias.p, "order": p_used,
                        "order_observed": bool(math.isfinite(p))}
        if math.isfinite(p):
            order = f"observed order {p:.2f}"
        elif len(cpds) < 3:
            order = f"two grids, order {ASSUMED_ORDER:g} assumed"
        else:
            order = f"no observed order (the differences change sign or no order in (0.1, 8) fits), " \
                    f"order {ASSUMED_ORDER:g} assumed"
        others = "".join(f"; C({c}) − C∞ = {b.mean:+.2e} ± {b.stderr:.1e}"
                         for c, b in ((c, paired_difference(v[c], c_inf)) for c in cpds[:-1] if c != carried))
        lines.append(f"* {est}: {order}; Richardson C∞ = {e_inf.mean:+.2e} ± {e_inf.error:.1e} (from the two finest "
                     f"grids, per seed); the series' {carried}-voxel value's bias C({carried}) − C∞ = {bias.mean:+.2e} ± "
                     f"{bias.stderr:.1e} (p {bias.p:.2g}){others}; the series carries |bias| ⊕ s.e. = "
                     f"{math.hypot(bias.mean, bias.stderr):.1e}")
    control_lines = []
    for c, setting in sorted({(c, st) for c, st, _s in controls}):
        have = [s for s in spec.seeds if (c, setting, s) in controls and (c, s) in runs]
        if len(have) < 2:
            continue
        if c == series_cells:  # the series' solve interval against this setting on its own grid
            summary["solve_interval"] = {"cells_per_diameter": c, "series": SERIES_SOLVES, "against": setting,
                                         "seeds": have}
        for est in ESTIMATORS:
            d = paired_difference([runs[c, s][est][0] for s in have], [controls[c, setting, s][est][0] for s in have])
            e = ensemble_mean([controls[c, setting, s][est][0] for s in have])
            if c == series_cells:
                summary["solve_interval"][est] = {"change": d.mean, "stderr": d.stderr, "error": e.error}
            control_lines.append(f"| {grids[c]} | {est} | {setting} | {e.mean:+.3e} ± {e.error:.1e} | "
                                 f"{d.mean:+.2e} ± {d.stderr:.1e} | {abs(d.mean) / e.error:.2f} | {len(have)} | "
                                 f"{np.mean([controls[c, setting, s]['cpu_s'] for s in have]):.0f} |")
    if control_lines:
        lines += ["", f"## The series' solves ({SERIES_SOLVES}) against another setting on the same grid", "",
                  "| grid | estimator | other setting | its C_I | series − other, paired ± s.e. | in stat. errors | "
                  "seeds | its CPU-s per run |", "|---|---|---|---|---|---|---|---|"] + control_lines
        lines += _control_evidence_lines(summary.get("solve_interval"))
    text = "\n".join(lines) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ci_resolution_beta10.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    (args.out / "ci_resolution_beta10.md").write_text(text, encoding="utf-8")
    ds = xr.Dataset({f"ci_{est}": (("cells_per_diameter", "seed"), [[runs[c, s][est][0] for s in seeds] for c in cpds],
                                   {"units": "1"}) for est in ESTIMATORS},
                    coords={"cells_per_diameter": cpds, "seed": seeds})
    ds.to_netcdf(args.out / "ci_resolution_beta10.nc", engine="h5netcdf")
    print(text)


if __name__ == "__main__":
    main()
