"""Cost of the Stokes solver: one CG iteration in real-3-D-FFT units, CG iterations
against kappa and grid, and what np = 2 buys.

Question: how close is an iteration to its floor (6 real FFTs in the 3-D stencil form:
3 velocity components back, 3 force components forward; 10 in the spectral form), at
64^3 and 128^3; how do the
iterations to a 1e-6 residual grow with the contrast kappa and the grid; and what
is the speed-up of np = 2 slabs over np = 1 at 128^3?
Command:  python benchmarks/bench_stokes_fft.py [--build build/editable] [--repeats 5] [--quick]
          python benchmarks/bench_stokes_fft.py --mpi [--grids 64 128] [--rounds 5]
          python benchmarks/bench_stokes_fft.py --project T_C ALPHA BETA [--grids 128]
          python benchmarks/bench_stokes_fft.py --precision [--grids 72 128] [--rounds 3]
          python benchmarks/bench_stokes_fft.py --forms [--grids 72] [--rounds 3]
          python benchmarks/bench_stokes_fft.py --rigidity [--grids 32 64]
Cost: ~3 min (--quick: ~1 min; --mpi: 2-5 min per round of 64^3 and 128^3, 4.5 min at load 10). Runs fortran/stokes/tests/bench_stokes_fft (FFTW_MEASURE
plans, a sphere of radius n/8 on a sheared lattice, simple shear) and prints medians
over repeats, with the load average before and after: the machine is shared, so read
ratios (iteration / FFT, measured back to back in one process), not absolute times.

Two FFT units are reported: ``hot`` (one field transformed back and forth, in cache)
and ``seq`` (c2r then r2c of each of the 5 strain fields in turn, as the iteration
does); ``ratio_seq`` is the one to compare with the floor of 10.

``--precision`` answers only: what does a CG iteration cost with single-precision
transforms of the operator (fft_precision single) against double, serial, per grid:
rounds of double then single back to back, medians of the CPU seconds per iteration,
of the iteration in units of one hot double FFT of the same process (CPU time), of the
hot single FFT against the double one (wall), and the speed-up double/single.

``--forms`` answers only: what does a serial CG iteration (double) cost in the stencil
form (3 + 3 transforms and a real-space pass over the voxels with eta /= eta_f, the
3-D default) against the spectral form (5 + 5 transforms), on a small sphere (0.8 % of
the cell) and a large one (27 %): rounds of the four back to back, medians of the
iteration in units of one hot double FFT (CPU time). The stencil pass grows with the
covered fraction, the spectral form does not: the crossover sets
STENCIL_FRACTION_MAX in fortran/stokes/fold_stokes_fft.f90.

``--rigidity`` answers only: what does one solve cost with exact rigidity
(numerics.stokes.rigidity = "exact", fold_stokes_rigid) beside the penalised one, serial:
per grid, the sphere of radius n/8 (centred, simple shear, cold start, through
``pyfold.native.stokes.solve_particles``) solved by the penalty (kappa 1e3 and 1e4) and by
the exact solve, at tolerances 1e-6 and 1e-3: CG iterations, CPU seconds, and the solve
in units of one hot double FFT of the same grid (CPU time, ``bench_stokes_fft N 1e3 R fft``,
mean of before and after), per solve and per iteration (voxelisation, plans and rigid fit
included, so the per-iteration figure is an upper bound of the iteration's cost).

``--mpi`` answers only the parallel question (docs/physics.md, "Parallel scaling of
the slab decomposition"): per round and grid, back to back, np = 1 (serial FFTW),
np = 2 with the transposed spectrum (one all-to-all per transform, what fold_run
uses), np = 2 with the natural spectrum (two all-to-alls) and np = 2 with the 5 strain
fields of a pass in one howmany = 5 plan against one at a time. It prints the load
average before each round and the medians over rounds of the speed-ups
t(np=1)/t(np=2) per CG iteration and per hot FFT: a busy machine stalls both ranks of
an all-to-all whenever either is descheduled, so quote them with the load.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import statistics
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1")


def _run(exe: Path, args: list[str], ranks: int) -> str:
    cmd = [str(exe), *args]
    if ranks > 1:
        cmd = ["mpirun", "-np", str(ranks), "--oversubscribe", *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, check=True, env=ENV).stdout


def cost(exe: Path, n: int, ranks: int, repeats: int, backend: str = "auto", precision: str = "double",
         shape: str = "sphere") -> dict:
    """Medians over repeats of the BENCH lines (first repeat dropped: page faults, caches)."""
    out = _run(exe, [str(n), "1000", str(repeats + 1), "cost", shape, backend, precision], ranks)
    rows = [dict((k, float(v)) for k, v in re.findall(r"(\w+)=\s*(\S+)", line))
            for line in out.splitlines() if line.startswith("BENCH")][1:]
    return {key: statistics.median(r[key] for r in rows) for key in rows[0]}


def batch(exe: Path, n: int, repeats: int) -> dict:
    """Medians over repeats of the BATCH lines of np = 2 (first repeat dropped)."""
    out = _run(exe, [str(n), "1000", str(repeats + 1), "batch"], 2)
    rows = [dict((k, float(v)) for k, v in re.findall(r"(\w+)=\s*(\S+)", line))
            for line in out.splitlines() if line.startswith("BATCH")][1:]
    return {key: statistics.median(r[key] for r in rows) for key in rows[0]}


def alltoall(exe: Path, n: int, repeats: int) -> dict:
    """Medians over repeats of the A2A lines of np = 2 (first repeat dropped)."""
    out = _run(exe, [str(n), "1000", str(repeats + 1), "a2a"], 2)
    rows = [dict((k, float(v)) for k, v in re.findall(r"(\w+)=\s*(\S+)", line))
            for line in out.splitlines() if line.startswith("A2A")][1:]
    return {key: statistics.median(r[key] for r in rows) for key in rows[0]}


#: Transforms, hence slab all-to-alls, per CG iteration in the 3-D stencil form
#: (fortran/stokes/fold_stokes_fft.f90; the spectral form makes 10)
TRANSFORMS = 6


def slab_a2a(p: int, n: int, alpha: float, beta: float) -> float:
    """Seconds of one slab all-to-all of the half spectrum on p ranks: p - 1 messages of V/p^2."""
    v = 16.0 * (n // 2 + 1) * n * n
    return (p - 1) * (alpha + v / (p * p * beta))


def pencil_a2a(p: int, n: int, alpha: float, beta: float) -> float:
    """Seconds of the two all-to-alls of a pencil transform on a p1 x p2 = p process grid
    (p1 the largest power of two <= sqrt(p)): one in each sub-communicator, p_i - 1
    messages of V/(p p_i)."""
    p1 = 2 ** (p.bit_length() // 2) if p & (p - 1) == 0 else max(d for d in range(1, int(p ** 0.5) + 1) if p % d == 0)
    v = 16.0 * (n // 2 + 1) * n * n
    return sum((q - 1) * (alpha + v / (p * q * beta)) for q in (p1, p // p1))


def projection(n: int, t_c: float, alpha: float, beta: float, ps: list[int]) -> None:
    """Strong scaling at n^3: t(P) = t_c/P + 6 a2a(P) per CG iteration (TRANSFORMS,
    one all-to-all each for slabs, two for pencils); slabs need P <= n."""
    print(f"\nprojected strong scaling at {n}^3 (t_c = {t_c:.3e} s, alpha = {alpha:.2e} s, beta = {beta:.2e} B/s)")
    print(f"{'P':>6} {'slab t_iter':>12} {'speed-up':>9} {'pencil t_iter':>14} {'speed-up':>9}")
    for p in ps:
        slab = t_c / p + TRANSFORMS * slab_a2a(p, n, alpha, beta) if p <= n else float("nan")
        pen = t_c / p + TRANSFORMS * pencil_a2a(p, n, alpha, beta)
        print(f"{p:>6} {slab:>12.3e} {t_c / slab:>9.1f} {pen:>14.3e} {t_c / pen:>9.1f}")
    # weak scaling: n^3/P = n0^3 points per rank, compute per rank ~ log2(n) (the FFTs)
    w = n ** 3 // 2
    print(f"\nprojected weak scaling at {w} points per rank (compute t_c/2 log2(n)/log2({n}); slabs need P <= n)")
    print(f"{'P':>6} {'n':>6} {'slab t_iter':>12} {'efficiency':>10} {'pencil t_iter':>14} {'efficiency':>10}")
    t2 = t_c / 2 + TRANSFORMS * slab_a2a(2, n, alpha, beta)
    for p in [2, 16, 128, 1024, 8192, 65536]:
        m = round((w * p) ** (1.0 / 3.0))
        comp = t_c / 2 * math.log2(m) / math.log2(n)
        slab = comp + TRANSFORMS * slab_a2a(p, m, alpha, beta) if p <= m else float("nan")
        pen = comp + TRANSFORMS * pencil_a2a(p, m, alpha, beta)
        print(f"{p:>6} {m:>6} {slab:>12.3e} {t2 / slab:>10.2f} {pen:>14.3e} {t2 / pen:>10.2f}")


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def mpi_rounds(exe: Path, grids: list[int], rounds: int, repeats: int) -> None:
    """np = 2 against np = 1, transposed against natural spectrum, batched FFTs; medians over rounds."""
    ratios: dict[tuple[int, str], list[float]] = {}
    t_c: dict[int, list[float]] = {}
    a2a: dict[int, list[dict]] = {}
    print(f"{'round':>5} {'grid':>6} {'load 1/5/15 min':>17} {'t_iter np1':>11} {'np2 tr':>10} {'np2 nat':>10} "
          f"{'t_fft np1':>10} {'np2 tr':>10} {'np2 nat':>10} {'batch/sep':>9}")
    for r in range(rounds):
        for n in grids:
            before = load()
            c1 = cost(exe, n, 1, repeats, "auto")
            c2 = cost(exe, n, 2, repeats, "auto")
            cn = cost(exe, n, 2, repeats, "natural")
            b = batch(exe, n, repeats)
            a = alltoall(exe, n, repeats)
            t_c.setdefault(n, []).append(c1["t_iter"])
            a2a.setdefault(n, []).append(a)
            print(f"{r:>5} {n:>5}^3 {before:>17} {c1['t_iter']:>11.3e} {c2['t_iter']:>10.3e} {cn['t_iter']:>10.3e} "
                  f"{c1['t_fft']:>10.3e} {c2['t_fft']:>10.3e} {cn['t_fft']:>10.3e} {b['ratio']:>9.3f}  "
                  f"a2a 8 B {a['t_small']:.2e} s, {a['bytes_pair']:.0f} B {a['t_big']:.2e} s", flush=True)
            for key, v in (("iter transposed", c1["t_iter"] / c2["t_iter"]),
                           ("iter natural", c1["t_iter"] / cn["t_iter"]),
                           ("fft transposed", c1["t_fft"] / c2["t_fft"]),
                           ("fft natural", c1["t_fft"] / cn["t_fft"]),
                           ("batch/sep", b["ratio"])):
                ratios.setdefault((n, key), []).append(v)
    print("\nmedian [min, max] over rounds of t(np=1)/t(np=2) (speed-up), and of t_batch/t_sep at np = 2")
    for (n, key), v in ratios.items():
        print(f"  {n:>4}^3 {key:<16} {statistics.median(v):6.2f} [{min(v):.2f}, {max(v):.2f}]  ({len(v)} rounds)")
    # Model parameters, the least disturbed round of each (other processes on a shared
    # machine only add time): alpha from the 8-byte all-to-all (one message per rank at
    # P = 2), beta from the transform-sized one; t_c the serial iteration
    n = max(grids)
    alpha = min(a["t_small"] for a in a2a[n])
    big = min(a["t_big"] for a in a2a[n])
    beta = a2a[n][0]["bytes_pair"] / max(big - alpha, 1e-12)
    tc = min(t_c[n])
    t2 = tc / 2 + TRANSFORMS * slab_a2a(2, n, alpha, beta)
    print(f"\nmodel at P = 2, {n}^3: t_c/2 + {TRANSFORMS} a2a(2) = {t2:.3e} s per iteration "
          f"(transposed; natural: {tc / 2 + 2 * TRANSFORMS * slab_a2a(2, n, alpha, beta):.3e} s)")
    projection(n, tc, alpha, beta, [1, 2, 4, 8, 16, 32, 64, 128, 256, 1024, 4096])


def precision_rounds(exe: Path, grids: list[int], rounds: int, repeats: int) -> None:
    """Serial CG iteration with double and with single-precision transforms; medians over rounds."""
    rows: dict[int, list[tuple[dict, dict]]] = {}
    print(f"{'round':>5} {'grid':>6} {'load 1/5/15 min':>17} {'CPU-s/iter dbl':>14} {'sgl':>10} {'FFT-eq dbl':>10} "
          f"{'sgl':>6} {'speed-up':>8} {'FFT sgl/dbl':>11}")
    for r in range(rounds):
        for n in grids:
            before = load()
            d = cost(exe, n, 1, repeats, "auto", "double")
            f = cost(exe, n, 1, repeats, "auto", "single")
            rows.setdefault(n, []).append((d, f))
            print(f"{r:>5} {n:>5}^3 {before:>17} {d['t_iter_cpu']:>14.3e} {f['t_iter_cpu']:>10.3e} "
                  f"{d['t_iter_cpu'] / d['t_fft_cpu']:>10.2f} {f['t_iter_cpu'] / f['t_fft_cpu']:>6.2f} "
                  f"{d['t_iter_cpu'] / f['t_iter_cpu']:>8.2f} {f['t_fft_sp'] / f['t_fft']:>11.2f}", flush=True)
    print("\nmedian [min, max] over rounds (CPU time of this process; FFT-eq = iteration / one hot double FFT)")
    for n, v in rows.items():
        for key, vals in (("FFT-eq/iter double", [d["t_iter_cpu"] / d["t_fft_cpu"] for d, _ in v]),
                          ("FFT-eq/iter single", [f["t_iter_cpu"] / f["t_fft_cpu"] for _, f in v]),
                          ("speed-up double/single", [d["t_iter_cpu"] / f["t_iter_cpu"] for d, f in v]),
                          ("hot FFT single/double", [f["t_fft_sp"] / f["t_fft"] for _, f in v])):
            print(f"  {n:>4}^3 {key:<24} {statistics.median(vals):6.2f} [{min(vals):.2f}, {max(vals):.2f}]  "
                  f"({len(vals)} rounds)")


def forms_rounds(exe: Path, grids: list[int], rounds: int, repeats: int) -> None:
    """Serial CG iteration, stencil against spectral form, small and large sphere."""
    cases = [(shape, form) for shape in ("sphere", "ball") for form in ("auto", "spectral")]
    rows: dict[tuple[int, str, str], list[float]] = {}
    print(f"{'round':>5} {'grid':>6} {'load 1/5/15 min':>17} " + " ".join(f"{s + '/' + f:>16}" for s, f in cases))
    for r in range(rounds):
        for n in grids:
            before = load()
            vals = []
            for shape, form in cases:
                c = cost(exe, n, 1, repeats, form, "double", shape)
                vals.append(c["t_iter_cpu"] / c["t_fft_cpu"])
                rows.setdefault((n, shape, form), []).append(vals[-1])
            print(f"{r:>5} {n:>5}^3 {before:>17} " + " ".join(f"{v:>16.2f}" for v in vals), flush=True)
    print("\nmedian [min, max] over rounds of FFT-eq per iteration (CPU time; auto = the stencil form; "
          "sphere 0.8 %, ball 27 % of the cell)")
    for (n, shape, form), v in rows.items():
        print(f"  {n:>4}^3 {shape:<7} {('stencil' if form == 'auto' else 'spectral'):<9} "
              f"{statistics.median(v):6.2f} [{min(v):.2f}, {max(v):.2f}]  ({len(v)} rounds)")


def fft_cpu(exe: Path, n: int, repeats: int) -> float:
    """Median CPU seconds of one hot double FFT of n^3 (first repeat dropped)."""
    out = _run(exe, [str(n), "1e3", str(repeats + 1), "fft"], 1)
    return statistics.median(float(v) for v in re.findall(r"t_fft_cpu=\s*(\S+)", out)[1:])


#: --rigidity: name -> StokesSettings keywords
RIGIDITY_SETTINGS = {
    **{f"penalty {k:.0e}, tol {t:.0e}": dict(kappa=k, tol=t) for k, t in ((1e3, 1e-6), (1e3, 1e-3), (1e4, 1e-6))},
    **{f"exact, tol {t:.0e}": dict(rigidity="exact", tol=t) for t in (1e-6, 1e-3)},
}


def rigidity_table(exe: Path, grids: list[int], repeats: int) -> None:
    """One cold solve per setting of the centred sphere of radius n/8, serial."""
    import time

    from pyfold.native.stokes import Particles, StokesSettings, solve_particles

    P = Particles(x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=0.125, length=0.25, shape="sphere")
    print(f"{'grid':>6} {'setting':<24} {'iter':>6} {'CPU-s':>8} {'FFT-eq':>8} {'FFT-eq/iter':>11} {'eta_eff':>10}")
    for n in grids:
        t_fft = fft_cpu(exe, n, repeats)
        rows = []
        for name, kw in RIGIDITY_SETTINGS.items():
            t0 = time.process_time()
            sol = solve_particles(P, [1, 1, 1], (n, n, n),
                                  settings=StokesSettings(measure_plans=False, max_iter=20000, **kw))
            rows.append((name, sol.iterations, time.process_time() - t0, sol.eta_eff))
        t_fft2 = fft_cpu(exe, n, repeats)
        unit = 0.5 * (t_fft + t_fft2)
        for name, its, t, eta in rows:
            print(f"{n:>5}^3 {name:<24} {its:>6d} {t:>8.3f} {t / unit:>8.0f} {t / unit / max(its, 1):>11.1f} "
                  f"{eta:>10.6f}", flush=True)
        print(f"        one hot FFT {unit:.3e} CPU-s (mean of {t_fft:.3e} before and {t_fft2:.3e} after; "
              f"load {load()})")


def iterations(exe: Path, n: int, kappa: float, shape: str = "sphere") -> int:
    out = _run(exe, [str(n), str(kappa), "1", "iters", shape], 1)
    m = re.search(r"iterations=\s*(\d+)", out)
    return int(m[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=str(ROOT / "build" / "editable"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="64^3 and np = 2 at 64^3 only, shorter sweeps")
    ap.add_argument("--mpi", action="store_true", help="only np = 2 against np = 1 (transposed, natural, batched)")
    ap.add_argument("--precision", action="store_true",
                    help="only the serial iteration with single- against double-precision transforms")
    ap.add_argument("--forms", action="store_true",
                    help="only the serial iteration in the stencil against the spectral form, small and large sphere")
    ap.add_argument("--rigidity", action="store_true",
                    help="only one solve with exact rigidity beside the penalised ones, serial, per grid")
    ap.add_argument("--grids", type=int, nargs="+", default=[64, 128],
                    help="grids of --mpi, --precision, --forms and --rigidity")
    ap.add_argument("--rounds", type=int, default=5, help="rounds of --mpi and --precision")
    ap.add_argument("--project", type=float, nargs=3, metavar=("T_C", "ALPHA", "BETA"),
                    help="only print the projected scaling at max(--grids) for a serial iteration T_C [s], "
                         "all-to-all latency ALPHA [s] and bandwidth BETA [B/s] (no run)")
    args = ap.parse_args()
    if args.project is not None:
        if not all(v > 0 for v in args.project):
            ap.error("--project: T_C, ALPHA and BETA must be > 0")
        projection(max(args.grids), *args.project, [1, 2, 4, 8, 16, 32, 64, 128, 256, 1024, 4096])
        return
    if args.repeats < 1 or args.rounds < 1 or any(n < 8 for n in args.grids):
        ap.error("--repeats must be >= 1, --rounds >= 1 and every --grids value >= 8")
    built = Path(args.build) / "fortran" / "stokes" / "tests" / "bench_stokes_fft"
    # a private copy: an editable import elsewhere may relink the build-tree binary mid-run
    exe = Path(tempfile.mkdtemp(prefix="bench_stokes_")) / "bench_stokes_fft"
    shutil.copy2(built, exe)
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    # the "only" options, in the order they take precedence: the first one given runs alone
    only = [
        (args.precision, lambda: precision_rounds(exe, args.grids, args.rounds, args.repeats)),
        (args.forms, lambda: forms_rounds(exe, args.grids, args.rounds, args.repeats)),
        (args.rigidity, lambda: rigidity_table(exe, args.grids, args.repeats)),
        (args.mpi, lambda: mpi_rounds(exe, args.grids, args.rounds, args.repeats)),
    ]
    for given, table in only:
        if given:
            table()
            print(f"\nload average after: {load()}")
            return

    # Parameters
    # (grid, ranks, backend): "auto" = serial FFTW on one rank (what fold_run uses),
    # FFTW-MPI slabs on two
    cases = [(64, 1, "auto"), (64, 2, "auto")] if args.quick else [(64, 1, "auto"), (128, 1, "auto"), (128, 2, "auto")]
    kappas = [1e1, 1e2, 1e3, 1e4]
    grids = [32, 48, 64] if args.quick else [32, 48, 64, 96, 128]

    # Run: cost of an iteration
    print(f"\n{'grid':>6} {'ranks':>5} {'backend':>13} {'t_iter [s]':>11} {'t_fft hot':>10} {'t_fft seq':>10} "
          f"{'iter/FFT hot':>13} {'iter/FFT seq':>13} {'FFTs/iter':>9}")
    t_iter = {}
    for n, ranks, backend in cases:
        c = cost(exe, n, ranks, args.repeats, backend)
        name = "fftw-mpi" if backend == "mpi" or ranks > 1 else "serial"
        if backend == "auto":
            t_iter[(n, ranks)] = c["t_iter"]
        print(f"{n:>5}^3 {ranks:>5} {name:>13} {c['t_iter']:>11.3e} {c['t_fft']:>10.3e} {c['t_fft_seq']:>10.3e} "
              f"{c['ratio']:>13.1f} {c['ratio_seq']:>13.1f} {int(c['ffts']):>9}")
    big = max(n for n, _, _ in cases)
    if (big, 2) in t_iter:
        print(f"speed-up np=2 vs np=1 at {big}^3 (wall time per iteration): {t_iter[(big, 1)] / t_iter[(big, 2)]:.2f}")

    # Run: iterations to 1e-6
    print("\nCG iterations to a relative preconditioned residual of 1e-6 (zero initial guess)")
    for shape in ("sphere", "spheroid"):
        print(f"{shape} (sphere: radius n/8; spheroid: aspect ratio 8, 2 voxels per radius at 64^3)")
        print("  vs kappa at 64^3: " + ", ".join(f"kappa {k:g}: {iterations(exe, 64, k, shape)}" for k in kappas))
        print("  vs grid at kappa 1e3: " + ", ".join(f"{n}^3: {iterations(exe, n, 1e3, shape)}" for n in grids))
    print(f"\nload average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
