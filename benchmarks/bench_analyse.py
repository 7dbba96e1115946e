"""Benchmark: wall and CPU time of ``pyfold analyse`` in a first (cold) and a second (warm) process.

Question
    How long does ``pyfold analyse RUN.h5`` take on a run of the default scene
    (data/scenes/default.toml: 128 fibres, beta = 10, t_end = 400, 801 records;
    6 closures) in a new process with an empty JAX compilation cache (cold), and in
    a second process that finds the compiled programs in the cache (warm)? Where
    does the time go?

Method
    Each repeat: a fresh, empty cache folder (``PYFOLD_JAX_CACHE``), then one child
    process running what ``pyfold analyse`` runs (pyfold/commands/analyse.py: the
    checks, ``trajectory_fit.fit_and_compare`` with its figures, the results file) (cold),
    then another child on the same cache (warm). A child times its stages: the
    imports, opening and checking the run (``run_checks.open_checked_run``), the fits
    (``pyfold.fast_fit.fit_ci_rk4`` through ``trajectory_fit.fit_ci_per_closure``), the
    closure errors (computed beside the fits, so the two overlap), the figures and the
    results file; each in wall time and in the process's CPU time (all threads). The
    parent reports for each of cold / warm the median over ``--repeats`` of the
    child's wall time (from its start to its exit, measured by the parent) and CPU
    time (user + system, from ``resource.getrusage(RUSAGE_CHILDREN)``), each stage's
    median, and the load average before and after (the machine is shared: compare CPU
    times, and wall times only at a low load). ``--cores N`` pins the children to N
    cores (what the fits run side by side on). No time is asserted anywhere.

Command
    nice -n 0 .venv/bin/python benchmarks/bench_analyse.py RUN.h5 [--repeats 3] [--cores N]
    RUN.h5: e.g. ``pyfold run data/scenes/default.toml -o out/bench_analyse/default.h5``
    (about 40 s on one core).

Cost on 2 cores
    About (cold + warm) x repeats analyses: two to three minutes at 3 repeats on an
    idle machine (most of it in the cold compilations; FEC ~0.05 ms per evaluation).

Outputs
    A table on stdout, and ``out/bench_analyse/bench_analyse.json`` (the raw timings).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def child(run_path: str, out: str) -> None:
    """The stages of ``pyfold analyse`` (pyfold/commands/analyse.py), each timed; prints JSON."""
    stages: dict[str, float] = {}
    cpu: dict[str, float] = {}
    t0, c0 = time.perf_counter(), time.process_time()

    def mark(name: str, t: float, c: float) -> tuple[float, float]:
        stages[name], cpu[name] = time.perf_counter() - t, time.process_time() - c
        return time.perf_counter(), time.process_time()

    from pyfold import run_checks, trajectory_fit
    from pyfold.commands import analyse  # noqa: F401  (the command's import cost counted here)

    t, c = mark("imports", t0, c0)
    path = Path(run_path)
    closures = run_checks.check_closures(",".join(run_checks.DEFAULT_CLOSURES))
    ds = run_checks.open_checked_run(path)
    closures = run_checks.check_closures(closures, dim=ds.sizes["i"])
    run_checks.check_output_folder(Path(out))
    t, c = mark("open_and_check", t, c)
    chain = trajectory_fit.fit_and_compare(path, Path(out), closures=closures, run=ds, quiet=True)
    t, c = mark("fit_errors_figures", t, c)
    trajectory_fit.results_dataset(chain).to_netcdf(Path(out) / "results.nc", engine="h5netcdf")
    mark("results_file", t, c)
    stages.update({f"  {k}": v for k, v in chain.seconds.items()})
    stages["in_process"], cpu["in_process"] = time.perf_counter() - t0, time.process_time() - c0
    fits = chain.fits
    ci = {str(n): float(v) for n, v in zip(fits["closure"].values, fits["ci"].values)}
    print(json.dumps({"stages": stages, "stages_cpu": cpu, "ci": ci}))


def run_child(run_path: str, cache: str, out: str, cores: int | None) -> dict:
    env = dict(os.environ, PYFOLD_JAX_CACHE=cache)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    pin = (lambda: os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:cores])) if cores else None
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, __file__, "--child", run_path, out], env=env, capture_output=True,
                          text=True, check=True, preexec_fn=pin)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result.update(wall=wall, cpu=cpu)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_file", help="a run of the default scene (RUN.h5)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cores", type=int, default=None, help="pin the children to this many cores")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("child_out", nargs="?", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.run_file, args.child_out)
        return
    if args.repeats < 1:
        parser.error("--repeats: must be an integer >= 1")
    if args.cores is not None and not 1 <= args.cores <= len(os.sched_getaffinity(0)):
        parser.error(f"--cores: must be an integer in [1, {len(os.sched_getaffinity(0))}]")
    outdir = ROOT / "out" / "bench_analyse"
    outdir.mkdir(parents=True, exist_ok=True)
    records = {"cold": [], "warm": []}
    load = [os.getloadavg()]
    for k in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="pyfold-jax-cache-") as cache:
            for kind in ("cold", "warm"):
                res = run_child(args.run_file, cache, str(outdir / f"analysis_{kind}"), args.cores)
                records[kind].append(res)
                print(f"repeat {k + 1} {kind}: wall {res['wall']:.1f} s, cpu {res['cpu']:.1f} s, "
                      f"load {os.getloadavg()[0]:.2f}", flush=True)
        load.append(os.getloadavg())
    print(f"\nload average (1, 5, 15 min) at the start {load[0]}, at the end {load[-1]}")
    for kind in ("cold", "warm"):
        rs = records[kind]
        print(f"\n{kind}: median over {len(rs)}: wall {statistics.median(r['wall'] for r in rs):.2f} s, "
              f"cpu {statistics.median(r['cpu'] for r in rs):.2f} s")
        for stage in rs[0]["stages"]:
            line = f"  {stage:<20} {statistics.median(r['stages'][stage] for r in rs):8.2f} s wall"
            if stage in rs[0]["stages_cpu"]:
                line += f" {statistics.median(r['stages_cpu'][stage] for r in rs):8.2f} s cpu"
            print(line)
    print("\nfitted C_I:", records["warm"][-1]["ci"])
    (outdir / "bench_analyse.json").write_text(json.dumps({"load": load, "cores": args.cores, **records}, indent=1))
    print(f"raw timings: {outdir / 'bench_analyse.json'}")


if __name__ == "__main__":
    main()
