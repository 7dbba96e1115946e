"""Jeffery period of a voxelised spheroid under the penalised and the exact-rigidity solve,
against resolution.

Question: does imposing rigidity exactly (numerics.stokes.rigidity = "exact") reduce the
coarse-grid error of a particle's Jeffery period, i.e. the resolution a study needs?
Scene: one prolate spheroid of aspect ratio beta (default 3) at the centre of a cubic
periodic cell 2.7 particle lengths wide, simple shear gamma_dot = 1, at 3, 4, 5.3, 7.1 and
8.9 voxels per diameter. Two static solves per setting (axis along the flow and along
the gradient) give the shape factor of the discretised body, lambda = omega(axis x) -
omega(axis y) (Jeffery 1922: theta' = -1/2 + (lambda/2) cos 2 theta), hence its period
T = 4 pi / (gamma_dot sqrt(1 - lambda^2)) (a full turn of p); the continuum spheroid has
lambda = (beta^2 - 1)/(beta^2 + 1) and T = 2 pi (beta + 1/beta). The cell's images shift
lambda by O(n L^3) (here n L^3 = 0.05), the same for both solves.
Command:  nice -n 5 python benchmarks/bench_rigidity_period.py [--beta 3] [--cpd 3 4 5.3 7.1 8.9]
Cost: ~3 CPU-min on 2 cores (the 71^3 penalised solves dominate). Prints a table.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from pyfold.native.stokes import Particles, StokesSettings, solve_particles


def shape_factor(beta: float, cpd: float, settings: StokesSettings) -> tuple[float, int, float]:
    """lambda of the voxelised spheroid, the grid size and the CG iterations of the two solves."""
    n = int(round(8 * cpd))  # cell = 8 diameters = 2.67 lengths at beta = 3
    R = 0.5 * cpd / n
    om, its = [], 0
    for axis in ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]):
        P = Particles(x=[[0.5, 0.5, 0.5]], p=[axis], radius=R, length=2 * beta * R, shape="spheroid")
        sol = solve_particles(P, [1, 1, 1], (n, n, n), settings=settings)
        om.append(sol.omega[0, 2])
        its += sol.iterations
    return om[0] - om[1], n, its


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--beta", type=float, default=3.0)
    ap.add_argument("--cpd", type=float, nargs="*", default=[3, 4, 5.3, 7.1, 8.9])
    ap.add_argument("--tol", type=float, default=1e-7)
    args = ap.parse_args()
    beta = args.beta
    lam0 = (beta**2 - 1) / (beta**2 + 1)
    period0 = 2 * np.pi * (beta + 1 / beta)
    settings = {
        "penalty kappa 1e3 (harmonic)": StokesSettings(kappa=1e3, tol=args.tol, measure_plans=False),
        "exact": StokesSettings(rigidity="exact", tol=args.tol, measure_plans=False),
    }
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    print(f"prolate spheroid beta = {beta:g}: continuum lambda = {lam0:.4f}, period = {period0:.3f} / gamma_dot")
    print(f"{'vox/diam':>8} {'grid':>5} {'setting':<30} {'lambda':>8} {'period err':>10} {'CG its':>7} {'s':>6}")
    for cpd in args.cpd:
        for name, st in settings.items():
            t0 = time.perf_counter()
            lam, n, its = shape_factor(beta, cpd, st)
            period = 4 * np.pi / np.sqrt(1 - lam**2)
            print(f"{cpd:>8.1f} {n:>5d} {name:<30} {lam:>8.4f} {period / period0 - 1:>+10.2%} {its:>7d} "
                  f"{time.perf_counter() - t0:>6.1f}", flush=True)
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
