"""The seed's disks in a Couette cell: overlaps with and without the collision strategy, contacts, wall shear stress.

Question
    The seed's slides ("Sphericals particles in Couette Flow", "Spheres - algorithm",
    "no collision strategy"; docs/physics.md#the-seeds-couette-disks) show disks at
    50 % area fraction sheared between two walls: with the collision strategy no two
    disks overlap at any step; without it (α = 0.02) they do. Does pyfold reproduce
    both, with the imposed shear (hydrodynamics = jeffery: contacts only) and with the
    fluid (hydrodynamics = stokes: the hypre backend imposes the walls)? How many
    overlaps appear without the strategy, how much work does the strategy do, and
    (Stokes) what shear stress do the walls carry?

Scene (data/scenes/couette_disks_stokes.toml, the only source of the set-up)
    2-D cell 1.5 × 1, no-slip walls at y = 0 and y = 1 moving at ∓0.5 (γ̇ = 1/s),
    42 disks R = 0.075 (area fraction 0.495), Δt = 0.05 s to t = 30 s, fluid
    viscosity 1 Pa s. Cases:
      strategy  collisions = strategy, α = 0.005 (the slide's "Spheres - algorithm")
      none      collisions = none, α = 0.02 (the slide's "no collision strategy"; α
                only keeps the placed disks α apart at t = 0)
    Seeds 1-3 (small form) or 1-10 (--large; Stokes grid 8 instead of 4 cells per
    diameter). Records and snapshots every step.

Measured per step (from each step's snapshot and record)
    overlaps       disk pairs with centre distance < 2R (minimum image along x) plus
                   disks closer than R to a wall
    in_zone        disk pairs with surface gap < α − tol_gap plus disks nearer than
                   α/2 − tol_gap to a wall: inside the security zone; tol_gap =
                   64 ε max(L), the contact loop's own stopping tolerance
                   (fortran/contact/fold_contacts.f90)
    min_gap        fold_run's smallest gap (pairs and walls) of the step; checked
                   against the snapshot's to round-off (check_min_gap)
    n_corrections, contact_iterations, capped_steps   fold_run's contact counters
    wall_shear_stress  Stokes runs only: σ_xy on the walls (pyfold.open_run: the cell
                   average of σ_xy, which in Stokes flow between walls equals it)
    Per run: totals and maxima of the above and the wall time; per case: mean over
    seeds ± the across-seed standard error (pyfold.ensemble.ensemble_mean).

Command
    nice -n 10 python studies/seed_examples/couette_disks.py --hydrodynamics jeffery          # contacts only
    nice -n 10 python studies/seed_examples/couette_disks.py --hydrodynamics stokes           # needs the hypre backend
    nice -n 10 python studies/seed_examples/couette_disks.py --hydrodynamics stokes --large
    Options: --seeds, --t-end (the snapshots shown are those nearest t = 27 and 30, or the
    last two), --analyse-only, --out. One fold_run at a time; finished runs are reused.

Cost (2 shared cores)
    jeffery, small: 6 runs of 600 steps, ~5 s wall each (42 disks; snapshot every step),
    under a minute with the analysis. stokes: 6 runs of 600 hypre solves on a 40 × 27
    grid (large: 80 × 54, 20 runs).

Outputs (under out/seed_examples/couette_disks/<hydrodynamics>/)
    runs/*.h5 (+ .toml, .json wall time)   the runs (reused)
    couette_disks.nc      per (case, seed, time) series and per (case, seed) totals
    couette_disks.md      table and answer
    snapshots_<case>.png  seed 1 at t = 27 and t = 30, overlapping disks in red
    overlaps.png          overlaps and pairs inside the security zone over time
    contacts.png          contact corrections and iterations per step (strategy)
    wall_stress.png       wall shear stress over time (Stokes runs)
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import tomli_w
import xarray as xr

from pyfold.command_line import command_line
from pyfold.ensemble import ensemble_mean
from pyfold.run_results import open_run

# Parameters

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "data" / "scenes" / "couette_disks_stokes.toml"
#: (collisions, alpha) of each case, from the slides
CASES = {"strategy": ("strategy", 0.005), "none": ("none", 0.02)}
#: the slide's snapshot times [s]
SNAPSHOT_TIMES = (27.0, 30.0)
#: tol_gap of fortran/contact/fold_contacts.f90: the loop stops when every gap >= alpha - tol_gap
TOL_GAP_ULPS = 64.0


@dataclasses.dataclass(frozen=True)
class Form:
    seeds: tuple[int, ...]
    t_end: float
    cells_per_diameter: int


SMALL = Form(seeds=(1, 2, 3), t_end=30.0, cells_per_diameter=4)
LARGE = Form(seeds=tuple(range(1, 11)), t_end=30.0, cells_per_diameter=8)


def base_scene() -> dict:
    return tomllib.loads(SCENE.read_text(encoding="utf-8"))


def scene_of(case: str, seed: int, hydrodynamics: str, form: Form) -> dict:
    """The bundled scene with the case's collisions and α, the seed, the end time and
    records and snapshots at every step."""
    scene = base_scene()
    collisions, alpha = CASES[case]
    dt = scene["numerics"]["dt"]
    scene["title"] = f"{scene['title']} ({case}, {hydrodynamics}, seed {seed})"
    scene["model"].update(hydrodynamics=hydrodynamics, collisions=collisions, alpha=alpha)
    scene["numerics"].update(seed=seed, t_end=form.t_end)
    scene["numerics"]["stokes"]["cells_per_diameter"] = form.cells_per_diameter
    scene["output"] = {"interval": dt, "snapshot_interval": dt}
    return scene


def run_name(case: str, seed: int, hydrodynamics: str, form: Form) -> str:
    grid = f"_cpd{form.cells_per_diameter}" if hydrodynamics == "stokes" else ""
    return f"{hydrodynamics}_{case}{grid}_t{form.t_end:g}_s{seed}"


# Solver: one fold_run at a time, finished runs reused


def ensure_run(runs: Path, name: str, scene: dict, analyse_only: bool) -> Path:
    from pyfold.cli import main as cli_main

    out = runs / f"{name}.h5"
    if out.exists():
        return out
    if analyse_only:
        raise FileNotFoundError(f"{out}: missing (--analyse-only simulates nothing)")
    runs.mkdir(parents=True, exist_ok=True)
    path = runs / f"{name}.toml"
    path.write_text(tomli_w.dumps(scene), encoding="utf-8")
    start = time.perf_counter()
    status = cli_main(["run", str(path), "-o", str(out), "--force"])
    wall = time.perf_counter() - start
    if status != 0:
        if out.exists():
            out.unlink()
        raise RuntimeError(f"pyfold run {path} failed with status {status}")
    (runs / f"{name}.json").write_text(json.dumps({"wall_s": wall}), encoding="utf-8")
    return out


# Analysis of one run


def gaps(x: np.ndarray, lengths, radius: float):
    """Surface gaps of disks at centres ``x`` (..., n, 2) in the Couette cell: pairs
    (..., n(n-1)/2) with the minimum image along x (periodic; no Lees–Edwards offset
    between walls), and walls (..., n) to the nearer wall."""
    lx, ly = lengths
    i, j = np.triu_indices(x.shape[-2], k=1)
    d = x[..., i, :] - x[..., j, :]
    d[..., 0] -= lx * np.round(d[..., 0] / lx)
    pair = np.hypot(d[..., 0], d[..., 1]) - 2.0 * radius
    wall = np.minimum(x[..., 1], ly - x[..., 1]) - radius
    return pair, wall


def analyse_run(path: Path, alpha: float, lengths, radius: float) -> dict:
    ds = open_run(path)
    t_snap = np.asarray(ds["snapshot_time"].values, dtype=float)
    x = np.asarray(ds["x"].values, dtype=float)
    pair, wall = gaps(x, lengths, radius)
    tol = TOL_GAP_ULPS * np.finfo(float).eps * max(lengths)
    t = np.asarray(ds["time"].values, dtype=float)
    out = {
        "t": t_snap, "x": x,
        "overlaps": (pair < 0.0).sum(-1) + (wall < 0.0).sum(-1),
        "in_zone": (pair < alpha - tol).sum(-1) + (wall < 0.5 * alpha - tol).sum(-1),
        "snapshot_min_gap": np.minimum(pair.min(-1), wall.min(-1)),
        "record_time": t,
        "min_gap": np.asarray(ds["min_gap"].values, dtype=float),
        "n_corrections": np.asarray(ds["n_corrections"].values, dtype=float),
        "contact_iterations": np.asarray(ds["contact_iterations"].values, dtype=float),
        "capped_steps": float(np.sum(ds["capped_steps"].values)),
        "status": str(ds.attrs.get("status", "")),
    }
    if "wall_shear_stress" in ds:
        out["wall_shear_stress"] = np.asarray(ds["wall_shear_stress"].values, dtype=float)
    ds.close()
    wall_file = path.with_suffix(".json")
    out["wall_s"] = json.loads(wall_file.read_text())["wall_s"] if wall_file.exists() else math.nan
    return out


def check_min_gap(r: dict) -> float:
    """Largest |fold_run's min_gap − the snapshot's| over the steps (records and snapshots
    at every step hold the same configuration): round-off, a few ε max(L)."""
    common, ia, ib = np.intersect1d(np.round(r["record_time"], 9), np.round(r["t"], 9), return_indices=True)
    return float(np.max(np.abs(r["min_gap"][ia] - r["snapshot_min_gap"][ib]))) if common.size else math.nan


# Figures


def plot_snapshots(path: Path, r: dict, lengths, radius: float, case: str, hydrodynamics: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    lx, ly = lengths
    want = [int(np.argmin(np.abs(r["t"] - tt))) for tt in SNAPSHOT_TIMES]
    if len(set(want)) < 2:
        want = [max(0, len(r["t"]) - 2), len(r["t"]) - 1]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, k in zip(axes, want):
        x = r["x"][k]
        pair, wall = gaps(x[None], lengths, radius)
        bad = np.zeros(len(x), bool)
        i, j = np.triu_indices(len(x), k=1)
        hit = pair[0] < 0
        bad[i[hit]] = bad[j[hit]] = True
        bad |= wall[0] < 0
        for p, b in zip(x, bad):
            for shift in (-lx, 0.0, lx):  # periodic images across x = 0, Lx
                c = (p[0] + shift, p[1])
                if -radius < c[0] < lx + radius:
                    ax.add_patch(Circle(c, radius, fc="tab:red" if b else "tab:blue", ec="k", lw=0.5, alpha=0.8))
        ax.add_patch(Rectangle((0, 0), lx, ly, fill=False, ec="0.5", ls="--"))
        ax.axhline(0.0, color="k", lw=3)
        ax.axhline(ly, color="k", lw=3)
        ax.set_xlim(0, lx)
        ax.set_ylim(-0.05, ly + 0.05)
        ax.set_aspect("equal")
        ax.set_title(f"t = {r['t'][k]:g} s: {int(r['overlaps'][k])} overlaps")
        ax.set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    fig.suptitle(f"model.collisions = {CASES[case][0]!r}, α = {CASES[case][1]:g} m, "
                 f"hydrodynamics = {hydrodynamics}; red: overlapping")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_series(path: Path, results: dict, key: str, ylabel: str, cases=None, ylog=False) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = cases or list(results)
    fig, axes = plt.subplots(1, len(cases), figsize=(5 * len(cases), 3.5), squeeze=False)
    for ax, case in zip(axes[0], cases):
        for seed, r in results[case].items():
            tt = r["t"] if key in ("overlaps", "in_zone") else r["record_time"]
            ax.plot(tt, r[key], lw=0.8, label=f"seed {seed}")
        ax.set_title(case)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(ylabel)
        if ylog:
            ax.set_yscale("symlog")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# Run


def run(hydrodynamics: str, form: Form, out: Path, analyse_only: bool = False, figures: bool = True) -> xr.Dataset:
    scene = base_scene()
    lengths = tuple(scene["cell"]["size"])
    radius = float(scene["particles"][0]["radius"])
    runs = out / "runs"
    results: dict[str, dict[int, dict]] = {}
    for case, (_, alpha) in CASES.items():
        results[case] = {}
        for seed in form.seeds:
            path = ensure_run(runs, run_name(case, seed, hydrodynamics, form),
                              scene_of(case, seed, hydrodynamics, form), analyse_only)
            results[case][seed] = analyse_run(path, alpha, lengths, radius)

    # Save: per (case, seed, time) series and per (case, seed) totals
    cases, seeds = list(CASES), list(form.seeds)
    first = results[cases[0]][seeds[0]]
    t_snap, t_rec = first["t"], first["record_time"]

    def stack(key):
        return np.array([[results[c][s][key] for s in seeds] for c in cases], dtype=float)

    def total(fn):
        return np.array([[fn(results[c][s]) for s in seeds] for c in cases], dtype=float)

    ds = xr.Dataset(
        {
            "overlaps": (("case", "seed", "time"), stack("overlaps"),
                         {"units": "1",
                          "long_name": "overlapping disk pairs + disks overlapping a wall, after the step"}),
            "in_zone": (("case", "seed", "time"), stack("in_zone"),
                        {"units": "1", "long_name": "disk pairs with gap < alpha + disks nearer than alpha/2 to a "
                                                    "wall (beyond the contact loop's tolerance 64 eps max(L))"}),
            "min_gap": (("case", "seed", "record_time"), stack("min_gap"),
                        {"units": "m", "long_name": "fold_run's smallest surface gap of the step (pairs and walls)"}),
            "n_corrections": (("case", "seed", "record_time"), stack("n_corrections"),
                              {"units": "1", "long_name": "contact corrections in the step"}),
            "contact_iterations": (("case", "seed", "record_time"), stack("contact_iterations"),
                                   {"units": "1", "long_name": "contact-loop iterations of the step"}),
            "overlap_steps": (("case", "seed"), total(lambda r: np.count_nonzero(r["overlaps"])),
                              {"units": "1", "long_name": "steps with at least one overlap"}),
            "overlaps_total": (("case", "seed"), total(lambda r: r["overlaps"].sum()),
                               {"units": "1", "long_name": "overlaps summed over the steps"}),
            "overlaps_max": (("case", "seed"), total(lambda r: r["overlaps"].max()),
                             {"units": "1", "long_name": "most overlaps at one step"}),
            "deepest_gap_over_radius": (("case", "seed"), total(lambda r: r["snapshot_min_gap"].min() / radius),
                                        {"units": "1", "long_name": "smallest surface gap over the run / R"}),
            "in_zone_total": (("case", "seed"), total(lambda r: r["in_zone"].sum()),
                              {"units": "1", "long_name": "pairs inside the security zone summed over the steps"}),
            "corrections_per_step": (("case", "seed"), total(lambda r: r["n_corrections"][1:].mean()),
                                     {"units": "1", "long_name": "mean contact corrections per step"}),
            "max_contact_iterations": (("case", "seed"), total(lambda r: r["contact_iterations"].max()),
                                       {"units": "1", "long_name": "most contact-loop iterations in one step"}),
            "capped_steps": (("case", "seed"), total(lambda r: r["capped_steps"]),
                             {"units": "1", "long_name": "steps whose contact loop reached contact_max_iter"}),
            "min_gap_check": (("case", "seed"), total(check_min_gap),
                              {"units": "m", "long_name": "largest abs(fold_run min_gap - snapshot min gap)"}),
            "wall_s": (("case", "seed"), total(lambda r: r["wall_s"]),
                       {"units": "s", "long_name": "wall time of the run (pyfold run, one process)"}),
        },
        coords={"case": cases, "seed": seeds,
                "time": ("time", t_snap, {"units": "s", "long_name": "snapshot time"}),
                "record_time": ("record_time", t_rec, {"units": "s", "long_name": "record time"}),
                "alpha": ("case", [CASES[c][1] for c in cases], {"units": "m", "long_name": "security zone"}),
                "collisions": ("case", [CASES[c][0] for c in cases])},
        attrs={"hydrodynamics": hydrodynamics, "scene": str(SCENE.relative_to(ROOT)), "radius": radius,
               "cell_lengths": list(lengths), "t_end": form.t_end, "cells_per_diameter": form.cells_per_diameter,
               "command": command_line(sys.argv)},
    )
    if all("wall_shear_stress" in results[c][s] for c in cases for s in seeds):
        ds["wall_shear_stress"] = (("case", "seed", "record_time"), stack("wall_shear_stress"),
                                   {"units": "Pa", "long_name": "shear stress on the walls"})
    out.mkdir(parents=True, exist_ok=True)
    ds.to_netcdf(out / "couette_disks.nc", engine="h5netcdf")
    (out / "couette_disks.md").write_text(summary(ds), encoding="utf-8")
    if figures:
        for case in cases:
            plot_snapshots(out / f"snapshots_{case}.png", results[case][seeds[0]], lengths, radius, case, hydrodynamics)
        plot_series(out / "overlaps.png", results, "overlaps", "overlaps after the step")
        plot_series(out / "contacts.png", results, "n_corrections", "contact corrections in the step",
                    cases=["strategy"])
        if "wall_shear_stress" in ds:
            plot_series(out / "wall_stress.png", results, "wall_shear_stress", "wall shear stress [Pa]")
    return ds


def _pm(values) -> str:
    m = ensemble_mean(np.asarray(values, dtype=float))
    return f"{m.mean:.4g}" + (f" ± {m.stderr_across:.2g}" if math.isfinite(m.stderr_across) else "")


def summary(ds: xr.Dataset) -> str:
    rows = ["overlap_steps", "overlaps_total", "overlaps_max", "deepest_gap_over_radius", "in_zone_total",
            "corrections_per_step", "max_contact_iterations", "capped_steps", "min_gap_check", "wall_s"]
    lines = [f"# The seed's Couette disks ({ds.attrs['hydrodynamics']})", "",
             f"Scene {ds.attrs['scene']}, t_end = {ds.attrs['t_end']:g} s, seeds {list(map(int, ds.seed.values))}; "
             "mean over seeds ± across-seed standard error.", "",
             "| quantity | " + " | ".join(f"{c} (α = {a:g})" for c, a in zip(ds.case.values, ds.alpha.values)) + " |",
             "|---|" + "---|" * ds.sizes["case"]]
    for key in rows:
        lines.append(f"| {key}: {ds[key].attrs['long_name']} | "
                     + " | ".join(_pm(ds[key].sel(case=c).values) for c in ds.case.values) + " |")
    if "wall_shear_stress" in ds:
        tau = ds["wall_shear_stress"].isel(record_time=slice(1, None)).mean("record_time")
        lines.append("| wall shear stress, time mean after t = 0 [Pa] | "
                     + " | ".join(_pm(tau.sel(case=c).values) for c in ds.case.values) + " |")
    strat, none = (ds["overlaps_total"].sel(case=c).values for c in ("strategy", "none"))
    lines += ["", "Answer: with the collision strategy "
              + ("no overlap at any step of any seed" if np.all(strat == 0) else
                 f"overlaps remain ({int(strat.sum())} over all seeds): the strategy failed")
              + "; without it " + (f"overlaps appear in every seed ({_pm(none)} overlaps summed over the steps)"
                                   if np.all(none > 0) else "some seeds show no overlap") + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hydrodynamics", choices=("jeffery", "stokes"), default="stokes",
                        help="jeffery: contacts only (imposed shear); stokes: the fluid (hypre backend)")
    parser.add_argument("--large", action="store_true", help="10 seeds, Stokes grid 8 cells per diameter")
    parser.add_argument("--seeds", type=int, nargs="+", help="override the form's seeds")
    parser.add_argument("--t-end", type=float, help="override the end time [s] (a multiple of dt = 0.05)")
    parser.add_argument("--analyse-only", action="store_true", help="use existing run files, simulate nothing")
    parser.add_argument("--no-figures", action="store_true")
    parser.add_argument("--out", type=Path, default=Path("out/seed_examples/couette_disks"))
    args = parser.parse_args(argv)
    form = LARGE if args.large else SMALL
    form = dataclasses.replace(form, **{k: v for k, v in (("seeds", tuple(args.seeds) if args.seeds else None),
                                                          ("t_end", args.t_end)) if v is not None})
    start = time.perf_counter()
    ds = run(args.hydrodynamics, form, args.out / args.hydrodynamics, args.analyse_only, not args.no_figures)
    print(summary(ds))
    print(f"wall time of the study: {time.perf_counter() - start:.1f} s; outputs in {args.out / args.hydrodynamics}")


if __name__ == "__main__":
    main()
