"""One Stokes solve of a dense fibre suspension, penalised against exact rigidity:
iterations, cost and rigid-velocity error against the kappa -> infinity limit, against
the number of fibres, the grid and the smallest gap.

Question: what does exact rigidity (numerics.stokes.rigidity = "exact") cost per solve at
a given accuracy of the particles' rigid velocities, compared with the penalty, and how
do its iterations grow with the number of particles, the resolution and the gaps?
Scenes: N fibres of aspect ratio 10 placed at random (random sequential addition,
closest axis distance >= (2 + gap) R), number density n L^3 = 4 (the dense-fibre scene
of bench_stokes_step.py: 55 fibres in a 2.4^3 cell), cells of 1.5, 2.4 and 3.2 fibre
lengths (14, 55 and 131 fibres), 3 voxels per diameter; the 55-fibre scene also at 2
and 4 voxels per diameter and with gaps 0.05 and 0.5 R; 14 and 28 fibres in the same
2.4^3 cell and 72^3 grid (the number of particles at a fixed grid). One static solve in
simple shear (gamma_dot = 1) per setting, cold start. Reference: the exact solve at
tolerance 1e-10 (the kappa -> infinity limit of the penalised solve on the same voxels:
the penalty is its Tikhonov regularisation, tests/micro/test_stokes_exact.py).
``--big``: the 128^3 sibling of bench_stokes_step.py --big (305 fibres, cell 4.25^3, 3
voxels per diameter), one cold solve per setting, errors against the exact solve at
1e-6 instead (its own error, ~2e-7 at 72^3, is far below the settings' it measures).
Error: sqrt(sum |V - V_ref|^2 + (L/2)^2 |w - w_ref|^2) / sqrt(sum |V_ref|^2 + (L/2)^2 |w_ref|^2)
over the fibres (vel err) and the same for the rotation rates alone (rot err); eta err:
the relative error of the particles' part of the effective viscosity.
Command:  nice -n 5 python benchmarks/bench_rigidity_solve.py [--quick | --big] [--seed 1] [--only NAME ...]
          nice -n 5 python benchmarks/bench_rigidity_solve.py --case CELL CPD GAP COUNT [--case ...]
          (one scene of the full list, e.g. --case 2.4 3 0.2 14; COUNT 0 = n L^3 = 4)
Cost: --quick (the 55-fibre scene at 3 voxels per diameter only) ~3 CPU-min; full ~30 CPU-min;
--big roughly 6x the 72^3 scene per iteration.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from pyfold.native.stokes import Particles, StokesSettings, solve_particles

BETA, NL3 = 10.0, 4.0
SETTINGS = {
    "penalty 1e3, tol 1e-6": dict(kappa=1e3, tol=1e-6),
    "penalty 1e3, tol 1e-3": dict(kappa=1e3, tol=1e-3),
    "penalty 1e4, tol 1e-6": dict(kappa=1e4, tol=1e-6),
    "exact, tol 1e-2": dict(rigidity="exact", tol=1e-2),
    "exact, tol 1e-3": dict(rigidity="exact", tol=1e-3),
    "exact, tol 1e-4": dict(rigidity="exact", tol=1e-4),
    "exact, tol 1e-6": dict(rigidity="exact", tol=1e-6),
}


def _segment_distance(p1, q1, p2, q2) -> float:
    """Closest distance of two segments (Ericson 2005, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    den = a * e - b * b
    s = np.clip((b * f - c * e) / den, 0.0, 1.0) if den > 1e-12 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, np.clip(-c / a, 0.0, 1.0)
    elif t > 1.0:
        t, s = 1.0, np.clip((b - c) / a, 0.0, 1.0)
    return float(np.linalg.norm(p1 + d1 * s - (p2 + d2 * t)))


def place(cell: float, count: int, gap: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """count fibres of length 1 at random in a periodic cube, axes >= (2 + gap) R apart."""
    rng = np.random.default_rng(seed)
    R = 0.5 / BETA
    xs, ps = [], []
    while len(xs) < count:
        c = rng.uniform(0.0, cell, 3)
        p = rng.normal(size=3)
        p /= np.linalg.norm(p)
        ok = True
        for c2, p2 in zip(xs, ps):
            dc = c - c2
            dc -= cell * np.round(dc / cell)
            if np.linalg.norm(dc) > 1.0 + (2 + gap) * R:
                continue
            if _segment_distance(c - p / 2, c + p / 2, c - dc - p2 / 2, c - dc + p2 / 2) < (2 + gap) * R:
                ok = False
                break
        if ok:
            xs.append(c)
            ps.append(p)
    return np.array(xs), np.array(ps)


def solve(x, p, cell, n, **kw):
    P = Particles(x=x, p=p, radius=0.5 / BETA, length=1.0, shape="fibre")
    t0 = time.process_time()
    sol = solve_particles(P, [cell] * 3, (n, n, n), settings=StokesSettings(measure_plans=False, max_iter=20000,
                                                                             **kw))
    return sol, time.process_time() - t0


def errors(sol, ref):
    w = np.array([1.0, 1.0, 1.0, 0.5, 0.5, 0.5])
    a = np.hstack([sol.v, sol.omega]) * w
    b = np.hstack([ref.v, ref.omega]) * w
    vel = np.linalg.norm(a - b) / np.linalg.norm(b)
    rot = np.linalg.norm(a[:, 3:] - b[:, 3:]) / np.linalg.norm(b[:, 3:])
    eta = (sol.eta_eff - ref.eta_eff) / (ref.eta_eff - 1.0)
    return vel, rot, eta


def scene(cell, cpd, gap, seed, count=None, ref_tol=1e-10, only=None):
    """The table of one scene: count fibres (default n L^3 = 4) in a cube of side cell,
    cpd voxels per diameter, axes >= (2 + gap) R apart; the settings named in only (all)."""
    count = count or int(round(NL3 * cell**3))
    n = int(round(cell * BETA * cpd))
    x, p = place(cell, count, gap, seed)
    ref, tref = solve(x, p, cell, n, rigidity="exact", tol=ref_tol)
    print(f"\n{count} fibres, cell {cell} L, grid {n}^3 ({cpd} voxels per diameter), gap >= {gap} R; "
          f"reference: exact {ref_tol:g}, {ref.iterations} iterations, {tref:.1f} CPU-s "
          f"(load {os.getloadavg()[0]:.2f})", flush=True)
    print(f"  {'setting':<24} {'iter':>6} {'CPU-s':>7} {'CPU-s/iter':>10} {'vel err':>9} {'rot err':>9} {'eta err':>9}")
    for name, kw in SETTINGS.items():
        if only is not None and name not in only:
            continue
        sol, t = solve(x, p, cell, n, **kw)
        vel, rot, eta = errors(sol, ref)
        print(f"  {name:<24} {sol.iterations:>6d} {t:>7.2f} {t / max(sol.iterations, 1):>10.4f} {vel:>9.2e} "
              f"{rot:>9.2e} {eta:>+9.2e}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the 55-fibre scene at 3 voxels per diameter only")
    ap.add_argument("--big", action="store_true", help="the 128^3 scene of 305 fibres only (one solve per setting)")
    ap.add_argument("--only", nargs="*", default=None, choices=list(SETTINGS), metavar="NAME",
                    help="settings to run (default all)")
    ap.add_argument("--case", type=float, nargs=4, action="append", metavar=("CELL", "CPD", "GAP", "COUNT"),
                    help="only this scene (cell side in fibre lengths, voxels per diameter, gap in R, fibres; "
                         "0 fibres = n L^3 = 4); repeatable")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    if args.big:
        scene(4.25, 3, 0.2, args.seed, count=305, ref_tol=1e-6, only=args.only)
        print(f"\nload average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        return
    # (cell, voxels per diameter, gap, count): count None = n L^3 = 4
    cases = [(2.4, 3, 0.2, None)] if args.quick else [
        (2.4, 3, 0.2, None), (1.5, 3, 0.2, None), (3.2, 3, 0.2, None), (2.4, 3, 0.2, 14), (2.4, 3, 0.2, 28),
        (2.4, 2, 0.2, None), (2.4, 4, 0.2, None), (2.4, 3, 0.05, None), (2.4, 3, 0.5, None)]
    if args.case:
        cases = [(cell, int(cpd), gap, int(count) or None) for cell, cpd, gap, count in args.case]
    for cell, cpd, gap, count in cases:
        scene(cell, cpd, gap, args.seed, count=count, only=args.only)
    print(f"\nload average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
