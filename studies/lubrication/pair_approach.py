"""Approach rate of two spheres in shear: the grid's flow, refined, against the lubrication correction.

Question
    Two equal spheres (R = 0.125 in a unit periodic cell, simple shear gamma_dot = 1) sit on
    the compressional axis (1, -1, 0)/sqrt 2 of the shear with surface gap h. The flow pushes
    them together at the normal rate w (relative velocity along the line of centres). How
    does the rate the fictitious-domain Stokes solver gives converge with the grid, and
    does the lubrication correction of fortran/contact/fold_lubrication.f90 (threshold
    h_c = 2 voxels, isolated-sphere mobility; docs/physics.md#lubrication-between-spheres)
    bring a coarse grid's rate closer to the converged one?

Method
    One Stokes solve per (gap, grid) through pyfold.native.stokes.solve_particles (the same
    solver and rigid fit as fold_run), tolerance 1e-8. The ratio w / w_affine (w_affine = the
    imposed flow's normal rate at the centres) is reported for the flow and for the flow with
    the lubrication correction. For one pair the correction is the closed form of the module
    header, w_corr = w (M/2) / (M/2 + c), M = 6 pi eta R, c = (3/2) pi eta R^2 (1/h - 1/h_c)
    for h < h_c (fortran/stokes/tests/test_lubrication.f90 and tests/micro/test_run_lubrication.py
    check that fold_run's correction equals it to round-off). The converged rate is estimated
    by Richardson extrapolation of the three finest grids with the observed order (reported;
    NaN when the sequence is not monotone and contracting). Deterministic: no random draw.

Command
    nice -n 10 python studies/lubrication/pair_approach.py            # grids 16, 32, 64
    nice -n 10 python studies/lubrication/pair_approach.py --large    # adds 128 (16 -> 32 voxels per diameter)

Cost on 2 cores
    small form: 12 solves, 17 s wall; large form: 16 solves, 3.6 min wall (load average 5;
    the four 128^3 solves dominate).

Outputs
    out/lubrication_pair_approach.nc (xarray: flow_ratio(gap, grid), corrected_ratio(gap, grid),
    richardson_limit(gap), observed_order(gap); gap in units of R, grid in voxels per edge) and
    a table on stdout.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import xarray as xr

from pyfold.native.stokes import Particles, StokesSettings, solve_particles

# Parameters
R = 0.125  # sphere radius [m] (cell side 1 m)
ETA = 1.0  # fluid viscosity [Pa s] (StokesSettings default; the ratios do not depend on it)
GAPS = (0.5, 0.25, 0.1, 0.05)  # surface gap / R
H_C_VOXELS = 2.0  # LUB_THRESHOLD_VOXELS of fortran/contact/fold_lubrication.f90


def approach_ratio(gap: float, n: int) -> float:
    """w / w_affine of the flow for surface gap `gap` [m] on an n^3 grid."""
    e = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    half = 0.5 * (2.0 * R + gap)
    x = np.array([[0.5, 0.5, 0.5]]) + np.array([[-1.0], [1.0]]) * half * e
    parts = Particles(x=x, p=[[1.0, 0.0, 0.0]] * 2, radius=[R, R], length=[2 * R, 2 * R], shape=["sphere"] * 2)
    sol = solve_particles(parts, [1.0, 1.0, 1.0], (n, n, n), settings=StokesSettings(tol=1e-8))
    r = x[0] - x[1]
    unit = r / np.linalg.norm(r)
    w = float(np.dot(sol.v[0] - sol.v[1], unit))
    w_affine = float(r[1] * unit[0])  # u = gamma_dot (y - 1/2) e_x
    return w / w_affine


def corrected(ratio: float, gap: float, n: int) -> float:
    """The lubrication-corrected ratio (closed form of fold_lubrication for one pair)."""
    h_c = H_C_VOXELS / n
    if gap >= h_c:
        return ratio
    m = 6.0 * np.pi * ETA * R
    c = 1.5 * np.pi * ETA * R**2 * (1.0 / gap - 1.0 / h_c)
    return ratio * 0.5 * m / (0.5 * m + c)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="add the 128^3 grid")
    ap.add_argument("--out", type=Path, default=Path("out/lubrication_pair_approach.nc"))
    args = ap.parse_args()
    grids = (16, 32, 64, 128) if args.large else (16, 32, 64)

    # Run
    flow = np.array([[approach_ratio(g * R, n) for n in grids] for g in GAPS])
    corr = np.array([[corrected(flow[i, j], g * R, n) for j, n in enumerate(grids)] for i, g in enumerate(GAPS)])
    order = np.full(len(GAPS), np.nan)
    limit = np.full(len(GAPS), np.nan)
    for i in range(len(GAPS)):
        f1, f2, f3 = flow[i, -3:]
        # a converging sequence: successive differences of one sign, shrinking
        if (f1 - f2) * (f2 - f3) > 0 and abs(f1 - f2) > abs(f2 - f3):
            order[i] = np.log2((f1 - f2) / (f2 - f3))
            limit[i] = f3 - (f2 - f3) / (2.0 ** order[i] - 1.0)

    # Save
    ds = xr.Dataset(
        {
            "flow_ratio": (("gap", "grid"), flow, {"units": "1", "long_name": "w / w_affine of the Stokes flow"}),
            "corrected_ratio": (("gap", "grid"), corr,
                                {"units": "1", "long_name": "w / w_affine with the lubrication correction"}),
            "richardson_limit": ("gap", limit, {"units": "1", "long_name": "extrapolated w / w_affine"}),
            "observed_order": ("gap", order, {"units": "1", "long_name": "observed convergence order"}),
        },
        coords={"gap": ("gap", np.array(GAPS), {"units": "R", "long_name": "surface gap / radius"}),
                "grid": ("grid", np.array(grids), {"units": "1", "long_name": "voxels per cell edge"})},
        attrs={"radius": R, "threshold_voxels": H_C_VOXELS, "command": "studies/lubrication/pair_approach.py"},
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    ds.to_netcdf(args.out)
    for i, g in enumerate(GAPS):
        for j, n in enumerate(grids):
            print(f"gap {g:5.2f} R  grid {n:4d} ({2 * R * n:4.0f} voxels/diameter, gap {g * R * n:5.2f} voxels): "
                  f"flow {flow[i, j]:.4f}  corrected {corr[i, j]:.4f}")
        print(f"   converged estimate {limit[i]:.4f} (observed order {order[i]:.2f})")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
