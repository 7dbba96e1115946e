"""Fewer Stokes solves: what does each save, and does it move the fluid-coupled C_I?

Question
    A fluid-coupled point costs nearly all its CPU time in the Stokes solves. A calibrated β = 10
    point (studies/interaction_coefficient/ci_fluid_series.py --beta 10 --calibrated) with a solve
    every 4th step at Δt = 0.02 makes 12.5 solves per unit strain, 55–62 CG iterations each on the
    72³ grid: about 4 CPU-hours for 4 seeds to strain 200; the β = 5 series (42³) a quarter of
    that per unit strain. Between solves the velocities are estimated; the series extrapolate the
    last two solves linearly (``numerics.stokes.reuse = "linear"``), which follows a tumbling
    fibre's angular velocity badly once the interval is a sizeable part of its flip.
    ``reuse = "jeffery"`` follows each particle's rotation in the mean flow every step (its dilute
    Jeffery velocity at its current axis) and extrapolates only the departure of the solves from
    it, which the interactions make. How far can the solve interval grow with each estimate
    before the fluid-coupled C_I moves by half its statistical error, and what does that save?

Method
    ``--beta 10 --concentrated`` (solve_reuse_beta10_concentrated.toml): the same series' Stokes scene
    at φβ = 1.0 (n L³ = 12.7: 176 fibres) on the series' own grid, 96³ (fibres voxelised at 1.100 R), a
    solve every 4th step against every 16th (the series') and every 8th, the Jeffery estimate between.
    ``--beta 10`` (studies/sweeps/solve_reuse_beta10.toml): the calibrated β = 10 series' Stokes
    scene at φβ = 0.5 (n L³ = 6.4: 88 fibres, cell 2.4 L, 72³ grid, fibres voxelised at 1.212 R,
    Zhang's β_e = 7.61 recorded, κ = 10³, CG tolerance 10⁻³, AB2, Δt = 0.02). ``--beta 5``
    (solve_reuse_beta5.toml): the β = 5 series' semi-dilute Stokes scene (n L³ = 4.98: 98 fibres,
    cell 2.7 L, 42³ grid, geometric radius, Cox's β_e, the same Stokes numerics, Δt = 0.02).
    Seeds 1–4, strain 20, at the intervals and estimates of the sweep file; its first point is the
    series' own setting (a solve every 4th step, linear), the reference. A seed fixes the
    initial state (checked: the initial axes are equal bit for bit), so the changes are paired.
    Per run, as studies/speed_accuracy/time_step_beta10.py measures them: the closure-free C_I
    (rate regression with the run's own a4) and the IBOF trajectory fit over strain 0–20, both
    with the ξ the runs record; the RMS change of a2(t) against the reference run; the median CG
    iterations per solve; the smallest gap over α; the CPU time (the sweep's attempts). Per
    setting and estimator: the paired change (pyfold.ensemble.paired_difference) in units of the
    reference's ensemble error (pyfold.ensemble.ensemble_mean): admissible at ≤ 0.5, the rule of
    ``numerics.preset = "study"`` (ADMISSIBLE_FRACTION of ci_stokes_settings.py), and resolved when
    the change plus twice its s.e. stays within that too (else 4 seeds cannot tell).

Command
    .venv/bin/python studies/speed_accuracy/solve_reuse.py [--beta 10|5] [--concentrated] [--analyse-only]

Cost (2 cores)
    β = 10: the reference runs 290 CPU-s each, the others less (the table gives each); the sweep
    of 20 runs about 1 CPU-hour, 35 min wall. β = 5: about 0.2 CPU-hour. The analysis about a
    CPU-minute.

Outputs (under out/speed_accuracy/solve_reuse_beta<β>[_concentrated]/, ``--out``)
    sweep/                      the runs (pyfold sweep folder)
    solve_reuse.md              per setting: CPU time, CG iterations, a2 change and both C_I changes
    solve_reuse.nc              C_I per setting and seed; per setting the CPU time and the paired change of
                                each estimator with its s.e. (ci_fluid_series.py reads the change of the
                                setting its sweep uses as part of the settings error)
    solve_reuse.png             change of C_I in statistical errors against CPU time per run
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
from time_step_beta10 import measure  # noqa: E402

#: The sweep of each (aspect ratio, concentrated) (studies/sweeps/<name>.toml) and what its scene is
SWEEPS = {(10.0, False): ("solve_reuse_beta10", "φβ = 0.5, calibrated radius"),
          (10.0, True): ("solve_reuse_beta10_concentrated", "φβ = 1.0, 96³, calibrated radius"),
          (5.0, False): ("solve_reuse_beta5", "n L³ = 4.98, geometric radius")}
ESTIMATORS = ("closure_free", "ibof_trajectory")


def label(point: dict) -> str:
    """A setting's name: its solve interval and estimate between solves."""
    return series.solve_label(point["solve_every"], point.get("reuse", "linear"))


def main() -> None:
    from pyfold.ensemble import ensemble_mean, paired_difference
    from pyfold.sweep import store as sweep_store
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--beta", type=float, default=10.0, choices=sorted({b for b, _c in SWEEPS}),
                    help="fibre aspect ratio: its sweep")
    ap.add_argument("--concentrated", action="store_true",
                    help="the series' concentrated point (beta = 10: phi beta = 1.0 on the series' 96^3 grid)")
    ap.add_argument("--out", type=Path, default=None,
                    help="output folder (out/speed_accuracy/solve_reuse_beta<β>[_concentrated])")
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    if (args.beta, args.concentrated) not in SWEEPS:
        ap.error(f"--concentrated: no such sweep at beta = {args.beta:g}")
    sweep, scene = SWEEPS[args.beta, args.concentrated]
    args.out = args.out or Path(f"out/speed_accuracy/{sweep}")
    spec = sweep_study.load_form(ROOT / "studies" / "sweeps", sweep, False)
    done = sweep_study.run_sweep(spec, args.sweep_dir or args.out / "sweep", args.executor,
                                 analyse_only=args.analyse_only)
    points = [dict(p) for p in spec.points]
    names = [label(p) for p in points]
    runs: dict[tuple[str, int], dict] = {}
    for (point, seed), path in done.items():
        m = measure(path)
        m["cpu_s"] = sweep_store.cpu_seconds(path.parent)
        runs[label(dict(zip(spec.axes, point))), seed] = m
    ref_name = names[0]
    ref_seeds = [s for s in spec.seeds if (ref_name, s) in runs]
    if len(ref_seeds) < 2:
        raise SystemExit(f"need 2 finished reference runs ({ref_name}) at least")
    ref = {s: runs[ref_name, s] for s in ref_seeds}
    e_ref = {est: ensemble_mean([ref[s][est][0] for s in ref_seeds], [ref[s][est][1] for s in ref_seeds])
             for est in ESTIMATORS}
    ref_cpu = float(np.mean([ref[s]["cpu_s"] for s in ref_seeds]))
    lines = [f"# Fewer Stokes solves at β = {args.beta:g} ({scene}, Δt = {float(spec.arguments.get('dt', 0.02)):g}, "
             "strain 0–20)", "",
             f"Reference: {ref_name} (the sweep's first point); closure-free C_I "
             f"{e_ref['closure_free'].mean:+.2e} ± {e_ref['closure_free'].error:.1e}, IBOF trajectory "
             f"{e_ref['ibof_trajectory'].mean:+.2e} ± {e_ref['ibof_trajectory'].error:.1e} (± the 4-seed "
             f"standard error). Change: paired over the seeds, ± its s.e.; in stat. errors: |change| over the "
             f"reference's error; admissible at ≤ {ADMISSIBLE_FRACTION:g}.", "",
             "| setting | seeds | CPU-s per run | × cheaper | CG it./solve | a2 RMS change | min gap / α | "
             "closure-free change | in stat. errors | IBOF trajectory change | in stat. errors | admissible |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    table = {}
    for name in names:
        seeds = [s for s in ref_seeds if (name, s) in runs]
        if not seeds:
            lines.append(f"| {name} | 0 | – | – | – | – | – | – | – | – | – | – |")
            continue
        new = {s: runs[name, s] for s in seeds}
        for s in seeds:
            if not np.array_equal(ref[s]["p0"], new[s]["p0"]):
                raise SystemExit(f"{name}, seed {s}: the initial axes differ from the reference run's; not paired")
        cpu = float(np.mean([new[s]["cpu_s"] for s in seeds]))
        rms = max(float(np.sqrt(np.mean((ref[s]["a2"] - new[s]["a2"]) ** 2))) for s in seeds)
        row = {"seeds": seeds, "cpu_s": cpu, "iterations": float(np.median([new[s]["iterations"] for s in seeds])),
               "rms": rms, "gap": min(new[s]["gap"] for s in seeds)}
        cells = []
        ok, resolved = True, True
        for est in ESTIMATORS:
            if name == ref_name:
                cells += ["–", "–"]
                row[est] = (0.0, 0.0, 0.0, 0.0)
                continue
            d = paired_difference([new[s][est][0] for s in seeds], [ref[s][est][0] for s in seeds])
            frac = abs(d.mean) / e_ref[est].error
            row[est] = (d.mean, d.stderr, frac, d.stderr / e_ref[est].error)
            ok = ok and frac <= ADMISSIBLE_FRACTION
            resolved = resolved and frac + 2 * d.stderr / e_ref[est].error <= ADMISSIBLE_FRACTION
            cells += [f"{d.mean:+.2e} ± {d.stderr:.1e}", f"{frac:.2f} ± {d.stderr / e_ref[est].error:.2f}"]
        table[name] = row
        lines.append(f"| {name}{' (reference)' if name == ref_name else ''} | {len(seeds)} | {cpu:.0f} | "
                     f"{ref_cpu / cpu:.2f} | {row['iterations']:.0f} | {rms:.4f} | {row['gap']:.3f} | "
                     f"{' | '.join(cells)} | {'–' if name == ref_name else verdict(ok, resolved)} |")
    lines += ["", "a2 RMS change: the largest over the seeds of the RMS difference of a2(t) from the reference run "
              "over strain 0–20. CPU-s: mean over the seeds of the sweep's recorded CPU time per run. Admissible: "
              f"|change| ≤ {ADMISSIBLE_FRACTION:g} statistical errors for both estimators; 'not resolved' when "
              f"|change| + 2 s.e. of the change exceeds {ADMISSIBLE_FRACTION:g} for one of them (4 seeds cannot "
              "tell whether the setting passes)."]
    lines += evidence_lines(table, args.beta, args.concentrated)
    text = "\n".join(lines) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "solve_reuse.md").write_text(text, encoding="utf-8")
    have = [n for n in names if n in table]
    ds = xr.Dataset(
        {**{f"ci_{est}": (("setting", "seed"), [[runs[n, s][est][0] if (n, s) in runs else np.nan
                                                 for s in ref_seeds] for n in have], {"units": "1"})
            for est in ESTIMATORS},
         "cpu_s": ("setting", [table[n]["cpu_s"] for n in have], {"units": "s", "long_name": "CPU time per run"}),
         **{f"change_{est}": ("setting", [table[n][est][0] for n in have],
                              {"units": "1", "long_name": "paired mean change of C_I against the reference"})
            for est in ESTIMATORS},
         **{f"change_{est}_stderr": ("setting", [table[n][est][1] for n in have], {"units": "1"})
            for est in ESTIMATORS},
         **{f"change_{est}_in_stat_errors": ("setting", [table[n][est][2] for n in have], {"units": "1"})
            for est in ESTIMATORS}},
        coords={"setting": have, "seed": ref_seeds})
    ds.attrs.update(reference=ref_name, strain=20.0, admissible_fraction=ADMISSIBLE_FRACTION, beta=args.beta,
                    n_l3=float(spec.arguments["n_l3"]),  # where it was measured: ci_fluid_series.reuse_evidence
                    cells_per_diameter=int(spec.arguments.get("cells_per_diameter",
                                                              series.STOKES["cells_per_diameter"])))
    ds.to_netcdf(args.out / "solve_reuse.nc", engine="h5netcdf")
    plot(table, e_ref, ref_name, args.out / "solve_reuse.png", f"β = {args.beta:g}, {scene}")
    print(text)


def evidence_lines(table: dict, beta: float, concentrated: bool) -> list[str]:
    """The settings of pyfold.scene.study_preset.BETA_EVIDENCE that this sweep measures (its regime,
    interval and estimate; at φβ = 0.5 the rows without ``measured_on``, the 96³ one being
    ci_resolution_beta10.py's) against the changes just computed."""
    from pyfold.scene.study_preset import BETA_EVIDENCE, Measured, compare_changes, evidence_check_lines

    ev = BETA_EVIDENCE.get(("concentrated" if concentrated else "semi-dilute", beta))
    if ev is None:
        return []
    notes, bad, checked = [], [], []
    for m in ev.settings:
        name = label({"solve_every": m.stokes.get("solve_every", 1), "reuse": m.stokes.get("reuse", "linear")})
        if (m.measured_on and not concentrated) or name not in table \
                or m.stokes.get("solve_every") == ev.reference.stokes["solve_every"]:
            continue
        row = table[name]  # per estimator: change, its s.e., both in statistical errors at [2], [3]
        new = Measured(name=m.name, stokes=m.stokes, dt_factor=m.dt_factor,
                       closure_free=round(row["closure_free"][2], 2),
                       closure_free_stderr=round(row["closure_free"][3], 2),
                       trajectory=round(row["ibof_trajectory"][2], 2),
                       trajectory_stderr=round(row["ibof_trajectory"][3], 2),
                       cpu_ratio=m.cpu_ratio)
        n, b = compare_changes(m.name, m, new)
        notes, bad, checked = notes + n, bad + b, checked + [m.name]
    return evidence_check_lines("BETA_EVIDENCE", notes, bad, f"checked: {', '.join(checked) or 'no row of this sweep'}")


def verdict(ok: bool, resolved: bool) -> str:
    """The admissibility of a setting: its mean changes within the rule, and whether that is
    resolved (the changes plus twice their s.e. within it too)."""
    if not ok:
        return "no"
    return "yes" if resolved else "yes, not resolved"


def plot(table: dict, e_ref: dict, ref_name: str, path: Path, title: str) -> None:
    """Change of each estimator's C_I in statistical errors against CPU time per run."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, est in zip(axes, ESTIMATORS):
        for name, row in table.items():
            if name == ref_name:
                continue
            mean, se, frac, _se_frac = row[est]
            ax.errorbar(row["cpu_s"], frac, yerr=se / e_ref[est].error, fmt="o", capsize=3,
                        color="C0" if "jeffery" in name else "C1")
            ax.annotate(name, (row["cpu_s"], frac), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.axhline(ADMISSIBLE_FRACTION, color="grey", ls="--", lw=1)
        ax.axvline(table[ref_name]["cpu_s"], color="grey", ls=":", lw=1)
        ax.set_xscale("log")
        ax.set_xlabel("CPU s per run (strain 20)")
        ax.set_title(est.replace("_", " "))
    axes[0].set_ylabel("|paired change of C_I| / statistical error")
    fig.suptitle(f"{title}: fewer Stokes solves (blue: Jeffery + departures, orange: linear)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
