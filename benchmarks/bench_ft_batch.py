"""Benchmark: 1024 Folgar--Tucker integrations (IBOF) in one jit(vmap) solve vs a SciPy loop.

Question
    How much faster is ``pyfold.models.solve_batch`` (diffrax Tsit5, jit + vmap)
    than the usual per-case ``scipy.integrate.solve_ivp`` loop, for a parameter
    sweep of the kind a C_I study needs, and do both give the same answer?

Problem
    Folgar--Tucker, IBOF closure (Chung & Kwon 2002), simple shear gamma_dot = 1,
    isotropic start, t in [0, 100] (101 outputs), rtol = 1e-8, atol = 1e-10;
    1024 cases with C_I log-spaced in [1e-4, 5e-2] and xi uniform in [0.8, 1]
    (seeded).

Method
    * JAX: one ``solve_batch`` call; first call = compile + run; warm time =
      median of ``--repeats`` further calls.
    * Reference: ``benchmarks/reference_scipy_ft.py`` (NumPy FT + IBOF written
      independently; only the published coefficient table is shared) with
      ``solve_ivp``, one case at a time, on every 32nd case (``--n-ref`` cases);
      the 1024-case time is that total times 1024 / n_ref (cases are
      independent and the subset spans the whole parameter range, so the mean
      cost per case carries over).
    * Agreement: max |a2_jax - a2_scipy| over the reference subset, all times.

Command
    MESONPY_EDITABLE_SKIP=... .venv/bin/python benchmarks/bench_ft_batch.py
    (a few minutes on 2 cores; not a test).
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import diffrax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from reference_scipy_ft import IBOF_POWERS, solve_ft_ibof  # noqa: E402

from pyfold._jax import jax, jnp  # noqa: E402
from pyfold.closures import _coefficients as table  # noqa: E402  (published data only)
from pyfold.kinematics import simple_shear  # noqa: E402
from pyfold.models import FolgarTucker, solve_batch  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=1024, help="batch size")
    parser.add_argument("--n-ref", type=int, default=32, help="SciPy cases actually timed")
    parser.add_argument("--repeats", type=int, default=3, help="warm JAX runs (median)")
    parser.add_argument("--method", default="DOP853", help="solve_ivp method for the reference")
    parser.add_argument("--solver", default="Tsit5", help="diffrax solver of the batch (Tsit5 = pyfold default, Dopri8)")
    parser.add_argument(
        "--buckets", type=int, default=1,
        help="split the sweep (ordered by C_I) into this many equal solve_batch calls: a vmapped "
             "adaptive solve steps every member until the slowest is done, so members of similar "
             "cost are better grouped",
    )
    parser.add_argument("--rtol", type=float, default=1e-8)
    parser.add_argument("--atol", type=float, default=1e-10)
    args = parser.parse_args()

    # Parameters
    n = args.n
    rng = np.random.default_rng(12345)
    ci = np.geomspace(1e-4, 5e-2, n)
    xi = rng.uniform(0.8, 1.0, n)
    t_eval = np.linspace(0.0, 100.0, 101)
    L = np.asarray(simple_shear(1.0, dim=3))
    a2_0 = np.eye(3) / 3.0
    assert tuple(table.IBOF_MONOMIALS) == IBOF_POWERS, "monomial order of the IBOF table changed"
    coeffs = np.array([table.IBOF_BETA3, table.IBOF_BETA4, table.IBOF_BETA6], dtype=np.float64)

    # JAX batch (one call, or --buckets equal calls over contiguous C_I ranges)
    if n % args.buckets:
        parser.error("--buckets must divide --n")
    solver = getattr(diffrax, args.solver)()
    chunks = np.split(np.arange(n), args.buckets)
    models = [FolgarTucker(ci=jnp.asarray(ci[c]), xi=jnp.asarray(xi[c]), closure="ibof") for c in chunks]

    def run():
        sols = [solve_batch(m, a2_0, L, t_eval, rtol=args.rtol, atol=args.atol, solver=solver) for m in models]
        jax.block_until_ready([s.a2 for s in sols])
        return sols

    t0 = time.perf_counter()
    sol = run()
    first = time.perf_counter() - t0
    warm = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        sol = run()
        warm.append(time.perf_counter() - t0)
    warm_median = statistics.median(warm)
    a2_jax = np.concatenate([np.asarray(s.a2) for s in sol])
    status = np.concatenate([np.asarray(s.status) for s in sol])
    steps = np.concatenate([np.asarray(s.stats["num_steps"]) for s in sol])

    # Reference: per-case SciPy loop on a strided subset
    stride = max(1, n // args.n_ref)
    subset = np.arange(0, n, stride)[: args.n_ref]
    ref_times, worst = [], 0.0
    for k in subset:
        t0 = time.perf_counter()
        a2_ref = solve_ft_ibof(ci[k], xi[k], a2_0, L, t_eval, coeffs, rtol=args.rtol, atol=args.atol, method=args.method)
        ref_times.append(time.perf_counter() - t0)
        worst = max(worst, float(np.max(np.abs(a2_ref - a2_jax[k]))))
    ref_subset = float(np.sum(ref_times))
    ref_total = ref_subset * n / subset.size

    # Report
    print(f"Folgar-Tucker + IBOF, simple shear, t in [0, 100], rtol={args.rtol:g}, atol={args.atol:g}")
    print(f"batch size                      : {n}  (C_I in [1e-4, 5e-2], xi in [0.8, 1]); "
          f"{args.buckets} solve_batch call(s)")
    print(f"JAX devices                     : {jax.devices()}")
    print(f"all members succeeded           : {bool(np.all(status == 0))}  "
          f"({args.solver} steps per member: median {int(np.median(steps))}, max {int(steps.max())})")
    print(f"JAX first call (compile + run)  : {first:8.2f} s")
    print(f"JAX warm run, median of {args.repeats}      : {warm_median:8.2f} s   (runs: "
          + ", ".join(f"{w:.2f}" for w in warm) + ")")
    print(f"JAX compile time (first - warm) : {first - warm_median:8.2f} s")
    print(f"SciPy {args.method} loop, {subset.size} cases   : {ref_subset:8.2f} s "
          f"(median {statistics.median(ref_times) * 1e3:.0f} ms per case)")
    print(f"SciPy loop extrapolated to {n}  : {ref_total:8.2f} s   (= subset total x {n}/{subset.size})")
    print(f"speed-up, warm                  : {ref_total / warm_median:8.1f} x")
    print(f"speed-up, including compilation : {ref_total / first:8.1f} x")
    print(f"max |a2_jax - a2_scipy| over the {subset.size} reference cases, all times: {worst:.2e}")


if __name__ == "__main__":
    main()
