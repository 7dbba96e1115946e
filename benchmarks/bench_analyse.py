"""Benchmark: wall and CPU time of ``pyfold analyse`` in a first (cold) and a second (warm) process.

Question
    How long does ``pyfold analyse RUN.h5`` take on a run of the default scene
    (data/scenes/default.toml: 128 fibres, beta = 10, t_end = 400, 801 records;
    6 closures) in a new process with an empty JAX compilation cache (cold), and in
    a second process that finds the compiled programs in the cache (warm)? Where
    does the time go?

Method
    Each repeat: a fresh, empty cache folder (``PYFOLD_JAX_CACHE``), then one child
    process running the stages of ``pyfold analyse`` (cold), then another child on
    the same cache (warm). A child times: the imports, opening and checking the run
    (``pipeline.open_checked_run``), the fit of each closure
    (``pyfold.fast_fit.fit_ci_rk4`` through ``pipeline.fit_ci_per_closure``), the
    closure errors, the figures and the results file. The parent reports for each of
    cold / warm the median over ``--repeats`` of the child's wall time (from its start
    to its exit, measured by the parent) and CPU time (user + system, from
    ``resource.getrusage(RUSAGE_CHILDREN)``), each stage's median wall time, and the
    load average before and after (the machine is shared: compare CPU times, and wall
    times only at a low load). No time is asserted anywhere.

Command
    nice -n 0 .venv/bin/python benchmarks/bench_analyse.py RUN.h5 [--repeats 3]
    RUN.h5: e.g. ``pyfold run data/scenes/default.toml -o out/bench_analyse/default.h5``
    (a few minutes on one core).

Cost on 2 cores
    About (cold + warm) x repeats analyses: a few minutes at 3 repeats on an idle
    machine (most of it in compiling; FEC ~0.04 ms per evaluation).

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
    t0 = time.perf_counter()
    from pyfold import pipeline
    from pyfold.fast_fit import fit_ci_rk4  # noqa: F401  (import cost counted here)

    stages["imports"] = time.perf_counter() - t0
    t = time.perf_counter()
    path = Path(run_path)
    closures = pipeline.check_closures(",".join(pipeline.DEFAULT_CLOSURES))
    ds = pipeline.open_checked_run(path)
    closures = pipeline.check_closures(closures, dim=ds.sizes["i"])
    pipeline.check_output_folder(Path(out))
    stages["open_and_check"] = time.perf_counter() - t
    L = pipeline.velocity_gradient_of(path)
    xi = pipeline.shape_factor_of(ds)
    fits = []
    for name in closures:
        t = time.perf_counter()
        fits.append(pipeline.fit_ci_per_closure(ds, L, (name,), xi))
        stages[f"fit_{name}"] = time.perf_counter() - t
    import xarray as xr

    fits = xr.concat(fits, dim="closure")
    t = time.perf_counter()
    errors = pipeline._closure_errors_padded(ds, [c for c in closures if c != "exact"], L)
    stages["closure_errors"] = time.perf_counter() - t
    t = time.perf_counter()
    pipeline._figures(ds, fits, errors, L, Path(out))
    stages["figures"] = time.perf_counter() - t
    t = time.perf_counter()
    chain = pipeline.ChainResult(run_path=path, fits=fits, closure_errors=errors)
    pipeline.results_dataset(chain).to_netcdf(Path(out) / "results.nc", engine="h5netcdf")
    stages["results_file"] = time.perf_counter() - t
    ci = {str(c): float(v) for c, v in zip(fits["closure"].values, fits["ci"].values)}
    print(json.dumps({"stages": stages, "ci": ci}))


def run_child(run_path: str, cache: str, out: str) -> dict:
    env = dict(os.environ, PYFOLD_JAX_CACHE=cache)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, __file__, "--child", run_path, out], env=env, capture_output=True,
                          text=True, check=True)
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
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("child_out", nargs="?", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.run_file, args.child_out)
        return
    if args.repeats < 1:
        parser.error("--repeats: must be an integer >= 1")
    outdir = ROOT / "out" / "bench_analyse"
    outdir.mkdir(parents=True, exist_ok=True)
    records = {"cold": [], "warm": []}
    load = [os.getloadavg()]
    for k in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="pyfold-jax-cache-") as cache:
            for kind in ("cold", "warm"):
                res = run_child(args.run_file, cache, str(outdir / f"analysis_{kind}"))
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
            print(f"  {stage:<16} {statistics.median(r['stages'][stage] for r in rs):8.2f} s wall")
    print("\nfitted C_I:", records["warm"][-1]["ci"])
    (outdir / "bench_analyse.json").write_text(json.dumps({"load": load, **records}, indent=1))
    print(f"raw timings: {outdir / 'bench_analyse.json'}")


if __name__ == "__main__":
    main()
