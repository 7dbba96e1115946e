"""Speed-accuracy table of the FFT Stokes solver on the Jeffery period of a prolate spheroid.

Question
    What does each numerical setting of the fictitious-domain FFT Stokes solver buy
    in accuracy, and what does it cost in wall time? Test case
    (docs/physics.md#single-particles-in-shear): a
    prolate spheroid of aspect ratio beta = 3 at the centre of a periodic cubic cell
    3 particle lengths wide, in simple shear (gamma_dot = 1, Lees-Edwards lattice).
    Its orbit period should approach Jeffery's T_J = (2 pi / gamma_dot)(beta + 1/beta)
    (Jeffery 1922, Proc. R. Soc. A 102:161) up to the box-size effect of the cell.
    One factor is varied at a time around the base setting:

    (a) voxels per diameter (grid n^3, n = 9 x voxels per diameter);
    (b) viscosity contrast kappa;
    (c) CG tolerance (relative preconditioned residual);
    (d) time step of a marched orbit, Euler and AB2 (``pyfold.native.stokes.march``).

    Base setting: n = 27 (3 voxels per diameter), kappa = 1e3, tol = 1e-6, rotated
    finite-difference derivatives, harmonic mixing, 3 sub-samples per voxel edge,
    flat start (no warm start) for (a)-(c), warm start for (d); (a)-(c) give T by
    quadrature over 16 orientations. The base grid is 3, not 4, voxels per diameter
    because (d) at 36^3 alone costs ~9 min (0.5 s per step, ~400 steps, x 2 schemes
    x 3 repeats); ``--base-grid 36`` runs it.

Method
    (a)-(c): Stokes flow has no memory, so the orbit is dtheta/dt = omega(theta) and
    T = int_0^{2 pi} dtheta / |omega(theta)|, omega solved at ``--ntheta`` fixed
    orientations (Lees-Edwards offset 0), trapezoid rule (functions reused from
    studies/stokes_validation/jeffery_period.py). The trapezoid rule applied to
    Jeffery's exact omega(theta) is off by 7.8e-3 with 8 orientations, 4.9e-4 with
    12 and 3.1e-5 with 16 (the default here), but the solver's omega(theta)
    converges much more slowly: at n = 27 (measured) T = 18.792 / 18.436 / 18.253
    / 18.215 / 18.168 / 18.194 with 8 / 16 / 24 / 32 / 48 / 96 orientations, so
    16 orientations carry a quadrature bias of ~+1.3 % at the base grid. It is
    common to all rows of (b) and (c) (same orientations) but differs between the
    grids of (a), which is one reason the grid orders below are erratic;
    ``--ntheta 32`` roughly doubles the cost of (a)-(c).
    (d): the axis starts along the gradient (theta = pi/2, t = 0) and is marched
    until it has turned by pi; the crossing time t_half comes from a cubic through
    the 4 steps around it (interpolation error O(dt^4)), T = 2 t_half. The marched
    orbit sees the Lees-Edwards offset s = gamma_dot t Ly change (and wrap at
    +-Lx/2), which the fixed-orientation quadrature (offset 0) does not.
    Control for (d), no Stokes: the same orbit stepped by
    ``pyfold.native.geometry.jeffery_advance`` (Jeffery's exact omega, frozen over a
    step, exact rotation = the Euler scheme of ``march``). For an autonomous orbit
    dtheta/dt = f(theta) the O(dt) period error of Euler, (dt/2) int f'/f dtheta,
    vanishes over a period, so the Euler *period* converges at second order; the
    Stokes march is not autonomous (omega depends on the Lees-Edwards offset).
    Observed orders: T(h) = T_inf + C h^p solved exactly on each triple of
    consecutive settings (h = 1/n for (a), h = dt for (d)), and for (a) also a
    least-squares fit over all grids (with standard errors).
    ``dev ref`` = T / T_ref - 1 with T_ref the sweep's most accurate setting (finest
    grid, largest kappa, smallest tol, smallest dt of the scheme): the factor's own
    error. ``err J`` is the total error against Jeffery, including the box-size
    effect of the 3-length cell, which no setting here removes.
    Wall time: median of ``--repeats`` full evaluations of T (all orientations, or
    the whole march), and its ratio to the cheapest setting of the sweep; results
    of the repeats are checked to be identical.

Command
    .venv/bin/python benchmarks/bench_speed_accuracy.py [--repeats 3] [--grids 18 27 36 48 64]
        [--base-grid 27] [--ntheta 16] [--dts 0.4 0.2 0.1 0.05] [--out out/bench/speed_accuracy]

Cost
    8.4 min measured on the 2-core shared machine at a load average of 0.4-1.1
    (9.0 min at ~2.5 with a concurrent test run): (a) 2.1 min, (b) + (c) 0.6 min,
    (d) 5.7 min. Serial (one core). 96^3 in (a) (~6 s per solve, ~5 min for 16 orientations x 3 repeats)
    was left out as too expensive.

Outputs
    A table on stdout (one block per sweep, with the fitted orders), and the same
    rows in ``<out>.csv`` and ``<out>.nc`` (NetCDF, with units, the base setting, the
    orders, load averages and the creator as attributes); ``out/`` is gitignored.
"""
from __future__ import annotations

import argparse
import csv
import os
import statistics
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import xarray as xr
from scipy.optimize import brentq, curve_fit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "studies" / "stokes_validation"))

from jeffery_period import (BETA, CELLS_PER_LENGTH, jeffery_period, orientations,  # noqa: E402
                            period_from_omegas, spheroid_at)

from pyfold.command_line import command_line  # noqa: E402
from pyfold.kinematics import aspect_ratio_to_xi  # noqa: E402
from pyfold.native.geometry import Cell, jeffery_advance  # noqa: E402
from pyfold.native.stokes import StokesSettings, march, solve_particles  # noqa: E402
from pyfold.run_input import creator  # noqa: E402

VOXELS_PER_DIAMETER = 1.0 / (BETA * CELLS_PER_LENGTH)  # x n: the diameter is 1/(beta CELLS_PER_LENGTH)
FIELDS = ["sweep", "scheme", "n", "voxels_per_diameter", "kappa", "tol", "dt", "ntheta", "T", "rel_err_jeffery",
          "rel_dev_reference", "iterations_mean", "rigidity_max", "wall_median_s", "wall_min_s", "wall_max_s",
          "wall_ratio", "repeats"]


def quadrature_period(n: int, settings: StokesSettings, ntheta: int) -> dict:
    """Period by quadrature over fixed orientations, with the mean CG iterations per solve and
    the largest rigidity residual."""
    sols = [solve_particles(spheroid_at(th), [1, 1, 1], (n, n, n), settings=settings)
            for th in orientations(ntheta)]
    return dict(T=period_from_omegas([s.omega[0, 2] for s in sols]),
                iterations_mean=float(np.mean([s.iterations for s in sols])),
                rigidity_max=float(max(s.rigidity[0] for s in sols)))


THETA0 = 0.5 * np.pi  # marched orbits start with the axis along the gradient


def _steps(dt: float, T_estimate: float) -> int:
    return int(np.ceil(0.5 * 1.15 * T_estimate / dt)) + 3  # half orbit + 15 % + the interpolation stencil


def half_orbit_period(t: np.ndarray, p: np.ndarray) -> tuple[float, int]:
    """T = 2 t_half, t_half the time at which the axis (history ``p`` (nsteps + 1, dim), from
    THETA0) has turned by pi, by a cubic in theta through the 4 steps around the crossing;
    also the index of the first step past it."""
    theta = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    target = THETA0 - np.pi  # omega < 0: theta decreases
    k = int(np.argmax(theta <= target)) if np.any(theta <= target) else -1
    if k < 2 or k + 1 >= len(t):
        raise RuntimeError(f"no half orbit within {len(t) - 1} steps of dt = {t[1] - t[0]} "
                           f"(theta end {theta[-1]:.3f})")
    window = slice(k - 2, k + 2)
    return 2.0 * float(np.polyval(np.polyfit(theta[window], t[window], 3), target)), k


def marched_period(n: int, settings: StokesSettings, dt: float, scheme: str, T_estimate: float) -> dict:
    """Period of an orbit marched with the Stokes rigid velocities (``march``)."""
    nsteps = _steps(dt, T_estimate)
    res = march(spheroid_at(THETA0), [1, 1, 1], (n, n, n), dt=dt, nsteps=nsteps, t0=0.0, scheme=scheme,
                settings=settings)
    T, k = half_orbit_period(res.t, res.p[:, 0])
    return dict(T=T, iterations_mean=float(res.iterations[:k].mean()), rigidity_max=float(res.rigidity_max[:k].max()))


def jeffery_euler_period(dt: float) -> dict:
    """Control without Stokes: the same orbit stepped by ``jeffery_advance`` (Jeffery's exact
    omega for xi(beta), frozen over each step, exact rotation: the Euler scheme of ``march``)."""
    P = spheroid_at(THETA0)
    nsteps = _steps(dt, jeffery_period())
    _, ph = jeffery_advance(Cell(lengths=(1.0, 1.0, 1.0), shear_rate=1.0), P.x, P.p,
                            float(aspect_ratio_to_xi(BETA)), dt, nsteps)
    T, _ = half_orbit_period(dt * np.arange(nsteps + 1), ph[:, 0])
    return dict(T=T, iterations_mean=0.0, rigidity_max=0.0)


def timed(fn, repeats: int) -> dict:
    """Run ``fn`` ``repeats`` times; its result (checked identical across repeats) and wall times."""
    walls, results = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        results.append(fn())
        walls.append(time.perf_counter() - t0)
    spread = max(abs(r["T"] - results[0]["T"]) for r in results)
    if spread > 1e-12 * abs(results[0]["T"]):
        raise RuntimeError(f"repeats disagree: T spread {spread:.3e}")
    return dict(results[0], wall_median_s=statistics.median(walls), wall_min_s=min(walls), wall_max_s=max(walls),
                repeats=repeats)


def order_triples(h, T) -> list[tuple[float, float]]:
    """(p, T_inf) of T = T_inf + C h^p solved exactly on each consecutive triple (h decreasing);
    p is nan when the differences change sign (no monotone convergence in that triple)."""
    out = []
    for i in range(len(h) - 2):
        (h1, h2, h3), (T1, T2, T3) = h[i:i + 3], T[i:i + 3]
        ratio = (T1 - T2) / (T2 - T3)
        if not ratio > 0:
            out.append((np.nan, np.nan))
            continue
        f = lambda p: (h1**p - h2**p) / (h2**p - h3**p) - ratio  # noqa: E731  (increasing in p)
        try:
            p = brentq(f, 0.05, 10.0)
        except ValueError:
            out.append((np.nan, np.nan))
            continue
        out.append((p, T3 - (T2 - T3) * h3**p / (h2**p - h3**p)))
    return out


def fit_order(h, T) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (T_inf, C, p) of T = T_inf + C h^p over all points, with standard errors."""
    h, T = np.asarray(h, float), np.asarray(T, float)
    try:
        popt, pcov = curve_fit(lambda h, T_inf, C, p: T_inf + C * h**p, h, T,
                               p0=(T[-1], (T[0] - T[-1]) / h[0], 1.0), maxfev=20000)
        return popt, np.sqrt(np.diag(pcov))
    except (RuntimeError, ValueError):
        return np.full(3, np.nan), np.full(3, np.nan)


def fmt_orders(label: str, settings: list[str], fits: list[tuple[float, float]]) -> str:
    parts = [f"{'-'.join(settings[i:i + 3])}: p = {p:.2f}" for i, (p, _) in enumerate(fits)]
    return f"  observed order, {label}: " + "; ".join(parts)


def print_block(title: str, rows: list[dict], label) -> None:
    print(f"\n{title}")
    print(f"  {'setting':>16} {'T':>9} {'err J':>9} {'dev ref':>9} {'CG it':>6} {'rigidity':>9} "
          f"{'wall [s]':>9} {'ratio':>6}")
    for r in rows:
        print(f"  {label(r):>16} {r['T']:>9.5f} {r['rel_err_jeffery']:>+9.2e} {r['rel_dev_reference']:>+9.2e} "
              f"{r['iterations_mean']:>6.0f} {r['rigidity_max']:>9.2e} {r['wall_median_s']:>9.3f} "
              f"{r['wall_ratio']:>6.1f}")


def finish(rows: list[dict], T_ref: float, T_J: float) -> None:
    cheapest = min(r["wall_median_s"] for r in rows)
    for r in rows:
        r.update(rel_err_jeffery=r["T"] / T_J - 1, rel_dev_reference=r["T"] / T_ref - 1,
                 wall_ratio=r["wall_median_s"] / cheapest)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--grids", type=int, nargs="+", default=[18, 27, 36, 48, 64])
    ap.add_argument("--base-grid", type=int, default=27)
    ap.add_argument("--ntheta", type=int, default=16)
    ap.add_argument("--kappas", type=float, nargs="+", default=[1e1, 1e2, 1e3, 1e4])
    ap.add_argument("--tols", type=float, nargs="+", default=[1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8])
    ap.add_argument("--dts", type=float, nargs="+", default=[0.4, 0.2, 0.1, 0.05])
    ap.add_argument("--out", default=str(ROOT / "out" / "bench" / "speed_accuracy"))
    args = ap.parse_args()
    load_before = os.getloadavg()
    started = time.perf_counter()
    print(f"load average before: {' '.join(f'{v:.2f}' for v in load_before)} on {os.cpu_count()} cores")

    # Parameters
    grids = sorted(args.grids)
    kappas, tols, dts = sorted(args.kappas), sorted(args.tols, reverse=True), sorted(args.dts, reverse=True)
    n0, ntheta = args.base_grid, args.ntheta

    # Problem
    T_J = jeffery_period()  # gamma_dot = 1
    common = dict(scheme="", n=n0, voxels_per_diameter=n0 * VOXELS_PER_DIAMETER, dt=np.nan, ntheta=ntheta)

    # Solver
    base = StokesSettings(kappa=1e3, tol=1e-6, derivative="fd", mixing="harmonic", subsamples=3, warm_start=False)
    print(f"beta = {BETA:g}, cell {CELLS_PER_LENGTH:g} lengths wide, gamma_dot = 1: Jeffery T = {T_J:.5f}")
    print(f"base: n = {n0} ({n0 * VOXELS_PER_DIAMETER:.2f} voxels per diameter), kappa = {base.kappa:g}, "
          f"tol = {base.tol:g}, derivative = {base.derivative}, mixing = {base.mixing}, "
          f"subsamples = {base.subsamples}, ntheta = {ntheta}; repeats = {args.repeats}")

    # Run (a): grid
    a = []
    for n in grids:
        r = timed(lambda: quadrature_period(n, base, ntheta), args.repeats)
        a.append(dict(common, sweep="grid", n=n, voxels_per_diameter=n * VOXELS_PER_DIAMETER, kappa=base.kappa,
                      tol=base.tol, **r))
    fits_a = order_triples([1.0 / r["n"] for r in a], [r["T"] for r in a])
    lsq_a, lsq_err_a = fit_order([1.0 / r["n"] for r in a], [r["T"] for r in a])
    finish(a, a[-1]["T"], T_J)
    # apparent order against Jeffery: contaminated by the box-size floor, shown for contrast
    slope_J = np.polyfit(np.log([1.0 / r["n"] for r in a]), np.log([abs(r["rel_err_jeffery"]) for r in a]), 1)[0]

    # Run (b): kappa
    b = [dict(common, sweep="kappa", kappa=k, tol=base.tol,
              **timed(lambda: quadrature_period(n0, replace(base, kappa=k), ntheta), args.repeats)) for k in kappas]
    finish(b, b[-1]["T"], T_J)

    # Run (c): CG tolerance
    c = [dict(common, sweep="tol", kappa=base.kappa, tol=tol,
              **timed(lambda: quadrature_period(n0, replace(base, tol=tol), ntheta), args.repeats)) for tol in tols]
    finish(c, c[-1]["T"], T_J)

    # Run (d): time step of a marched orbit (warm start: what a run does)
    T_est = next((r["T"] for r in a if r["n"] == n0), T_J)
    d, fits_d = [], {}
    for scheme in ("euler", "ab2"):
        rows = [dict(common, sweep="dt", scheme=scheme, kappa=base.kappa, tol=base.tol, dt=dt, ntheta=0,
                     **timed(lambda: marched_period(n0, replace(base, warm_start=True), dt, scheme, T_est),
                             args.repeats)) for dt in dts]
        fits_d[scheme] = order_triples(dts, [r["T"] for r in rows])
        finish(rows, rows[-1]["T"], T_J)
        d += rows
    jeffery_euler_period(dts[0])  # warm-up: the first call loads the extension and compiles xi(beta)
    control = [dict(common, sweep="dt", scheme="jeffery-euler", n=0, voxels_per_diameter=np.nan, kappa=np.nan,
                    tol=np.nan, dt=dt, ntheta=0, **timed(lambda: jeffery_euler_period(dt), args.repeats)) for dt in dts]
    fits_d["jeffery-euler"] = order_triples(dts, [r["T"] for r in control])
    finish(control, T_J, T_J)
    cheapest_d = min(r["wall_median_s"] for r in d)  # one ratio base for both schemes
    for r in d:
        r["wall_ratio"] = r["wall_median_s"] / cheapest_d

    # Save (print)
    print("\nerr J = T/T_J - 1 (Jeffery); dev ref = T/T_ref - 1, T_ref = the sweep's most accurate setting "
          "(finest grid, largest kappa, smallest tol, smallest dt of the scheme); "
          "CG it = mean per solve; rigidity = largest residual; wall = median over repeats; "
          "ratio = to the sweep's cheapest")
    print_block("(a) grid", a, lambda r: f"n={r['n']} ({r['voxels_per_diameter']:.2f}/d)")
    print(fmt_orders("T = T_inf + C h^p, h = 1/n, exact on triples", [str(r["n"]) for r in a], fits_a))
    print(f"  least squares over all grids: p = {lsq_a[2]:.2f} +- {lsq_err_a[2]:.2f}, T_inf = {lsq_a[0]:.3f} "
          f"+- {lsq_err_a[0]:.3f} (err J {lsq_a[0] / T_J - 1:+.2e})")
    print(f"  apparent slope of log|err J| against log h over all grids: {slope_J:.2f} (box-size floor included)")
    print_block(f"(b) kappa (T_ref = kappa {kappas[-1]:g})", b, lambda r: f"kappa={r['kappa']:g}")
    print_block(f"(c) CG tolerance (T_ref = tol {tols[-1]:g})", c, lambda r: f"tol={r['tol']:g}")
    print_block(f"(d) marched orbit, half orbit from theta = pi/2 (quadrature T at this grid {T_est:.5f}); "
                f"control: jeffery_advance, exact Jeffery omega, no Stokes (dev ref = err J)", d + control,
                lambda r: f"{r['scheme']} dt={r['dt']:g}")
    for scheme, fits in fits_d.items():
        print(fmt_orders(f"{scheme}, h = dt, exact on triples", [f"{v:g}" for v in dts], fits)
              + f"; T(dt->0) from the finest triple = {fits[-1][1]:.5f}"
              + ("" if scheme.startswith("jeffery") else f" (vs quadrature {fits[-1][1] / T_est - 1:+.2e})"))
    load_after = os.getloadavg()
    total = time.perf_counter() - started
    print(f"\nload average after: {' '.join(f'{v:.2f}' for v in load_after)}; total {total / 60:.1f} min")

    # Save (files)
    rows = a + b + c + d + control
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS)
        w.writeheader()
        w.writerows({k: r[k] for k in FIELDS} for r in rows)
    units = dict(n="1", voxels_per_diameter="1", kappa="1", tol="1", dt="s", T="s", wall_median_s="s",
                 wall_min_s="s", wall_max_s="s")
    ds = xr.Dataset({k: ("row", np.array([r[k] for r in rows])) for k in FIELDS})
    for k, u in units.items():
        ds[k].attrs["units"] = u
    ds["T"].attrs["long_name"] = "Jeffery orbit period (gamma_dot = 1)"
    ds.attrs.update(
        format="pyfold.bench.speed_accuracy", creator=creator(), created=datetime.now(timezone.utc).isoformat(),
        command=command_line([Path(sys.executable).name, *sys.argv]), beta=BETA, cell_lengths=CELLS_PER_LENGTH,
        jeffery_T=T_J, base=f"n={n0}, kappa={base.kappa:g}, tol={base.tol:g}, derivative={base.derivative}, "
                            f"mixing={base.mixing}, subsamples={base.subsamples}, ntheta={ntheta}",
        order_grid_triples=np.array([p for p, _ in fits_a]), order_grid_lsq=lsq_a[2], order_grid_lsq_err=lsq_err_a[2],
        T_inf_grid_lsq=lsq_a[0], T_inf_grid_lsq_err=lsq_err_a[0],
        order_euler=np.array([p for p, _ in fits_d["euler"]]), order_ab2=np.array([p for p, _ in fits_d["ab2"]]),
        order_jeffery_euler=np.array([p for p, _ in fits_d["jeffery-euler"]]),
        load_before=np.array(load_before), load_after=np.array(load_after), total_wall_s=total)
    ds.to_netcdf(out.with_suffix(".nc"), engine="h5netcdf")
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.nc')}")


if __name__ == "__main__":
    main()
