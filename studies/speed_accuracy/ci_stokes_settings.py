"""What each numerical setting of the Stokes-coupled simulation costs, and what it does to C_I.

Question
    A user of the fluid-coupled simulation pays for a C_I at a stated accuracy, not for a
    Stokes step. For the Folgar–Tucker C_I of a semi-dilute and a concentrated fibre
    suspension (closure-free rate regression with the run's own a4, and the trajectory fit
    of Folgar–Tucker + IBOF to a2(t)) and for a2(t) itself: how far does each cheaper
    setting of the Stokes numerics (CG tolerance, single-precision transforms, a solve every
    k-th step, the time step, the penalty κ) and the number of MPI ranks move the
    answer from the reference setting, in units of the answer's statistical error over 4
    seeds, and what does it save in CPU time? Which settings keep their change below half
    that statistical error (the rule of ``numerics.preset = "study"``)?

Method
    Each scene (pyfold.scene.sheared_fibres: β = 5 fibres, simple shear γ̇ = 1, security
    zone α = 0.1 d, Δt = α/(γ̇L) = 0.02 unless a setting changes it, AB2, records every
    0.2 strain, strain 30) is run with every setting on the same seeds: a seed fixes the
    initial state, so each setting is compared with the reference seed by seed
    (pyfold.ensemble.paired_difference). Reference: κ = 10³, CG tolerance 10⁻⁴, 3 voxels
    per diameter requested (the numerics of ci_hydrodynamics.py and of the evidence behind
    ``hydrodynamics = "auto"``). Per setting: the ensemble C_I (mean over seeds, error the
    larger of the scatter and the pooled run errors, pyfold.ensemble.ensemble_mean), the
    paired change against the reference ± its standard error, the change in units of the
    reference's ensemble error, the RMS change of a2(t) over the run (paired mean), and the
    mean CPU time per run with its ratio to the reference's.
    The penalty κ: a softer solid (κ = 10² and 30) needs fewer CG iterations (about √κ) and
    carries a looser tolerance (the stress bound below allows 10⁻² for κ ≤ 10²); its own error
    is a rigidity error of order 1/κ (the fibres' strain rate inside, /stokes/rigidity_max).
    Ranks (studies/sweeps/ci_stokes_settings_ranks.toml, the RANKED rows): the setting
    "tolerance 10⁻³, a solve every 4th step" on 2 MPI ranks per run, one run at a time; the
    domain decomposition changes the transforms' round-off only, so its change of C_I is that
    round-off grown by the suspension's chaos, and what it buys is wall time (CPU time counts
    both ranks). Ranks are the run's resources, not a preset setting.
    The penalty's tolerance stops at 10⁻³ for κ = 10³: at 10⁻² ``pyfold validate`` refuses κ = 10³ on
    these grids (the bound on the particles' stress error,
    docs/physics.md#how-large-a-penalty-the-solver-can-carry). Exact rigidity
    (``rigidity = "exact"``) is not a point: at tolerance 10⁻² on the semi-dilute scene it
    ran at about 4 times the reference's CPU time per step and stopped at step 183 (1000 CG
    iterations, rigidity error 1.3·10⁻²), docs/speed_accuracy.md. The grid is
    not varied here: the C_I is that of 3 voxels per diameter (a β = 5 spheroid's period is 16 %
    short there); studies/interaction_coefficient/ci_resolution.py measures the resolution.
    Scenes: semi-dilute n L³ = 5 (98 fibres, cell 2.7 L, 42³ at 3 voxels per diameter) and
    concentrated n L³ = 8 (157 fibres, volume fraction 0.25; at n L³ = 10, φ = 0.31, the
    random placement jams); the settings are listed in SETTINGS, the points in
    studies/sweeps/ci_stokes_settings.toml.

Command
    .venv/bin/python studies/speed_accuracy/ci_stokes_settings.py [--executor slurm] [--seeds 1 2] [--no-ranks]
    (the sweep runs two serial simulations at a time; finished runs are re-used, a killed
    one is resumed from its checkpoint; --analyse-only analyses what is there)

Cost (2 cores)
    The sweep is about 3 CPU-hours (per run, semi-dilute: the reference 9 CPU-min, the
    cheapest setting 2; concentrated: about 12 and 3); the analysis about 2 CPU-min.
    The measured CPU time of every run is in the outputs.

Outputs (under out/speed_accuracy/ci_stokes_settings/, ``--out``)
    sweep/                       the runs (pyfold sweep folder)
    sweep_ranks/                 the 2-rank runs (--no-ranks: none)
    ci_stokes_settings.nc        per scene, setting and seed: C_I (both estimators), a2 RMS
                                 change, CPU s; per scene and setting the ensemble and paired values
    ci_stokes_settings.md        the tables
    ci_stokes_settings.png       change of C_I in units of its statistical error against CPU
                                 time per run, one panel per scene and estimator
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import xarray as xr

from pyfold import run_checks
from pyfold.ci_estimators import ci_rate_regression
from pyfold.ensemble import ensemble_mean, paired_difference
from pyfold.fast_fit import fit_ci_rk4
from pyfold.run_results import open_run
from pyfold.scene.sheared_fibres import sheared_fibres
from pyfold.sweep import store as sweep_store

ALPHA_OVER_D = 0.1
BETA = 5.0
#: scene name -> n L^3
SCENES = {"semi-dilute": 5.0, "concentrated": 8.0}
REFERENCE = "tol1e-4"
#: the reference's [numerics.stokes] keys that every setting shares unless it changes them
REFERENCE_STOKES = {"cells_per_diameter": 3, "kappa": 1e3}
#: the reference time step: alpha / (gamma_dot L) with alpha = 0.1 d, d = L / BETA, L = 1, gamma_dot = 1
DT_REFERENCE = ALPHA_OVER_D / BETA
#: setting -> ([numerics.stokes] keys, time step or None (alpha / (gamma_dot L)), what it is)
SETTINGS: dict[str, tuple[dict, float | None, str]] = {
    "tol1e-4": ({"tolerance": 1e-4}, None, "κ 10³, tolerance 10⁻⁴ (reference)"),
    "tol1e-3": ({"tolerance": 1e-3}, None, "tolerance 10⁻³"),
    "tol1e-3_single": ({"tolerance": 9.9e-4, "fft_precision": "single"}, None,
                       "tolerance 9.9·10⁻⁴, single-precision transforms"),
    "tol1e-3_every2": ({"tolerance": 1e-3, "solve_every": 2}, None, "tolerance 10⁻³, a solve every 2nd step"),
    "tol1e-3_every4": ({"tolerance": 1e-3, "solve_every": 4}, None, "tolerance 10⁻³, a solve every 4th step"),
    "tol1e-3_dt0.04": ({"tolerance": 1e-3}, 0.04, "tolerance 10⁻³, Δt 0.04 (twice the reference)"),
    "kappa100_tol1e-3_every4": ({"kappa": 1e2, "tolerance": 1e-3, "solve_every": 4}, None,
                                "κ 10², tolerance 10⁻³, a solve every 4th step"),
    "kappa100_tol1e-2_every4": ({"kappa": 1e2, "tolerance": 1e-2, "solve_every": 4}, None,
                                "κ 10², tolerance 10⁻², a solve every 4th step"),
    "kappa30_tol1e-2_every4": ({"kappa": 30.0, "tolerance": 1e-2, "solve_every": 4}, None,
                               "κ 30, tolerance 10⁻², a solve every 4th step"),
}
#: the ranks lever (studies/sweeps/ci_stokes_settings_ranks.toml): its row -> (the setting it runs,
#: MPI ranks per run, what it is). Not a preset setting: ranks are the run's resources, not its
#: numerics, and change the answer only through round-off.
RANKED: dict[str, tuple[str, int, str]] = {
    "tol1e-3_every4_np2": ("tol1e-3_every4", 2, "tolerance 10⁻³, a solve every 4th step, 2 MPI ranks"),
}
ESTIMATORS = {"closure_free": "rate regression with the run's own a4",
              "ibof_trajectory": "Folgar–Tucker + IBOF fitted to a2(t)"}
#: The preset's rule: a setting is admissible where its change of C_I stays below this
#: fraction of the reference's ensemble error.
ADMISSIBLE_FRACTION = 0.5


def scene_of(scene: str, setting: str, seed: int, t_end: float):
    """The sweep's builder: the scene ``scene`` with the numerics ``setting``, seed ``seed``."""
    stokes = {**REFERENCE_STOKES, **SETTINGS[setting][0]}
    return sheared_fibres(BETA, SCENES[scene], seed, t_end, alpha_over_d=ALPHA_OVER_D, dt=SETTINGS[setting][1],
                          hydrodynamics="stokes", stokes=stokes, time_scheme="ab2")


def ranked_runs(done: dict, ranks: int) -> dict[tuple[str, str, int], Path]:
    """The finished runs ``done`` of the ranks sweep (``{((scene, setting), seed): run file}``, run
    on ``ranks`` ranks each) keyed ``(scene, RANKED row, seed)``; runs of no RANKED row are left out."""
    rows_of = {(setting, np_): row for row, (setting, np_, _) in RANKED.items()}
    return {(scene, rows_of[setting, ranks], seed): path for ((scene, setting), seed), path in done.items()
            if (setting, ranks) in rows_of}


def label(row: str) -> str:
    """What the row ``row`` (a SETTINGS or RANKED key) is, for the tables."""
    return RANKED[row][2] if row in RANKED else SETTINGS[row][2]


def analyse_run(path: Path) -> dict:
    """C_I of one run by both estimators, its a2(t) and its CPU time."""
    ds = open_run(path)
    L = run_checks.velocity_gradient_of(path)
    xi = run_checks.shape_factor_of(ds)
    t, a2, a4 = ds["time"].values, ds["a2"].values, ds["a4"].values
    reg = ci_rate_regression(t, a2, a4, L, xi)
    fit = fit_ci_rk4("ibof", t, a2, L, xi)
    attempts = sweep_store.attempts(path.parent)
    return {"t": t, "a2": a2, "cpu_s": sweep_store.cpu_seconds(path.parent),
            "wall_s": float(sum(a.get("wall_s", math.nan) for a in attempts)) if attempts else math.nan,
            "closure_free": (reg.ci, reg.stderr), "ibof_trajectory": (fit.ci, fit.stderr),
            "iterations": float(ds["stokes_iterations"].values.mean()) if "stokes_iterations" in ds else math.nan}


def compare(runs: dict, scene: str, settings: list[str], seeds: list[int]) -> list[dict]:
    """Per setting: ensemble C_I, paired change against the reference, a2 change, cost."""
    ref = {s: runs[scene, REFERENCE, s] for s in seeds}
    rows = []
    for name in settings:
        have = [s for s in seeds if (scene, name, s) in runs]
        row = {"setting": name, "seeds": have, "cpu_s": float(np.mean([runs[scene, name, s]["cpu_s"] for s in have])),
               "wall_s": float(np.mean([runs[scene, name, s]["wall_s"] for s in have])),
               "iterations": float(np.mean([runs[scene, name, s]["iterations"] for s in have]))}
        row["cpu_ratio"] = row["cpu_s"] / float(np.mean([ref[s]["cpu_s"] for s in have]))
        for est in ESTIMATORS:
            v = [runs[scene, name, s][est][0] for s in have]
            e = [runs[scene, name, s][est][1] for s in have]
            ens = ensemble_mean(v, e)
            ref_ens = ensemble_mean([ref[s][est][0] for s in have], [ref[s][est][1] for s in have])
            d = paired_difference(v, [ref[s][est][0] for s in have])
            row[est] = {"mean": ens.mean, "error": ens.error, "change": d.mean, "change_stderr": d.stderr,
                        "p": d.p, "in_stat_errors": abs(d.mean) / ref_ens.error,
                        "stderr_in_stat_errors": d.stderr / ref_ens.error,
                        "bound_in_stat_errors": (abs(d.mean) + d.stderr) / ref_ens.error
                        if math.isfinite(d.stderr) else math.nan}
        a2c = []
        for s in have:
            a, r = runs[scene, name, s], ref[s]
            a2_on_ref = np.stack([np.interp(r["t"], a["t"], a["a2"][:, i, j]) for i in range(3) for j in range(3)], 1)
            a2c.append(float(np.sqrt(np.mean((a2_on_ref - r["a2"].reshape(len(r["t"]), 9)) ** 2))))
        row["a2_rms_change"] = float(np.mean(a2c))
        rows.append(row)
    return rows


def table(scene: str, rows: list[dict]) -> str:
    head = (f"### {scene}\n\n| setting | seeds | CPU s/run | wall s/run | × cheaper | CG it/solve | "
            + " | ".join(f"C_I {k} ± err | change ± s.e. | in stat. errors" for k in ESTIMATORS)
            + " | a2 RMS change |\n|" + "---|" * (7 + 3 * len(ESTIMATORS)) + "\n")
    lines = []
    for r in rows:
        cells = [label(r["setting"]), str(len(r["seeds"])), f"{r['cpu_s']:.0f}", f"{r['wall_s']:.0f}",
                 f"{1 / r['cpu_ratio']:.2f}",
                 f"{r['iterations']:.1f}"]
        for est in ESTIMATORS:
            c = r[est]
            cells += [f"{c['mean']:.2e} ± {c['error']:.1e}", f"{c['change']:+.1e} ± {c['change_stderr']:.1e}",
                      f"{c['in_stat_errors']:.2f}"]
        cells.append(f"{r['a2_rms_change']:.1e}")
        lines.append("| " + " | ".join(cells) + " |")
    return head + "\n".join(lines) + "\n"


def figure(all_rows: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(all_rows), len(ESTIMATORS), figsize=(10, 3.8 * len(all_rows)), squeeze=False)
    for i, (scene, rows) in enumerate(all_rows.items()):
        for j, est in enumerate(ESTIMATORS):
            ax = axes[i, j]
            for r in rows:
                c = r[est]
                ax.errorbar(r["cpu_s"], c["in_stat_errors"], yerr=np.nan_to_num(c["stderr_in_stat_errors"]),
                            fmt="o", color="C3" if r["setting"] == REFERENCE else "C0")
                ax.annotate(r["setting"], (r["cpu_s"], c["in_stat_errors"]), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
            ax.axhline(ADMISSIBLE_FRACTION, color="k", ls="--", lw=0.8)
            ax.set_xscale("log")
            ax.set_xlabel("CPU s per run (strain 30)")
            ax.set_ylabel("|ΔC_I| / statistical error (4 seeds)")
            ax.set_title(f"{scene}: {ESTIMATORS[est]}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def dataset(runs: dict, all_rows: dict, seeds: list[int]) -> xr.Dataset:
    scenes, settings = list(all_rows), [*SETTINGS, *RANKED]
    shape = (len(scenes), len(settings), len(seeds))
    data = {f"ci_{est}": np.full(shape, np.nan) for est in ESTIMATORS}
    data.update({f"ci_{est}_stderr": np.full(shape, np.nan) for est in ESTIMATORS})
    data["cpu_s"] = np.full(shape, np.nan)
    data["wall_s"] = np.full(shape, np.nan)
    for (sc, st, sd), r in runs.items():
        if sc in scenes and sd in seeds:
            k = (scenes.index(sc), settings.index(st), seeds.index(sd))
            for est in ESTIMATORS:
                data[f"ci_{est}"][k], data[f"ci_{est}_stderr"][k] = r[est]
            data["cpu_s"][k], data["wall_s"][k] = r["cpu_s"], r["wall_s"]
    dims = ("scene", "setting", "seed")
    names = {"cpu_s": "CPU time of the run (all ranks)", "wall_s": "wall time of the run"}
    ds = xr.Dataset({k: (dims, v, {"units": "s" if k in names else "1", "long_name": names.get(k, k.replace("_", " "))})
                     for k, v in data.items()},
                    coords={"scene": scenes, "setting": settings, "seed": seeds})
    for est in ESTIMATORS:
        for field, units in (("change", "1"), ("change_stderr", "1"), ("in_stat_errors", "1")):
            v = np.full((len(scenes), len(settings)), np.nan)
            for i, sc in enumerate(scenes):
                for r in all_rows[sc]:
                    v[i, settings.index(r["setting"])] = r[est][field]
            ds[f"ci_{est}_{field}"] = (("scene", "setting"), v,
                                       {"units": units, "long_name": f"paired {field.replace('_', ' ')} of C_I "
                                                                     f"({ESTIMATORS[est]}) against {REFERENCE}"})
    ds.attrs.update(reference=REFERENCE, beta=BETA, alpha_over_d=ALPHA_OVER_D,
                    admissible_fraction=ADMISSIBLE_FRACTION)
    return ds


def measured(rows: list[dict]) -> dict[str, "Measured"]:
    """The rows as pyfold.scene.study_preset.Measured (changes in statistical errors, 2 digits)."""
    from pyfold.scene.study_preset import Measured

    out = {}
    for r in rows:
        if r["setting"] in RANKED:
            continue
        stokes = {**REFERENCE_STOKES, **SETTINGS[r["setting"]][0]}
        cf, tr = r["closure_free"], r["ibof_trajectory"]
        out[r["setting"]] = Measured(
            name=r["setting"], stokes=stokes, dt_factor=(SETTINGS[r["setting"]][1] or DT_REFERENCE) / DT_REFERENCE,
            closure_free=round(cf["in_stat_errors"], 2), closure_free_stderr=round(cf["stderr_in_stat_errors"], 2),
            trajectory=round(tr["in_stat_errors"], 2), trajectory_stderr=round(tr["stderr_in_stat_errors"], 2),
            cpu_ratio=round(r["cpu_ratio"], 2))
    return out


def evidence_check(all_rows: dict) -> tuple[list[str], list[str]]:
    """These runs against pyfold.scene.study_preset.EVIDENCE (the preset's copy): (notes, disagreements).

    Identical rows are expected from the same runs. Runs remade on another machine are other
    realisations of a chaotic suspension (the transforms' round-off differs with the CPU's
    vector units, and trajectories decorrelate within a strain of a few units): a change then
    agrees when it differs from the stored one by at most twice their combined standard
    error; CPU ratios are the machine's and are only noted."""
    from pyfold.scene.study_preset import EVIDENCE

    notes, bad = [], []
    for scene, rows in all_rows.items():
        ev = EVIDENCE.get(scene)
        if ev is None:
            bad.append(f"{scene}: no row in pyfold/scene/study_preset.py")
            continue
        stored = {m.name: m for m in (ev.reference, *ev.settings)}
        for name, m in measured(rows).items():
            old = stored.get(name)
            if old is None:
                bad.append(f"{scene}/{name}: not in pyfold/scene/study_preset.py")
                continue
            if old == m:
                continue
            for est in ("closure_free", "trajectory"):
                a, b = getattr(old, est), getattr(m, est)
                width = 2.0 * math.hypot(getattr(old, f"{est}_stderr"), getattr(m, f"{est}_stderr"))
                line = f"{scene}/{name}/{est}: stored {a:.2f}, recomputed {b:.2f} (2 combined s.e. {width:.2f})"
                (bad if abs(a - b) > width else notes).append(line)
            if old.cpu_ratio != m.cpu_ratio:
                notes.append(f"{scene}/{name}: CPU ratio stored {old.cpu_ratio:.2f}, this machine {m.cpu_ratio:.2f}")
    return notes, bad


def main() -> None:
    from pyfold.sweep import study as sweep_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--analyse-only", action="store_true", help="analyse the finished runs, simulate nothing")
    ap.add_argument("--seeds", type=int, nargs="+", help="override the sweep's seeds")
    ap.add_argument("--np", type=int, default=None, help="MPI ranks per run (default: the sweep file's)")
    ap.add_argument("--no-ranks", action="store_true",
                    help="leave out the ranks lever (studies/sweeps/ci_stokes_settings_ranks.toml)")
    ap.add_argument("--out", type=Path, default=Path("out/speed_accuracy/ci_stokes_settings"))
    sweep_study.add_arguments(ap)
    args = ap.parse_args()
    spec = sweep_study.load_form(Path(__file__).resolve().parents[1] / "sweeps", "ci_stokes_settings", False,
                                 seeds=tuple(args.seeds) if args.seeds else None)
    done = sweep_study.run_sweep(spec, args.sweep_dir or args.out / "sweep", args.executor, args.np,
                                 analyse_only=args.analyse_only)
    runs = {(scene, setting, seed): analyse_run(path) for ((scene, setting), seed), path in done.items()}
    if not args.no_ranks:
        ranked = sweep_study.load_form(Path(__file__).resolve().parents[1] / "sweeps", "ci_stokes_settings_ranks",
                                       False, seeds=tuple(args.seeds) if args.seeds else None)
        # after the serial sweep, one run of 2 ranks at a time; the ranks are the sweep file's
        serial = args.sweep_dir or args.out / "sweep"
        done = sweep_study.run_sweep(ranked, serial.with_name(serial.name + "_ranks"),
                                     args.executor, analyse_only=args.analyse_only)
        runs.update({key: analyse_run(path) for key, path in ranked_runs(done, ranked.resources.np).items()})
    seeds = list(spec.seeds)
    all_rows = {}
    for scene in SCENES:
        settings = [st for st in [*SETTINGS, *RANKED] if any((scene, st, s) in runs for s in seeds)]
        ref_seeds = [s for s in seeds if (scene, REFERENCE, s) in runs]
        if REFERENCE in settings and ref_seeds:
            all_rows[scene] = compare(runs, scene, settings, ref_seeds)
    args.out.mkdir(parents=True, exist_ok=True)
    md = "\n".join(table(sc, rows) for sc, rows in all_rows.items())
    (args.out / "ci_stokes_settings.md").write_text(md)
    dataset(runs, all_rows, seeds).to_netcdf(args.out / "ci_stokes_settings.nc", engine="h5netcdf")
    figure(all_rows, args.out / "ci_stokes_settings.png")
    print(md)
    for scene, rows in all_rows.items():
        print(f"{scene}: as pyfold.scene.study_preset.Measured rows:")
        for m in measured(rows).values():
            print(f"    {m!r},")
    notes, bad = evidence_check(all_rows)
    print("evidence check against pyfold/scene/study_preset.py: "
          + ("agrees" if not bad else "DISAGREES:\n  " + "\n  ".join(bad))
          + "".join(f"\n  note: {n}" for n in notes))
    if bad:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
