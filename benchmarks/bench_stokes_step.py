"""Cost and accuracy of a Stokes-coupled time step of a dense fibre suspension, per
solver setting, against a tight reference.

Question: how many real-3-D-FFT-equivalents does one step of fold_run cost (Stokes
solve, rigid fit, contacts, output), and what accuracy of the particles' motion does
each speed setting keep? Scene: 55 fibres, aspect ratio 10, cell 2.4^3
fibre lengths, 3 voxels per diameter (grid 72^3), kappa 1e3, AB2, dt = 0.01 (strain
0.01 per step), contacts on (strategy); ``--big``: its 128^3 sibling (cell 4.25^3,
305 fibres, same number density and resolution); ``--quick``: 2 voxels per diameter
(grid 48^3), 30 steps.
Command:  nice -n 5 python benchmarks/bench_stokes_step.py [--quick | --big] [--steps N]
          [--only NAME ...] [--np 2] [--build build-wt] [--keep DIR [--reuse]]
Cost (CPU time; wall time depends on the load): --quick ~4 CPU-min for the reference, the baseline
and 7 settings, default (72^3, 100 steps) ~15 CPU-min for the reference and the baseline, --big hours.

Each setting is one ``pyfold run`` of the same scene (same seed, hence the same
initial state) through the build's fold_run (``$PYFOLD_FOLD_RUN``, else
BUILD/fortran/app/fold_run), with a record and a snapshot every step. fold_run prints
``TIMING steps= wall= cpu= cg_iterations=`` for its time loop (placement, planning and
the first solve excluded). The unit of cost is one hot real 3-D FFT of the same grid
(r2c + c2r of one field / 2, FFTW_MEASURE plans, ``bench_stokes_fft N 1e3 R fft``),
measured in this run before and after the settings; the FFT-equivalents per step are
CPU seconds per step / CPU seconds per FFT (CPU time: the machine is shared, wall times
carry the other engineers' load; the wall-based ratio is printed too). With ``--np 2``
every setting runs on two ranks (slabs): CPU seconds are fold_run's rank 0, so the
FFT-equivalents per step are those of one rank (compare iterations per step with the
serial table; the serial FFT is the unit).

Accuracy, against the reference setting (tolerance 1e-10, a solve every step):
* ``vel err``: RMS relative error of the particles' rigid rates over the steps,
  sqrt(sum |dx/dt - ref|^2 + (L/2)^2 |dp/dt - ref|^2) / sqrt(sum |ref rates|^2), the
  rates taken from consecutive snapshots (the velocities the particles actually moved
  with: AB2 combination and contact corrections included); particle-steps crossing a
  periodic face are left out (counted in ``masked``);
* ``rot err``: the same for the axis rates (L/2) dp/dt alone (not dominated by the
  affine translation G x);
* ``a2 err``: max |a2 - a2_ref| over the components after the last step.
Targets: vel err <= 1e-3 and a2 err <= 1e-4 after 100 steps.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

from pyfold.scene.sheared_fibres import sheared_fibres_toml

ROOT = Path(__file__).resolve().parents[1]

#: Speed settings: name -> ([numerics.stokes] overrides, what it tests). The first is the
#: reference, the second the baseline (the current defaults).
SETTINGS: dict[str, tuple[dict, str]] = {
    "reference": ({"tolerance": 1e-10}, "tolerance 1e-10, a solve every step, previous solution as guess"),
    "baseline": ({}, "defaults: tolerance 1e-6, previous solution as guess"),
    "extrapolate": ({"initial_guess": "extrapolate"}, "guess 2 u_n - u_(n-1) of the last two solutions"),
    "tol1e-5": ({"tolerance": 1e-5}, "tolerance 1e-5"),
    "tol1e-4": ({"tolerance": 1e-4}, "tolerance 1e-4"),
    "tol1e-3": ({"tolerance": 1e-3}, "tolerance 1e-3"),
    "tol1e-4_every2": ({"tolerance": 1e-4, "solve_every": 2},
                       "tolerance 1e-4, a solve every 2nd step (velocities extrapolated linearly in between)"),
    "tol1e-4_every4": ({"tolerance": 1e-4, "solve_every": 4}, "tolerance 1e-4, a solve every 4th step"),
    "tol1e-3_every2": ({"tolerance": 1e-3, "solve_every": 2}, "tolerance 1e-3, a solve every 2nd step"),
    "tol1e-3_every3": ({"tolerance": 1e-3, "solve_every": 3}, "tolerance 1e-3, a solve every 3rd step"),
    "tol1e-3_every4": ({"tolerance": 1e-3, "solve_every": 4}, "tolerance 1e-3, a solve every 4th step"),
    # 9.9e-4: with single transforms, kappa = 1e3 needs tolerance <= 9.986e-4 at 72^3
    # (pyfold.native.stokes.kappa_range; docs/physics.md#how-large-a-penalty-the-solver-can-carry)
    "tol1e-3_single": ({"tolerance": 9.9e-4, "fft_precision": "single"},
                       "tolerance 9.9e-4, single-precision transforms of the CG operator"),
    "tol1e-4_single": ({"tolerance": 1e-4, "fft_precision": "single"},
                       "tolerance 1e-4, single-precision transforms of the CG operator"),
    # exact rigidity (fold_stokes_rigid): the tolerance is the rigidity error; "exact_ref" is
    # the kappa -> infinity reference of --reference exact_ref
    "exact_ref": ({"rigidity": "exact", "tolerance": 1e-10}, "exact rigidity, tolerance 1e-10 (kappa -> infinity)"),
    "exact1e-6": ({"rigidity": "exact", "tolerance": 1e-6}, "exact rigidity, tolerance 1e-6"),
    "exact1e-4": ({"rigidity": "exact", "tolerance": 1e-4}, "exact rigidity, tolerance 1e-4"),
    "exact1e-3": ({"rigidity": "exact", "tolerance": 1e-3}, "exact rigidity, tolerance 1e-3"),
    # the multiplier's warm start against a cold start (zero multiplier) every solve
    "exact1e-3_cold": ({"rigidity": "exact", "tolerance": 1e-3, "warm_start": False},
                       "exact rigidity, tolerance 1e-3, cold start every solve"),
    "tol1e-3_cold": ({"tolerance": 1e-3, "warm_start": False}, "tolerance 1e-3, cold start every solve"),
    "exact1e-2": ({"rigidity": "exact", "tolerance": 1e-2}, "exact rigidity, tolerance 1e-2"),
}


def scene_text(size: float, count: int, cells_per_diameter: int, steps: int, stokes: dict, seed: int) -> str:
    dt = 0.01
    return sheared_fibres_toml(
        title="bench_stokes_step", side=size, count=count, radius=0.05, dt=dt, t_end=dt * steps, seed=seed,
        interval=dt, snapshot_interval=dt, checkpoint_interval=0, hydrodynamics="stokes", collisions="strategy",
        time_scheme="ab2", stokes={"cells_per_diameter": cells_per_diameter, "kappa": 1e3,
                                   "max_grid_points": 4000000, "max_iterations": 20000, **stokes})


def run_setting(workdir: Path, name: str, text: str, fold_run: Path, reuse: bool = False, ranks: int = 1) -> dict:
    """One pyfold run on ``ranks`` ranks (or, with reuse, the kept run of the same scene text,
    rank count and its log)."""
    name = name if ranks == 1 else f"{name}_np{ranks}"
    scene = workdir / f"{name}.toml"
    out = workdir / f"{name}.h5"
    log = workdir / f"{name}.log"
    if not (reuse and scene.is_file() and scene.read_text() == text and out.is_file() and log.is_file()):
        scene.write_text(text)
        env = dict(os.environ, PYFOLD_FOLD_RUN=str(fold_run))
        pyfold = Path(sys.executable).parent / "pyfold"
        cmd = [str(pyfold), "run", str(scene), "-o", str(out), "--force", "--np", str(ranks)]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        log.write_text(proc.stdout + "\n" + proc.stderr)
        if proc.returncode != 0:
            raise SystemExit(f"{name}: pyfold run failed (exit {proc.returncode}):\n{log.read_text()[-3000:]}")
    timing = [dict(re.findall(r"(\w+)=\s*([-+.\dEe]+)", line)) for line in log.read_text().splitlines()
              if "TIMING" in line]
    if not timing or len(timing[-1]) < 4:
        raise SystemExit(f"{name}: no TIMING line from fold_run:\n{log.read_text()[-3000:]}")
    t = timing[-1]
    steps = int(t["steps"])
    with h5py.File(out) as f:
        rec = dict(x=f["x"][()], p=f["p"][()], a2=f["a2"][()], iters=f["stokes_iterations"][()],
                   L=float(f["setup/resolved/family_length"][0]), cell=f["setup/resolved/cell_lengths"][()],
                   dt=float(f["setup/resolved/dt"][()]),
                   grid=tuple(int(v) for v in f["setup/resolved/stokes_grid"][()]))
    rec.update(steps=steps, wall=float(t["wall"]) / steps, cpu=float(t["cpu"]) / steps,
               cg=int(t["cg_iterations"]) / steps, cg_max=int(rec["iters"][1:].max()))
    return rec


def rates(r: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """dx/dt, (L/2) dp/dt between consecutive snapshots; mask of periodic crossings."""
    dx = np.diff(r["x"], axis=0)
    jump = np.any(np.abs(dx) > 0.25 * r["cell"].min(), axis=2)
    return dx / r["dt"], 0.5 * r["L"] * np.diff(r["p"], axis=0) / r["dt"], jump


def accuracy(r: dict, ref: dict) -> dict:
    v, w, jv = rates(r)
    v0, w0, j0 = rates(ref)
    keep = ~(jv | j0)
    dv = np.sum((v - v0)[keep] ** 2) + np.sum((w - w0)[keep] ** 2)
    vel = np.sqrt(dv / (np.sum(v0[keep] ** 2) + np.sum(w0[keep] ** 2)))
    rot = np.sqrt(np.sum((w - w0)[keep] ** 2) / np.sum(w0[keep] ** 2))
    return dict(vel=vel, rot=rot, a2=float(np.abs(r["a2"][-1] - ref["a2"][-1]).max()), masked=int((~keep).sum()))


def fft_time(exe: Path, n: int, repeats: int = 5) -> tuple[float, float]:
    out = subprocess.run([str(exe), str(n), "1e3", str(repeats + 1), "fft"], capture_output=True, text=True,
                         check=True).stdout
    rows = re.findall(r"t_fft_wall=\s*(\S+) t_fft_cpu=\s*(\S+)", out)[1:]
    return statistics.median(float(a) for a, _ in rows), statistics.median(float(b) for _, b in rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=str(ROOT / "build" / "editable"))
    ap.add_argument("--quick", action="store_true", help="48^3 grid (2 voxels per diameter), 30 steps")
    ap.add_argument("--big", action="store_true", help="the 128^3 sibling (305 fibres, cell 4.25^3)")
    ap.add_argument("--steps", type=int, default=None, help="steps (default 100, --quick 30)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", nargs="*", default=None, help="settings to run besides the reference and baseline")
    ap.add_argument("--reference", default="reference", choices=list(SETTINGS),
                    help="the setting the accuracy is measured against (exact_ref: the kappa -> infinity limit)")
    ap.add_argument("--np", type=int, default=1, help="MPI ranks of every run (pyfold run --np)")
    ap.add_argument("--keep", default=None, help="folder to keep the run files in")
    ap.add_argument("--reuse", action="store_true",
                    help="reuse the runs kept in --keep whose scene is unchanged (e.g. the reference)")
    args = ap.parse_args()
    build = Path(args.build)
    fold_run = Path(os.environ.get("PYFOLD_FOLD_RUN") or build / "fortran" / "app" / "fold_run")
    # private copies: an editable import elsewhere may relink the build-tree binaries mid-run
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_stokes_step_"))
    tmp.mkdir(parents=True, exist_ok=True)
    exe = tmp / "bench_stokes_fft"
    shutil.copy2(build / "fortran" / "stokes" / "tests" / "bench_stokes_fft", exe)
    fr = tmp / "fold_run"
    shutil.copy2(fold_run, fr)

    # Parameters
    if args.big:
        size, count, cpd = 4.25, 305, 3
    else:
        size, count, cpd = 2.4, 55, (2 if args.quick else 3)
    steps = args.steps or (30 if args.quick else 100)
    names = list(SETTINGS)[:2] + [k for k in list(SETTINGS)[2:] if args.only is None or k in args.only]
    if args.reference not in names:
        names.insert(0, args.reference)

    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    n = 128 if args.big else int(round(size / (0.1 / cpd)))
    fft_before = fft_time(exe, n)
    runs = {}
    for name in names:
        text = scene_text(size, count, cpd, steps, SETTINGS[name][0], args.seed)
        runs[name] = run_setting(tmp, name, text, fr, args.reuse, args.np)
        r = runs[name]
        print(f"  ran {name}: grid {r['grid']}, {r['steps']} steps, {r['cg']:.1f} CG iterations/step, "
              f"{r['cpu']:.3f} CPU-s/step (load {os.getloadavg()[0]:.2f})", flush=True)
    if runs[args.reference]["grid"][0] != n:
        raise SystemExit(f"grid {runs[args.reference]['grid']} is not the expected {n}^3")
    fft_after = fft_time(exe, n)
    fw0, fc0 = 0.5 * (fft_before[0] + fft_after[0]), 0.5 * (fft_before[1] + fft_after[1])
    print(f"load average after the runs: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")

    ref, base = runs[args.reference], runs["baseline"]
    print(f"accuracy against: {args.reference} ({SETTINGS[args.reference][1]})")
    print(f"\n{count} fibres (aspect ratio 10), cell {size}^3 L, grid {'x'.join(map(str, ref['grid']))}, "
          f"kappa 1e3, AB2, dt 0.01, {steps} steps, np = {args.np}; one hot FFT = {fc0:.3e} CPU-s ({fw0:.3e} s wall; "
          f"before/after the runs {fft_before[1]:.3e}/{fft_after[1]:.3e} CPU-s)")
    head = (f"{'setting':<16} {'iter/step':>9} {'max':>5} {'CPU-s/step':>10} {'FFT-eq/step':>11} {'(wall)':>7} "
            f"{'x base':>6} {'FFT-eq/iter':>11} {'vel err':>9} {'rot err':>9} {'a2 err':>9} {'masked':>6}")
    print(head)
    for name in names:
        r = runs[name]
        acc = accuracy(r, ref)
        eq = r["cpu"] / fc0
        print(f"{name:<16} {r['cg']:>9.1f} {r['cg_max']:>5d} {r['cpu']:>10.3f} {eq:>11.0f} {r['wall'] / fw0:>7.0f} "
              f"{base['cpu'] / r['cpu']:>6.2f} {eq / max(r['cg'], 1e-9):>11.1f} {acc['vel']:>9.2e} "
              f"{acc['rot']:>9.2e} {acc['a2']:>9.2e} {acc['masked']:>6d}")
    print("\n" + "\n".join(f"  {k}: {SETTINGS[k][1]}" for k in names))
    print("FFT-eq/step = CPU s per step / CPU s of one hot FFT (same run); 'x base' = baseline CPU / setting CPU; "
          "FFT-eq/iter includes the per-step work outside CG (voxelisation, rigid fit, stress, contacts, output)")
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
