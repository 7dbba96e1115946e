"""Cost of a fold_run step with the collision strategy vs the number of fibres.

Question: does the seed's collision strategy with cell lists scale as O(N) at fixed
concentration, and how much faster is it than the O(N^2) naive search?

Command (serial; a few minutes on one core):
    .venv/bin/python benchmarks/bench_contacts.py [--sizes 1000 3000 10000 30000 100000] [--repeats 3]

Scene: fibres L = 1, aspect ratio 20 (R = 0.025), n L^3 = 2 (cell edge (N/2)^(1/3)),
isotropic, placed by fold_placement (alpha = 0.01), simple shear gamma_dot = 1,
dt = 0.01, Jeffery kinematics. Time per step = (time of a K+1-step run minus that
of a 1-step run) / K, so start-up, file I/O and the step-0 record cancel; the median
over repeats is reported. K = max(4, 2e5 / N) (about 0.2 s of stepping at ~1 us per
fibre and step, well above the few-ms scatter of the start-up that the subtraction
leaves); naive is timed over the same K steps as the strategy it is compared with
(sweeps per step vary from step to step), once by default (--naive-repeats: it is
O(N^2), ~0.3 s per step at N = 2000), recording its sweeps in that same run. Time
is the CPU time (user + system) of the fold_run child process by default (`--clock
wall` for wall time): the machine is shared and wall time is noisy. Prints the log-log slope of time per step vs N (goal <= 1.1),
strategy / naive at N = 2000 (goal >= 50x; naive is the seed's literal loop: every
sweep rescans all pairs by the O(N^2) double loop), and the contact sweeps per step
(fold_run's contact_iterations record, one record per step). Not a test.
"""
from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "micro"))
from test_run_common import write_run_file, xi_of  # noqa: E402

from pyfold.commands.run import find_fold_run  # noqa: E402

# Parameters
N_L3 = 2.0
BETA = 20.0
K_MIN = 4
# K = max(K_MIN, STEPPED_FIBRES / N) steps are timed
STEPPED_FIBRES = 200_000


def scene(n: int, seed: int = 1) -> dict:
    from pyfold.native.geometry import FIBRE, Cell, place_particles

    cell = (n / N_L3) ** (1.0 / 3.0)
    R = 0.5 / BETA
    c = Cell(lengths=(cell, cell, cell), shear_rate=1.0)
    pl = place_particles(c, np.full(n, FIBRE), np.full(n, R), np.full(n, 1.0), alpha=0.01, seed=seed)
    return dict(x=pl.x, p=pl.p, radius=R, length=1.0, xi=xi_of(BETA), cell_lengths=(cell, cell, cell),
                shear_rate=1.0, dt=0.01, alpha=0.01)


CLOCK = "cpu"
SWEEPS: list[int] = []


def _child_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_time(exe: Path, sc: dict, steps: int, mode: int, tmp: Path, record_sweeps: bool = False) -> float:
    import h5py

    path = tmp / f"b{steps}_{mode}.h5"
    # timed runs write no per-step record; one extra run records every step's sweeps
    write_run_file(path, **sc, t_end=steps * 0.01, collisions=mode, contact_max_iter=100, on_contact_cap=1,
                   output_every=1 if record_sweeps else 1000)
    t0, c0 = time.perf_counter(), _child_cpu()
    proc = subprocess.run([str(exe), str(path)], capture_output=True, text=True)
    dt = time.perf_counter() - t0 if CLOCK == "wall" else _child_cpu() - c0
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr)
    if record_sweeps:
        with h5py.File(path) as f:
            SWEEPS.extend(int(v) for v in f["contact_iterations"][1:])  # steps 1.. (record 0: initial state)
    path.unlink()
    return dt


def per_step(exe: Path, sc: dict, mode: int, repeats: int, tmp: Path, record_in_timed: bool = False) -> float:
    """Median CPU (or wall) time per step over K = max(K_MIN, STEPPED_FIBRES / N) steps.
    record_in_timed: record the sweeps in the timed runs (per-step records cost ~1 ms,
    negligible for naive) instead of an extra run."""
    k = max(K_MIN, -(-STEPPED_FIBRES // len(sc["x"])))
    samples = [(run_time(exe, sc, k + 1, mode, tmp, record_sweeps=record_in_timed and r == 0)
                - run_time(exe, sc, 1, mode, tmp)) / k for r in range(repeats)]
    if not record_in_timed:
        run_time(exe, sc, k + 1, mode, tmp, record_sweeps=True)
    return float(np.median(samples))


def sweeps_text() -> str:
    s = np.array(SWEEPS)
    SWEEPS.clear()
    return f"correcting sweeps/step median {np.median(s):.0f}, max {s.max()}; all-pair scans = sweeps + 1"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 3000, 10000, 30000, 100000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--naive-n", type=int, default=2000)
    ap.add_argument("--naive-repeats", type=int, default=1)
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu")
    args = ap.parse_args()
    global CLOCK
    CLOCK = args.clock
    built = find_fold_run()  # PyfoldError with the places it looked in when not built

    # Run
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        # a private copy: an editable rebuild may relink the build-tree binary mid-run
        exe = tmp / "fold_run"
        shutil.copy2(built, exe)
        rows = []
        for n in args.sizes:
            t = per_step(exe, scene(n), 2, args.repeats, tmp)
            rows.append((n, t))
            print(f"N = {n:7d}  strategy: {1e3 * t:9.2f} ms/step  ({1e6 * t / n:6.2f} us per fibre; {sweeps_text()})",
                  flush=True)
        ns, ts = np.array(rows).T
        slope = np.polyfit(np.log(ns), np.log(ts), 1)[0]
        print(f"log-log slope of {CLOCK} time per step vs N: {slope:.3f} (goal <= 1.1)")

        sc = scene(args.naive_n)
        t_s = per_step(exe, sc, 2, args.repeats, tmp)
        sw_s = sweeps_text()
        t_n = per_step(exe, sc, 1, args.naive_repeats, tmp, record_in_timed=True)
        sw_n = sweeps_text()
        print(f"N = {args.naive_n}: strategy {1e3 * t_s:.2f} ms/step ({sw_s}), naive {1e3 * t_n:.2f} ms/step "
              f"({sw_n}), naive/strategy = {t_n / t_s:.1f}x (goal >= 50x; {CLOCK} time)")


if __name__ == "__main__":
    main()
