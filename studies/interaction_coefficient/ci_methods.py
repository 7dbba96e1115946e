"""Three ways to get the Folgar–Tucker C_I from a concentrated, contacts-only simulation.

Question
    A direct simulation gives a2(t) and its own a4(t). Which interaction coefficient
    C_I does it imply, and do three estimators agree within their error bars?
    (a) trajectory fit, pyfold.fit.fit_parameters, per closure (exact a4, IBOF, FEC);
    (b) steady-state match, pyfold.ci_estimators.ci_steady_state_match: the C_I whose
        Folgar–Tucker steady state with the closure reproduces the stationary a2
        (IBOF, FEC; the error propagated from the s.e. of the stationary mean);
    (c) rate regression, pyfold.ci_estimators.ci_rate_regression: no ODE, the run's
        own a4, da2/dt by centred differences, over the whole run and over the
        stationary part only.
    The stationary part is found by pyfold.steady_state.detect_steady_state (MSER-5;
    blocking standard errors). Error bars: per seed, the estimator's own s.e.
    (time averages); over the ensemble, the s.e. across seeds (std / sqrt(n)), which
    also contains the seed-to-seed scatter of a short run.

Command
    .venv/bin/python studies/interaction_coefficient/ci_methods.py [--seeds 1 2 3 4] [--t-end 100]
    Cost on 2 shared cores: one simulation per seed (200 fibres, β = 10, nL³ = 14.5,
    5000 steps: ~20 s each), then per seed three trajectory fits (the first of each
    closure compiles), two steady-state matches and the regressions: measured
    9.6 min for 4 seeds (first seed 4 min with the compilations, then 1.5–3 min each,
    the trajectory fits over a strain of 100 dominating).

Outputs (under out/interaction_coefficient/)
    ci_methods.nc    C_I and s.e. per seed, method and closure; stationary a2 per seed
    ci_methods.png   C_I per method (seeds and ensemble mean ± s.e.), a2(t) of the seeds
    a printed table
"""
from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr

from pyfold import run_checks
from pyfold.commands import run as run_command
from pyfold.ci_estimators import ci_rate_regression, ci_steady_state_match
from pyfold.fit import fit_parameters
from pyfold.models import FolgarTucker
from pyfold.run_results import open_run
from pyfold.scene.sheared_fibres import sheared_fibres_toml
from pyfold.steady_state import detect_steady_state

# Parameters
COUNT = 200
SIDE = 2.4  # n L^3 = 200 / 2.4^3 = 14.5 (concentrated: > L/d = 10); >= 2 (L + 2R + alpha)
INTERVAL = 0.2  # record spacing [1/gamma_dot] for (b), (c); (a) fits every 2nd record
TRAJECTORY_CLOSURES = ("exact", "ibof", "fec")
STEADY_CLOSURES = ("ibof", "fec")
METHODS = (
    [f"a_fit_{c}" for c in TRAJECTORY_CLOSURES]
    + [f"b_steady_{c}" for c in STEADY_CLOSURES]
    + ["c_rate_all", "c_rate_stationary"]
)


def scene_text(seed: int | str, t_end: float) -> str:
    """The study's scene: COUNT fibres (beta = 10) in a cell of SIDE, contacts with alpha = 0.2 d."""
    return sheared_fibres_toml(
        title="concentrated contacts-only fibres in simple shear (C_I methods study)", side=SIDE, count=COUNT,
        radius=0.05, dt=0.02, t_end=t_end, seed=seed, interval=INTERVAL, snapshot_interval=t_end,
        hydrodynamics="jeffery", collisions="strategy", alpha=0.02)


def simulate(seed: int, t_end: float, folder: Path) -> Path:
    scene = folder / f"seed_{seed}.toml"
    scene.write_text(scene_text(seed, t_end))
    return run_command.run_scene(scene, folder / f"seed_{seed}.h5")


def estimates(run_path: Path) -> dict:
    ds = open_run(run_path)
    L = run_checks.velocity_gradient_of(run_path)
    xi = run_checks.shape_factor_of(ds)
    t, a2, a4 = ds["time"].values, ds["a2"].values, ds["a4"].values
    out: dict = {"t": t, "a2": a2, "xi": xi}
    steady = detect_steady_state(t, a2)
    out["steady"] = steady
    # (a) trajectory fits on every 2nd record
    data = xr.Dataset({"a2": (("time", "i", "j"), a2[::2]), "a4": (("time", "i", "j", "k", "l"), a4[::2])},
                      coords={"time": ("time", t[::2], {"units": "s"})})
    for name in TRAJECTORY_CLOSURES:
        model = FolgarTucker(ci=1e-3, xi=xi, closure="quadratic" if name == "exact" else name)
        res = fit_parameters(data, model, params=("ci",), L=L, closure=name)
        out[f"a_fit_{name}"] = (res.values["ci"], res.stderr["ci"], res.success)
    # (b) steady-state match with the s.e. of the stationary mean
    for name in STEADY_CLOSURES:
        m = ci_steady_state_match(steady.mean, name, xi, L, a2_stderr=steady.stderr)
        out[f"b_steady_{name}"] = (m.ci, m.stderr, steady.stationary)
    # (c) rate regression with the run's own a4
    r = ci_rate_regression(t, a2, a4, L, xi)
    out["c_rate_all"] = (r.ci, r.stderr, True)
    r = ci_rate_regression(t, a2, a4, L, xi, window=(steady.onset_time, t[-1]))
    out["c_rate_stationary"] = (r.ci, r.stderr, steady.stationary)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--t-end", type=float, default=100.0)
    parser.add_argument("--out", type=Path, default=Path("out/interaction_coefficient"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    rows = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            # Solver: direct simulation, then the three estimators
            run_path = simulate(seed, args.t_end, Path(tmp))
            rows.append(estimates(run_path))
            print(f"seed {seed}: done after {time.perf_counter() - start:.0f} s", flush=True)

    # Save
    n = len(rows)
    ci = np.array([[r[m][0] for m in METHODS] for r in rows])
    se = np.array([[r[m][1] for m in METHODS] for r in rows])
    ok = np.array([[bool(r[m][2]) for m in METHODS] for r in rows], dtype=np.int8)
    ens_mean = ci.mean(axis=0)
    ens_se = ci.std(axis=0, ddof=1) / math.sqrt(n) if n > 1 else np.full(len(METHODS), np.nan)
    pooled_se = np.sqrt(np.sum(se**2, axis=0)) / n  # s.e. of the mean from the per-seed time averages
    steady_mean = np.stack([r["steady"].mean for r in rows])
    steady_se = np.stack([r["steady"].stderr for r in rows])
    t = rows[0]["t"]
    result = xr.Dataset(
        {
            "ci": (("seed", "method"), ci, {"units": "1", "long_name": "C_I estimate"}),
            "ci_stderr": (("seed", "method"), se, {"units": "1", "long_name": "s.e. of C_I (time average)"}),
            "ok": (("seed", "method"), ok, {"long_name": "fit converged / steady state judged stationary"}),
            "ci_ensemble": ("method", ens_mean, {"units": "1", "long_name": "mean over seeds"}),
            "ci_ensemble_stderr": ("method", ens_se, {"units": "1", "long_name": "s.e. across seeds"}),
            "ci_pooled_stderr": ("method", pooled_se, {"units": "1",
                                                       "long_name": "s.e. of the mean from per-seed s.e."}),
            "onset_time": ("seed", [r["steady"].onset_time for r in rows], {"units": "s"}),
            "stationary": ("seed", np.array([r["steady"].stationary for r in rows], dtype=np.int8)),
            "steady_message": ("seed", [r["steady"].message for r in rows]),
            "a2_steady": (("seed", "i", "j"), steady_mean, {"units": "1"}),
            "a2_steady_stderr": (("seed", "i", "j"), steady_se, {"units": "1"}),
            "a2": (("seed", "time", "i", "j"), np.stack([r["a2"] for r in rows]), {"units": "1"}),
        },
        coords={"seed": args.seeds, "method": list(METHODS), "time": ("time", t, {"units": "s"}),
                "i": ["x", "y", "z"], "j": ["x", "y", "z"]},
        attrs={"question": "C_I of a concentrated contacts-only suspension by three methods",
               "scene": scene_text("<seed>", args.t_end),
               "xi": rows[0]["xi"], "n_L3": COUNT / SIDE**3},
    )
    result.to_netcdf(args.out / "ci_methods.nc", engine="h5netcdf")
    _figure(result, args.out / "ci_methods.png")
    print(f"\n{COUNT} fibres, beta = 10, nL^3 = {COUNT / SIDE**3:.1f}, strain {args.t_end:g}, seeds {args.seeds}")
    for r, seed in zip(rows, args.seeds):
        s = r["steady"]
        print(f"seed {seed}: onset t = {s.onset_time:.1f}, stationary a2 diag = {np.diag(s.mean).round(4)} "
              f"± {np.diag(s.stderr).round(4)}, a2_xy = {s.mean[0, 1]:.4f} ± {s.stderr[0, 1]:.4f}: {s.message}")
    header = f"{'method':>20} " + " ".join(f"{'seed ' + str(s):>21}" for s in args.seeds)
    print("\n" + header + f" {'mean ± s.e.(seeds)':>24} {'[pooled s.e.]':>13}")
    for k, m in enumerate(METHODS):
        cells = " ".join(f"{ci[i, k]:10.2e}±{se[i, k]:8.1e}{'' if ok[i, k] else '*'}".rjust(21) for i in range(n))
        print(f"{m:>20} {cells} {ens_mean[k]:11.2e} ± {ens_se[k]:9.1e} {pooled_se[k]:13.1e}")
    print("* fit not converged, or the stationary part was not judged stationary (drift / late MSER minimum)")
    print(f"written: {args.out} ({time.perf_counter() - start:.0f} s)")


def _figure(result: xr.Dataset, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 3.8), layout="constrained")
    left, right = fig.subplots(1, 2)
    methods = list(result["method"].values)
    x = np.arange(len(methods))
    for k, seed in enumerate(result["seed"].values):
        left.errorbar(x + 0.08 * (k - 1.5), result["ci"].sel(seed=seed), yerr=result["ci_stderr"].sel(seed=seed),
                      fmt="o", ms=3, capsize=2, alpha=0.6, label=f"seed {seed}")
    left.errorbar(x, result["ci_ensemble"], yerr=result["ci_ensemble_stderr"], fmt="s", color="k", capsize=4,
                  label="mean ± s.e. (seeds)")
    left.axhline(0.0, color="grey", lw=0.8)
    left.axhspan(1e-4, 3e-2, color="tab:green", alpha=0.08, label="published range")
    left.set_yscale("symlog", linthresh=1e-4)
    left.set_xticks(x, methods, rotation=30, ha="right")
    left.set_ylabel("C_I")
    left.legend(frameon=False, fontsize=7)
    for seed in result["seed"].values:
        for (i, j), c in zip([(0, 0), (1, 1), (2, 2), (0, 1)], ["C0", "C1", "C2", "C3"]):
            right.plot(result["time"], result["a2"].sel(seed=seed).values[:, i, j], color=c, lw=0.7, alpha=0.6)
    for seed in result["seed"].values:
        right.axvline(float(result["onset_time"].sel(seed=seed)), color="grey", lw=0.6, ls=":")
    right.set_xlabel("strain γ̇t")
    right.set_ylabel("a_xx, a_yy, a_zz, a_xy")
    fig.savefig(path, dpi=130)


if __name__ == "__main__":
    main()
