"""How the fluid-coupled C_I depends on the Stokes grid: three resolutions, paired over seeds.

Question
    The fluid-coupled C_I of the study scenes is computed at 3 voxels per fibre diameter
    (where one β = 5 spheroid's Jeffery period is 16 % short). Does C_I change when the grid
    is refined to 4 and 5 voxels per diameter, by how much against its statistical error,
    with what observed order, and what does a Richardson extrapolation give? Does
    subtracting the Jeffery term with the rotation rate the solver gives one fibre on each
    grid (its measured β_e) instead of Cox's β_e take out the grid dependence? And
    (``--calibrated``) does voxelising each grid's fibres at the radius that makes one of them
    turn like the converged cylinder (numerics.stokes.fibre_radius_scale) take it out?

Method
    The semi-dilute scene of ci_fluid_series.py (β = 5, n L³ = 4.98, 98 fibres, cell 2.7 L,
    α = 0.1 d, Δt = 0.02, AB2, κ = 10³, CG tolerance 10⁻³, a solve every 4th step) at
    ``cells_per_diameter`` 3 / 4 / 5 (grids 42³ / 54³ / 70³: 3.11 / 4.0 / 5.19 voxels per
    diameter), strain 20 (two thirds of a Jeffery period, the transient from the isotropic
    start where C_I is best determined per strain), 4 seeds: a seed fixes the initial state,
    so each grid is compared with the finest seed by seed (pyfold.ensemble.paired_difference).
    Per run: the closure-free C_I (rate regression over all records with the run's own a4)
    and the IBOF trajectory fit over all records (pyfold.fast_fit.fit_ci_rk4), each once with
    Cox's ξ (what the runs record) and once with the ξ of the grid's fibre (single-fibre
    check of ci_hydrodynamics.py on that grid: orbit period from ω(θ) at 24 orientations).
    Observed order p from the three ensemble means, (C₃ − C₄)/(C₄ − C₅) =
    (h₃ᵖ − h₄ᵖ)/(h₄ᵖ − h₅ᵖ), when the differences are monotone; otherwise (or with two
    grids) p = 1 is assumed (the fictitious domain's surface error is first order in h: the
    largest extrapolation of the plausible orders). Richardson per seed (the grids of a seed
    share its initial state), C∞ = C₅ + (C₅ − C₄)/((h₄/h₅)ᵖ − 1), and the bias of the
    3-voxel value, C₃ − C∞, paired over the seeds: ci_fluid_series.py takes that bias
    (|mean| and its s.e. in quadrature) as the resolution error of its 3-voxel C_I, the
    closure-free one for its rate regressions and the IBOF one for its trajectory fits.
    ``--calibrated``: the same runs (studies/sweeps/ci_resolution_calibrated.toml: same scene,
    grids and seeds, hence the same initial states) with the fibres voxelised at s R, s of each
    grid the one at which the single-fibre check gives Zhang et al. (2011)'s β_e = 4.112, the
    converged cylinder's (docs/jeffery_orbits.md), within CALIBRATION_TOLERANCE; the study
    measures β_e at the sweep file's scales before it runs and stops if one misses. The
    calibrated sweep also runs a 2-voxel grid (27³, 2.8 times cheaper than 42³), to measure
    whether the calibration lets the series go below 3 voxels per diameter; Richardson still
    uses the three finest grids, and the summary the 3-voxel grid's bias.
    ``--calibrate`` finds the scales (:func:`calibrate_scale`: secant on β_e(s) from s = 1, 1.1)
    and prints the sweep file's [[points]].
    ``--calibrated --shells apart`` (ci_resolution_calibrated_apart.toml): the calibrated runs on the
    three finest grids with the added shells kept the security zone apart
    (numerics.stokes.fibre_shells = "apart"): at s = 1.129 (42³) the shells of two fibres at the
    security gap overlap by 0.16 R otherwise, and the pair moves as one body.

Command
    .venv/bin/python studies/interaction_coefficient/ci_resolution.py [--executor slurm] [--seeds 1 2]
    .venv/bin/python studies/interaction_coefficient/ci_resolution.py --calibrated [--shells apart]
    .venv/bin/python studies/interaction_coefficient/ci_resolution.py --calibrate   # the scales only
    (two serial runs at a time; finished runs are re-used; --analyse-only analyses what is there)

Cost (2 cores)
    Measured per run (two serial runs at a time on the shared 2-core machine): 84–88 /
    173–190 / 392–443 CPU-s on the three grids, 0.77 CPU-hour for the 12 runs; the
    single-fibre checks 76 CPU-s; the analysis about 2 CPU-min. --calibrated: 90 / 196 / 461
    CPU-s per run on 42³ / 54³ / 70³ and 32 on the 2-voxel 27³ grid, about 0.95 CPU-hour; --shells apart
    90 / 164 / 404 with 8 seeds, about 1.5 CPU-hours. The CPU time of every run is in the outputs.

Outputs (under out/interaction_coefficient/resolution/ or, with --calibrated,
out/interaction_coefficient/resolution_calibrated[_apart]/ [calibration/: its single-fibre checks]; ``--out``)
    sweep/                  the runs (pyfold sweep folder)
    ci_resolution.nc        per grid and seed: C_I by both estimators, with Cox's and the grid's ξ, CPU s
    ci_resolution.md        per grid: ensemble C_I, paired change against the finest grid, order, Richardson
    ci_resolution.json      per estimator and ξ: C∞, the coarse grid's bias and its s.e. (read by ci_fluid_series.py)
    ci_resolution.png       C_I against voxel size h/d, both ξ, with the Richardson estimate
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from pyfold.scene import registry
from pyfold.scene.sheared_fibres import sheared_fibres

ROOT = Path(__file__).resolve().parents[2]
SWEEPS = ROOT / "studies" / "sweeps"
sys.path.insert(0, str(Path(__file__).resolve().parent))
import ci_fluid_series as series  # noqa: E402  (the scene and numerics of the series)

N_L3 = 5.0
ESTIMATORS = ("closure_free", "ibof_trajectory")
XI = ("cox", "grid")  # the Jeffery term with Cox's beta_e / with the grid fibre's measured beta_e
#: Order assumed when none is observed: the fictitious domain's surface error is first order in h
#: (the smallest plausible order, so the largest extrapolation)
ASSUMED_ORDER = 1.0
#: The grid of the fluid-coupled series (ci_fluid_series.STOKES): its bias is the one the summary
#: (ci_resolution.json) gives, whichever coarser grids the sweep also runs
SERIES_CELLS = int(series.STOKES["cells_per_diameter"])
#: Relative mismatch of β_e at which a calibrated radius is accepted: below the single-fibre
#: check's own quadrature error (~0.3 % on the period at 24 orientations, ci_hydrodynamics.py)
#: doubled, since dβ_e/β_e ≈ dT/T · β_e²/(β_e² − 1) (docs/jeffery_orbits.md)
CALIBRATION_TOLERANCE = 0.006


def scene_of(cells_per_diameter: int, seed: int, t_end: float, fibre_radius_scale: float = 1.0,
             fibre_shells: str | None = None):
    """The sweep's builder: the series' semi-dilute Stokes scene at ``cells_per_diameter``, its
    fibres voxelised with ``fibre_radius_scale`` times their radius (``fibre_shells``:
    numerics.stokes.fibre_shells, None its default)."""
    stokes = {**series.STOKES, "cells_per_diameter": int(cells_per_diameter), "max_grid_points": 1_000_000}
    if fibre_radius_scale != 1.0:  # only then: the scenes (and run ids) of the geometric sweep stay as they were
        stokes["fibre_radius_scale"] = float(fibre_radius_scale)
    if fibre_shells is not None:
        stokes["fibre_shells"] = str(fibre_shells)
    return sheared_fibres(series.BETA, N_L3, seed, t_end, alpha_over_d=series.ALPHA_OVER_D, hydrodynamics="stokes",
                          stokes=stokes, time_scheme="ab2")


def scaled_beta_e(grid: list[int], side: float, scale: float, cache: Path, beta: float = series.BETA) -> float:
    """β_e of one fibre on ``grid`` voxelised at ``scale`` times its radius (the single-fibre check,
    cached as ``cache``/single_fibre_<n>_s<scale>.nc, the calibration's checks)."""
    cache.mkdir(parents=True, exist_ok=True)
    return series.beta_e_on(grid, side, cache / f"single_fibre_{grid[0]}_s{scale:.3f}.nc", beta, scale)


def calibrate_scale(grid: list[int], side: float, target: float, cache: Path, beta: float = series.BETA,
                    tolerance: float = CALIBRATION_TOLERANCE, max_checks: int = 6) -> tuple[float, float, list]:
    """The fibre radius scale s (numerics.stokes.fibre_radius_scale) at which one fibre on ``grid``
    turns like a fibre of β_e = ``target``: secant iteration on the measured β_e(s) (the
    single-fibre check, :func:`ci_fluid_series.beta_e_on`; β_e falls as s grows) from s = 1 and
    1.1, until |β_e(s) − target| ≤ ``tolerance`` · target. Returns (s, β_e(s), [(s, β_e), ...]);
    s is rounded to 3 decimals and measured there, so the returned β_e is that of the scale a
    scene would use. Raises SystemExit naming the grid when ``max_checks`` checks do not reach it."""
    bounds = registry.setting("numerics.stokes.fibre_radius_scale")
    cache.mkdir(parents=True, exist_ok=True)

    def measure(scale: float) -> float:
        return scaled_beta_e(grid, side, scale, cache, beta)

    pts = [(1.0, measure(1.0)), (1.1, measure(1.1))]
    while abs(pts[-1][1] - target) > tolerance * target:
        if len(pts) >= max_checks:
            raise SystemExit(f"calibrate_scale: grid {grid[0]}^3: beta_e {pts[-1][1]:.4f} at s = {pts[-1][0]:.3f} "
                             f"after {len(pts)} checks, target {target:.4f}; checks: {pts}")
        (s0, b0), (s1, b1) = pts[-2], pts[-1]
        if b1 == b0:
            raise SystemExit(f"calibrate_scale: grid {grid[0]}^3: beta_e does not change between s = {s0} and {s1}")
        s_new = round(min(max(s1 + (target - b1) * (s1 - s0) / (b1 - b0), bounds.lo), bounds.hi), 3)
        if any(abs(s_new - s) < 5e-4 for s, _ in pts):
            break
        pts.append((s_new, measure(s_new)))
    best = min(pts, key=lambda q: abs(q[1] - target))
    if abs(best[1] - target) > tolerance * target:  # the iteration stalled at a bound of the scale's range
        raise SystemExit(f"calibrate_scale: grid {grid[0]}^3: no scale in [{bounds.lo:g}, {bounds.hi:g}] gives beta_e {target:.4f}; "
                         f"checks: {pts}")
    return best[0], best[1], pts


def cox_xi(path: Path) -> float:
    """The shape factor the run records (Cox's β_e, what Folgar–Tucker uses by default)."""
    from pyfold import run_checks
    from pyfold.run_results import open_run

    ds = open_run(path)
    try:
        return run_checks.shape_factor_of(ds)
    finally:
        ds.close()


def analyse_run(path: Path, xis: dict[str, float]) -> dict:
    """C_I of one run by both estimators for each xi of ``xis``, and its CPU time."""
    from pyfold import run_checks
    from pyfold.ci_estimators import ci_rate_regression
    from pyfold.fast_fit import fit_ci_rk4
    from pyfold.run_results import open_run

    ds = open_run(path)
    L = run_checks.velocity_gradient_of(path)
    t, a2, a4 = ds["time"].values, ds["a2"].values, ds["a4"].values
    ds.close()
    out = {"cpu_s": series.cpu_of(path)}
    for name, xi in xis.items():
        reg = ci_rate_regression(t, a2, a4, L, xi)
        fit = fit_ci_rk4("ibof", t, a2, L, xi)
        out["closure_free", name] = (reg.ci, reg.stderr)
        out["ibof_trajectory", name] = (fit.ci, fit.stderr)
    return out


def observed_order(c: list[float], h: list[float]) -> float:
    """p with (c0 - c1)/(c1 - c2) = (h0^p - h1^p)/(h1^p - h2^p) (coarse to fine), NaN when the
    differences are not monotone (same sign) or no p in (0.1, 8) fits."""
    from scipy.optimize import brentq

    d01, d12 = c[0] - c[1], c[1] - c[2]
    if d01 == 0.0 or d12 == 0.0 or (d01 > 0) != (d12 > 0):
        return math.nan
    q = d01 / d12

    def f(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - q

    try:
        return float(brentq(f, 0.1, 8.0))
    except ValueError:
        return math.nan


def analyse(done: dict, seeds: tuple[int, ...], out: Path, scales: dict[int, float] | None = None) -> str:
    """Tables, Richardson estimates, NetCDF and figure of the finished runs ``done`` ({(cells per
    diameter, seed): run file}); ``scales``: the fibre radius scale of each grid (default 1)."""
    import xarray as xr

    from pyfold.ensemble import ensemble_mean, paired_difference
    from pyfold.kinematics import aspect_ratio_to_xi

    cpds = sorted({c for c, _ in done})
    have = [s for s in seeds if all((c, s) in done for c in cpds)]
    if len(cpds) < 2 or len(have) < 2:
        raise SystemExit(f"need 2 grids and 2 seeds finished on all of them under {out / 'sweep'}")
    side = scene_of(cpds[0], have[0], 1.0).side
    grids = {c: series.grid_of(done[c, have[0]]) for c in cpds}
    h = {c: side / grids[c][0] / (1.0 / series.BETA) for c in cpds}  # voxel size / diameter
    scales = {c: (scales or {}).get(c, 1.0) for c in cpds}
    beta_e = {c: series.beta_e_on(grids[c], side, out / f"single_fibre_check_{grids[c][0]}.nc",
                                  fibre_radius_scale=scales[c]) for c in cpds}
    rows = {}
    for c in cpds:
        for s in have:
            xis = {"cox": cox_xi(done[c, s]), "grid": float(aspect_ratio_to_xi(beta_e[c]))}
            rows[c, s] = analyse_run(done[c, s], xis)
            print(f"cells_per_diameter {c}, seed {s}: analysed", flush=True)
    fine = cpds[-1]
    calibrated = any(v != 1.0 for v in scales.values())
    lines = ["# Fluid-coupled C_I against the Stokes grid (β = 5, n L³ = 4.98, strain 20"
             + (", fibres voxelised at the calibrated radius)" if calibrated else ")"), "",
             "| cells/d | grid | h/d | radius scale | β_e of one fibre | CPU s/run | estimator | ξ | C_I ± stat. | "
             "change vs finest ± s.e. | change / stat. |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    data = {}
    richardson = []
    summary: dict[str, dict] = {}
    for est in ESTIMATORS:
        for xi in XI:
            means = []
            for c in cpds:
                vals = [rows[c, s][est, xi][0] for s in have]
                errs = [rows[c, s][est, xi][1] for s in have]
                e = ensemble_mean(vals, errs)
                d = paired_difference(vals, [rows[fine, s][est, xi][0] for s in have])
                means.append(e.mean)
                cpu = float(np.mean([rows[c, s]["cpu_s"] for s in have]))
                head = f"| {c} | {grids[c][0]}³ | {h[c]:.3f} | {scales[c]:.3f} | {beta_e[c]:.3f} | {cpu:.0f} | {est} | {xi} | "
                lines.append(head + (f"{e.mean:+.2e} ± {e.error:.1e} | {d.mean:+.2e} ± {d.stderr:.1e} | "
                                     f"{abs(d.mean) / e.error:.2f} |" if c != fine else
                                     f"{e.mean:+.2e} ± {e.error:.1e} | (finest) | |"))
                data[est, xi, c] = (vals, errs, e.mean, e.error)
            # Richardson per seed (the grids of a seed share the initial state): C_inf_s from the two
            # finest grids, and the bias of a coarse grid's value C_coarse_s - C_inf_s, paired
            p = observed_order(means[-3:], [h[c] for c in cpds[-3:]]) if len(cpds) >= 3 else math.nan
            # the coarse grid whose bias the summary carries: the series' grid where it was run
            mid = cpds[-2]
            coarse = SERIES_CELLS if SERIES_CELLS in cpds[:-1] else cpds[0]
            p_used = p if math.isfinite(p) else ASSUMED_ORDER
            r = (h[mid] / h[fine]) ** p_used
            v_fine, v_mid, v_coarse = (np.array(data[est, xi, c][0]) for c in (fine, mid, coarse))
            c_inf = v_fine + (v_fine - v_mid) / (r - 1.0)
            e_inf = ensemble_mean(c_inf)
            bias = paired_difference(v_coarse, c_inf)
            coarser = [(c, paired_difference(np.array(data[est, xi, c][0]), c_inf)) for c in cpds[:-2] if c != coarse]
            summary[f"{est}_{xi}"] = {"coarse_cells_per_diameter": coarse, "coarse": float(np.mean(v_coarse)),
                                      "richardson": e_inf.mean, "richardson_err": e_inf.error,
                                      "coarse_bias": bias.mean, "coarse_bias_stderr": bias.stderr,
                                      "order": p_used, "order_observed": bool(math.isfinite(p)),
                                      "grids": [int(grids[c][0]) for c in cpds], "seeds": list(have)}
            if math.isfinite(p):
                order = f"observed order {p:.2f}"
            elif len(cpds) < 3:
                order = f"two grids, order {ASSUMED_ORDER:g} assumed"
            else:
                d01, d12 = means[-3] - means[-2], means[-2] - means[-1]
                why = ("the differences change sign" if (d01 > 0) != (d12 > 0) else
                       f"no order in (0.1, 8) gives the ratio of the differences, {d01 / d12:.3g}")
                order = f"no observed order ({why}), order {ASSUMED_ORDER:g} assumed"
            richardson.append(f"* {est}, ξ {xi}: {order}; Richardson C∞ = {e_inf.mean:+.2e} ± {e_inf.error:.1e}; "
                              f"the {coarse}-voxel value's bias C({coarse}) − C∞ = {bias.mean:+.2e} ± "
                              f"{bias.stderr:.1e} (paired over {bias.n} seeds, p-value {bias.p:.2g})"
                              + "".join(f"; C({c}) − C∞ = {b.mean:+.2e} ± {b.stderr:.1e} (p-value {b.p:.2g})"
                                        for c, b in coarser))
    text = "\n".join(lines + ["", "## Order and Richardson extrapolation", ""] + richardson) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "ci_resolution.md").write_text(text, encoding="utf-8")
    (out / "ci_resolution.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    ds = xr.Dataset(
        {f"ci_{est}_{xi}": (("cells_per_diameter", "seed"), [data[est, xi, c][0] for c in cpds], {"units": "1"})
         for est in ESTIMATORS for xi in XI},
        coords={"cells_per_diameter": cpds, "seed": list(have),
                "h_over_d": ("cells_per_diameter", [h[c] for c in cpds]),
                "beta_e_grid": ("cells_per_diameter", [beta_e[c] for c in cpds]),
                "fibre_radius_scale": ("cells_per_diameter", [scales[c] for c in cpds])})
    for est in ESTIMATORS:
        for xi in XI:
            ds[f"ci_{est}_{xi}_stderr"] = (("cells_per_diameter", "seed"), [data[est, xi, c][1] for c in cpds])
    ds["cpu_s"] = (("cells_per_diameter", "seed"), [[rows[c, s]["cpu_s"] for s in have] for c in cpds],
                   {"units": "s"})
    ds.to_netcdf(out / "ci_resolution.nc", engine="h5netcdf")
    _figure(data, cpds, h, out / "ci_resolution.png")
    return text


def _figure(data, cpds, h, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    x = [h[c] for c in cpds]
    for ax, est in zip(axes, ESTIMATORS):
        for xi, mk in zip(XI, ("o", "s")):
            ax.errorbar(x, [data[est, xi, c][2] for c in cpds], [data[est, xi, c][3] for c in cpds], fmt=mk + "-",
                        capsize=3, label=f"ξ: {'Cox β_e' if xi == 'cox' else 'the grid fibre’s β_e'}")
        ax.set_xlabel("voxel size h / d")
        ax.set_ylabel("C_I")
        ax.set_xlim(0, max(x) * 1.1)
        ax.set_title(est.replace("_", " "))
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main() -> None:
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--np", type=int, default=None, help="MPI ranks per run (default: the sweep file's, 1)")
    ap.add_argument("--seeds", type=int, nargs="+", help="override the sweep's seeds")
    ap.add_argument("--calibrated", action="store_true",
                    help="the runs of studies/sweeps/ci_resolution_calibrated.toml: each grid's fibres voxelised "
                         "at the radius calibrated to the converged cylinder's β_e (default --out: "
                         "out/interaction_coefficient/resolution_calibrated)")
    ap.add_argument("--calibrate", action="store_true",
                    help="measure the calibrated radius scale of each grid of the calibrated sweep, print the "
                         "[[points]] of its sweep file, run nothing else")
    ap.add_argument("--shells", choices=series.SHELL_RULES, default=registry.default("numerics.stokes.fibre_shells"),
                    help="with --calibrated: numerics.stokes.fibre_shells of the runs, apart: "
                         "studies/sweeps/ci_resolution_calibrated_apart.toml")
    ap.add_argument("--out", type=Path, default=None,
                    help="output folder (default out/interaction_coefficient/resolution[_calibrated[_apart]])")
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    calibrated = args.calibrated or args.calibrate
    if args.shells == "apart" and not args.calibrated:
        ap.error("--shells apart: the shells are those of the calibrated radius; add --calibrated")
    suffix = "_apart" if args.shells == "apart" else ""
    out = args.out or Path("out/interaction_coefficient/" + ("resolution_calibrated" + suffix if calibrated
                                                             else "resolution"))
    name = "ci_resolution_calibrated" + suffix if calibrated else "ci_resolution"
    spec = sweep_study.load_form(SWEEPS, name, False, seeds=tuple(args.seeds) if args.seeds else None)
    start = time.perf_counter()
    scales = {}
    if calibrated:
        scales = check_calibration(spec, out / "calibration", recalibrate=args.calibrate)
        if args.calibrate:
            return
    done = sweep_study.run_sweep(spec, args.sweep_dir or out / "sweep", args.executor, args.np,
                                 analyse_only=args.analyse_only)
    keyed = {(int(values[0]), seed): p for (values, seed), p in done.items()}
    print(analyse(keyed, tuple(spec.seeds), out, scales))
    print(f"written: {out} ({time.perf_counter() - start:.0f} s)")


def calibration_target() -> float:
    """β_e the calibrated fibres turn with: the converged flat-ended cylinder's, which the solver's
    converged cylinder follows (Zhang et al. 2011's rule, docs/jeffery_orbits.md)."""
    from pyfold.kinematics import equivalent_aspect_ratio

    return float(equivalent_aspect_ratio(series.BETA, "zhang"))


def check_calibration(spec, cache: Path, recalibrate: bool = False) -> dict[int, float]:
    """The fibre radius scale of each point of the calibrated sweep ``spec``, checked: one fibre at
    that scale on the point's grid turns with β_e within CALIBRATION_TOLERANCE of
    :func:`calibration_target` (SystemExit naming the grid otherwise). ``recalibrate``: measure each
    grid's scale anew (:func:`calibrate_scale`) and print the sweep file's [[points]] instead."""
    from pyfold.scene import parse_scene

    target = calibration_target()
    scales = {}
    for point in spec.points:
        c, s = int(point["cells_per_diameter"]), float(point["fibre_radius_scale"])
        probe = scene_of(c, spec.seeds[0], 1.0, s)
        grid, side = [int(g) for g in parse_scene(probe.toml).stokes_grid], probe.side
        if recalibrate:
            s_new, be, pts = calibrate_scale(grid, side, target, cache)
            print(f"[[points]]\ncells_per_diameter = {c}         # {grid[0]}^3: beta_e {be:.3f} at this scale "
                  f"(target {target:.3f}; checks {', '.join(f'{a:.3f}: {b:.3f}' for a, b in pts)})\n"
                  f"fibre_radius_scale = {s_new:.3f}\n")
            scales[c] = s_new
            continue
        be = scaled_beta_e(grid, side, s, cache)
        if abs(be - target) > CALIBRATION_TOLERANCE * target:
            raise SystemExit(f"fibre_radius_scale = {s:.3f} of cells_per_diameter = {c} ({grid[0]}^3): one fibre "
                             f"turns with beta_e {be:.4f} on this machine, target {target:.4f} (allowed "
                             f"± {CALIBRATION_TOLERANCE:.1%}); recalibrate with --calibrate")
        print(f"calibrated radius, {grid[0]}^3: scale {s:.3f}, beta_e {be:.4f} (target {target:.4f})", flush=True)
        scales[c] = s
    return scales



if __name__ == "__main__":
    main()
