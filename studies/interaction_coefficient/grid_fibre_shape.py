"""Which voxelised diameter makes a fibre on a coarse Stokes grid turn like the real fibre?

Question
    A fluid-coupled run fits Folgar–Tucker with a Jeffery term, and the trajectory C_I depends
    strongly on the ξ used there: at β = 10 on the 72³ grid of ci_fluid_series.py (3 voxels
    per diameter) one fibre turns like a fibre of β_e = 9.56, not Cox's 8.17, and fitting
    with one or the other ξ changes the IBOF C_I by 1.9·10⁻³, three quarters of its value
    (docs/fluid_coupled_ci.md). How does the grid fibre's β_e depend on the voxelised
    diameter on that grid, and which diameter makes it turn like Cox's β_e for the geometric
    β, or like the converged cylinder (Zhang et al. 2011's rule, which the solver's converged
    cylinder follows, docs/jeffery_orbits.md)? That diameter is what a hydrodynamic radius
    calibrated to the grid would be.

Method
    One fibre of length L = 1 and diameter d = 1/b for each b of ``--betas`` on the given grid
    and cubic cell, at the series' κ = 10³ and CG tolerance 10⁻³: the single-fibre check of
    ci_hydrodynamics.py (the solver's ω(θ) at fixed orientations in the shear plane, the
    Jeffery period from their quadrature, β_e from the period; ci_fluid_series.beta_e_on).
    The diameters giving the target β_e of the geometric ``--beta`` (Cox 1971, Zhang et al.
    2011: pyfold.kinematics.equivalent_aspect_ratio) are read off by linear interpolation of
    β_e against d between the two measured diameters that bracket it (NaN when none does).

Command
    .venv/bin/python studies/interaction_coefficient/grid_fibre_shape.py
    (defaults: --beta 10 --grid 72 --side 2.4 --betas 8 8.5 9 9.5 10, the β = 10 series' grid)

Cost (2 cores)
    46–54 CPU-s per diameter on the 72³ grid (measured while other runs shared the machine),
    about 4 CPU-min for the default five; each check is cached under ``--out``.

Outputs (under out/interaction_coefficient/grid_fibre_shape/, ``--out``)
    grid_fibre_shape.csv / .nc   per diameter: b, d, voxels per diameter, β_e of the grid fibre
    grid_fibre_shape.md          the table and the diameters that give Cox's and Zhang's β_e
    single_fibre_b<b>.nc         the single-fibre checks (cache)
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "studies" / "interaction_coefficient"))


def diameter_for(target: float, diameters, beta_e) -> float:
    """The diameter at which the grid fibre's β_e equals ``target``: linear interpolation between
    the two neighbouring measured diameters that bracket it; NaN when no pair does."""
    d = np.asarray(diameters, dtype=float)
    b = np.asarray(beta_e, dtype=float)
    order = np.argsort(d)
    d, b = d[order], b[order]
    for k in range(len(d) - 1):
        lo, hi = sorted((b[k], b[k + 1]))
        if lo <= target <= hi and b[k + 1] != b[k]:
            return float(d[k] + (target - b[k]) * (d[k + 1] - d[k]) / (b[k + 1] - b[k]))
    return math.nan


def main() -> None:
    import xarray as xr

    import ci_fluid_series as series
    from pyfold.kinematics import equivalent_aspect_ratio

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--beta", type=float, default=10.0, help="geometric aspect ratio of the fibre to imitate")
    ap.add_argument("--grid", type=int, default=72, help="Stokes grid points per side (cubic)")
    ap.add_argument("--side", type=float, default=2.4, help="cubic cell side [fibre lengths]")
    ap.add_argument("--betas", type=float, nargs="+", default=[8.0, 8.5, 9.0, 9.5, 10.0],
                    help="aspect ratios L/d of the voxelised fibres measured (d = 1/b)")
    ap.add_argument("--out", type=Path, default=Path("out/interaction_coefficient/grid_fibre_shape"))
    args = ap.parse_args()
    for name, value in (("--beta", args.beta), *(("--betas", b) for b in args.betas)):
        if not value > 1.0:
            ap.error(f"{name}: {value:g}; aspect ratios must be > 1")
    if args.grid < 8:
        ap.error(f"--grid: {args.grid}; at least 8 points per side")
    if not args.side > 1.0:
        ap.error(f"--side: {args.side:g}; the cell must be longer than the fibre (> 1)")
    args.out.mkdir(parents=True, exist_ok=True)
    betas = sorted(set(args.betas))
    diameters = [1.0 / b for b in betas]
    voxels = [args.grid / args.side * d for d in diameters]  # voxels per diameter
    measured = []
    for b, d, v in zip(betas, diameters, voxels):
        be = series.beta_e_on([args.grid] * 3, args.side, args.out / f"single_fibre_b{b:g}.nc", b)
        measured.append(be)
        print(f"b = {b:g} (d = {d:.4f} L, {v:.2f} voxels per diameter): beta_e = {be:.3f}", flush=True)
    targets = {rule: float(equivalent_aspect_ratio(args.beta, rule)) for rule in ("cox", "zhang")}
    found = {rule: diameter_for(t, diameters, measured) for rule, t in targets.items()}
    ds = xr.Dataset(
        {"beta_e": (("b",), measured, {"units": "1", "long_name": "equivalent aspect ratio of the grid fibre"}),
         "diameter": (("b",), diameters, {"units": "L", "long_name": "voxelised fibre diameter"}),
         "voxels_per_diameter": (("b",), voxels, {"units": "1"})},
        coords={"b": ("b", betas, {"units": "1", "long_name": "L/d of the voxelised fibre"})},
        attrs={"title": f"beta_e of one fibre on the {args.grid}^3 grid of a {args.side:g} L cell against its diameter",
               "command": "studies/interaction_coefficient/grid_fibre_shape.py " + " ".join(sys.argv[1:]),
               **{f"diameter_for_{rule}": found[rule] for rule in targets},
               **{f"target_beta_e_{rule}": targets[rule] for rule in targets}})
    ds.to_netcdf(args.out / "grid_fibre_shape.nc")
    ds.to_dataframe().to_csv(args.out / "grid_fibre_shape.csv")
    lines = [f"# β_e of one fibre on the {args.grid}³ grid ({args.side:g} L cell) against its diameter", "",
             "| L/d | d [L] | voxels per diameter | β_e of the grid fibre |", "|---|---|---|---|"]
    lines += [f"| {b:g} | {d:.4f} | {v:.2f} | {be:.3f} |" for b, d, v, be in zip(betas, diameters, voxels, measured)]
    lines.append("")
    for rule, t in targets.items():
        d = found[rule]
        lines.append(f"* {rule}: β_e({args.beta:g}) = {t:.3f} → diameter "
                     + (f"{d:.4f} L ({d * args.beta:.3f} of the geometric 1/β)" if math.isfinite(d)
                        else "outside the measured range (add --betas)"))
    text = "\n".join(lines) + "\n"
    (args.out / "grid_fibre_shape.md").write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
