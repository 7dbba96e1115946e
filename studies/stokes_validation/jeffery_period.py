"""Jeffery period of a prolate spheroid from the fictitious-domain Stokes solver.

Question: how does the orbit period T of a beta = 3 spheroid in simple shear,
computed by the FFT Stokes solver in a periodic cell 3 lengths wide, converge to
Jeffery's T = (2 pi / gamma_dot)(beta + 1/beta) (Jeffery 1922) as the grid is
refined, and at which observed order?
Method: Stokes flow has no memory, so the orbit is dtheta/dt = omega(theta) with
omega computed at fixed orientations; T = int_0^{2 pi} dtheta / |omega(theta)|
by the trapezoid rule on n_theta orientations. The solver's omega(theta) carries
voxelisation wiggles, so the rule is NOT spectrally accurate here: at 27^3 the
period moves 18.79 / 18.44 / 18.25 / 18.22 / 18.17 / 18.19 for 8 / 16 / 24 / 32 /
48 / 96 orientations (benchmarks/bench_speed_accuracy.py); use >= 48. A time-marched orbit converges to this T as dt -> 0
(see tests/micro/test_stokes.py for the Euler/AB2 orders).
Command:  python studies/stokes_validation/jeffery_period.py [--grids 48 64 96] [--ntheta 48]
Cost (48 orientations, load ~1): 48^3 38 s, 64^3 79 s, 96^3 several minutes. Output: a table
(grid, voxels per diameter, T, relative error, observed order).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from pyfold.native.stokes import Particles, StokesSettings, solve_particles

# Parameters
BETA = 3.0
CELLS_PER_LENGTH = 3.0  # cell = 3 particle lengths


def jeffery_period(beta: float = BETA, shear_rate: float = 1.0) -> float:
    """Jeffery's orbit period T = (2 pi / gamma_dot)(beta + 1/beta) of a spheroid of aspect
    ratio beta in unbounded simple shear (Jeffery 1922, Proc. R. Soc. A 102:161)."""
    return 2 * np.pi / shear_rate * (beta + 1 / beta)


def spheroid_at(theta: float) -> Particles:
    """The BETA spheroid at the centre of the unit cell (CELLS_PER_LENGTH lengths wide),
    axis in the flow-gradient plane at angle theta from the flow direction."""
    b = 1.0 / (2 * BETA * CELLS_PER_LENGTH)  # minor semi-axis, cell of size 1
    return Particles(x=[[0.5, 0.5, 0.5]], p=[[np.cos(theta), np.sin(theta), 0.0]], radius=b,
                     length=2 * BETA * b, shape="spheroid")


def orientations(ntheta: int) -> np.ndarray:
    """ntheta equispaced angles over [0, pi) (omega has period pi)."""
    return np.pi * np.arange(ntheta) / ntheta


def period_from_omegas(omegas) -> float:
    """T = int_0^{2 pi} dtheta / |omega| = 2 int_0^pi, by the trapezoid rule on the
    equispaced orientations of ``orientations`` (spectrally accurate: smooth, periodic)."""
    return 2 * np.pi * np.mean(1.0 / np.abs(np.asarray(omegas)))


def omega_at(theta: float, n: int, settings: StokesSettings) -> float:
    return solve_particles(spheroid_at(theta), [1, 1, 1], (n, n, n), settings=settings).omega[0, 2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", type=int, nargs="+", default=[36, 48, 64])
    ap.add_argument("--ntheta", type=int, default=48)
    ap.add_argument("--kappa", type=float, default=1e3)
    args = ap.parse_args()
    # Problem / Solver
    settings = StokesSettings(kappa=args.kappa, tol=1e-6)
    exact = jeffery_period()
    thetas = orientations(args.ntheta)
    # Run
    rows = []
    for n in args.grids:
        t0 = time.perf_counter()
        om = np.array([omega_at(th, n, settings) for th in thetas])
        T = period_from_omegas(om)
        rows.append((n, n / (BETA * CELLS_PER_LENGTH), T, T / exact - 1, time.perf_counter() - t0))
    # Save (print)
    print(f"{'grid':>5} {'vox/diam':>8} {'T':>9} {'rel err':>9} {'order':>6} {'wall [s]':>9}")
    for i, (n, vpd, T, err, wall) in enumerate(rows):
        order = "" if i == 0 else f"{np.log(abs(rows[i-1][3] / err)) / np.log(n / rows[i-1][0]):6.2f}"
        print(f"{n:>5} {vpd:>8.2f} {T:>9.4f} {err:>9.4f} {order:>6} {wall:>9.1f}")
    print(f"Jeffery: T = {exact:.4f}")


if __name__ == "__main__":
    main()
