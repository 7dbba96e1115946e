"""Bulk stress of a Stokes-coupled fibre DNS against the slender-body constitutive law.

Question: does the particle stress of a fibre suspension simulated with the FFT Stokes
solver follow the slender-body constitutive law sigma_p = eta_f N_p a4:D fed with the
run's own fourth-order orientation tensor a4(t) (Batchelor 1971, *J. Fluid Mech.*
46:813; Dinh & Armstrong 1984, *J. Rheol.* 28:207) over the orientation transient from
an isotropic start, for the shear stress sigma_p,xy and the first normal stress
difference N1 = sigma_xx - sigma_yy, and how large is the solver's resolution error?

Law. A slender rigid fibre (length L, diameter d) in the strain rate D carries the
axial force per length zeta (s p.D.p), s in [-L/2, L/2], with the drag coefficient
zeta = 2 pi eta_f / ln(2h/d) of a fibre screened by its neighbours at distance h
(Batchelor's cell model); its stresslet is zeta L^3/12 pppp:D, so

    sigma_p = eta_f N_p a4:D,    N_p = pi n L^3 / (6 ln(2h/d))

(n fibres per volume), with h = (n L)^(-1/2) (parallel fibres, Batchelor 1971) or
h = 1/(n L^2) (random orientation, Dinh & Armstrong 1984). Both spacings are
tabulated. The law neglects O(1/ln(2h/d)) corrections and the O(phi) terms of a
finite aspect ratio (Lipscomb et al. 1988 form 2 eta_f phi (A a4:D + B (a2.D + D.a2) +
C D)); at beta = 5 those are not small, so the DNS is also fitted by

    sigma_p = eta_f (N_fit a4:D + 2 B_fit D),

whose N_fit comes from N1 alone (D carries no N1) and B_fit from sigma_xy. In simple
shear u = (gamma_dot y, 0, 0): (a4:D)_xy = gamma_dot a4_xxyy and
N1 = eta_f N gamma_dot (a4_xxxy - a4_yyxy).

DNS. pyfold.scene.sheared_fibres with hydrodynamics = "stokes": beta = 5 fibres (L = 1,
d = 0.2), flat-ended cylinders, isotropic start, contacts on (alpha = 0.1 d), kappa =
1e3, AB2; its records give stress(t) (deviatoric bulk stress <2 eta eps(u)>, so
sigma_p = stress - 2 eta_f E) and a4(t). The particle stress of a configuration does not
depend on the past (Stokes flow), so the resolution error is measured on the run's
snapshots: each is re-solved (pyfold.native.stokes.solve_particles, the run's settings)
on three grids; the re-solve on the run's own grid reproduces the recorded stress (a
check of the frame and Lees-Edwards offset), the observed order and the extrapolation
give the error of the run's grid.

Command:  python studies/rheology/fibre_stress.py                 (small form)
          python studies/rheology/fibre_stress.py --large         (large form)
          python studies/rheology/fibre_stress.py --analyse RUN.h5 [RUN.h5 ...]
                (the law and fits on existing Stokes fibre runs, no simulation)
Cost on 2 cores (nice 10): small form (39 fibres, n L^3 = 2, 42^3 grid, strain 10, 500
steps; then 6 snapshots re-solved on 42^3/54^3/64^3): the run about 5 CPU-min (17 min wall
at a load average of 9), the re-solves 22 CPU-s; --analyse of the four 98-fibre runs of
studies/interaction_coefficient/ci_hydrodynamics.py (2 snapshots each) 23 CPU-s. Large
form (n L^3 = 5, 54^3 grid, strain 30) not run; estimated 30-40 CPU-min.
Outputs: out/rheology/fibre_stress.{nc,md,png} and the run under out/rheology/runs/.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import xarray as xr

from pyfold.command_line import command_line
from pyfold.native.stokes import Particles, StokesSettings, solve_particles
from pyfold.run_results import open_run
from pyfold.scene.sheared_fibres import sheared_fibres

# Parameters
BETA = 5.0
#: security zone in diameters (the design above: alpha = 0.1 d)
ALPHA_OVER_D = 0.1
SMALL = dict(n_l3=2.0, t_end=10.0, cells_per_diameter=3, snapshots=5, regrid=(42, 54, 64), seed=1)
LARGE = dict(n_l3=5.0, t_end=30.0, cells_per_diameter=4, snapshots=10, regrid=(54, 64, 81), seed=1)
TOLERANCE = 1e-5
KAPPA = 1e3


def spacing(n: float, L: float, kind: str) -> float:
    """Mean inter-fibre distance h: (n L)^(-1/2) for parallel fibres (Batchelor 1971),
    1/(n L^2) for random orientation (Dinh & Armstrong 1984)."""
    return (n * L) ** -0.5 if kind == "aligned" else 1.0 / (n * L * L)


def n_p(n: float, L: float, d: float, kind: str) -> float:
    """Slender-body particle-stress coefficient N_p = pi n L^3 / (6 ln(2h/d))."""
    return math.pi * n * L ** 3 / (6.0 * math.log(2.0 * spacing(n, L, kind) / d))


def a4_colon_shear(a4: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a4:D)_xy and (a4:D)_xx - (a4:D)_yy for u = (y, 0, 0) (gamma_dot = 1)."""
    return a4[..., 0, 0, 1, 1], a4[..., 0, 0, 0, 1] - a4[..., 1, 1, 0, 1]


def fit_law(sxy, n1, a4, eta_f) -> dict:
    """Least squares of N1 = eta_f N (a4:D)_N1 (one parameter) and then
    sigma_xy = eta_f (N (a4:D)_xy + B) for B (the 2 B D term, D_xy = 1/2)."""
    axy, an1 = a4_colon_shear(a4)
    N = float(np.dot(an1, n1) / (eta_f * np.dot(an1, an1)))
    B = float(np.mean(sxy / eta_f - N * axy))
    N_xy_only = float(np.dot(axy, sxy) / (eta_f * np.dot(axy, axy)))
    return dict(N_fit=N, B_fit=B, N_xy_only=N_xy_only,
                rms_n1=float(np.sqrt(np.mean((n1 - eta_f * N * an1) ** 2))),
                rms_xy=float(np.sqrt(np.mean((sxy - eta_f * (N * axy + B)) ** 2))))


def lees_edwards_offset(t: float, shear_rate: float, side: float) -> float:
    """s = gamma_dot t Ly wrapped to [-Lx/2, Lx/2) (docs/physics.md#periodic-cell-and-imposed-flow)."""
    s = shear_rate * t * side
    return (s + 0.5 * side) % side - 0.5 * side


def resolve_snapshot(ds, k: int, side: float, grid: int) -> np.ndarray:
    """Deviatoric bulk stress of snapshot k re-solved on grid^3 with the run's settings."""
    P = Particles(x=ds["x"].values[k], p=ds["p"].values[k], radius=ds["particle_radius"].values,
                  length=ds["particle_length"].values, shape="fibre", xi=ds["particle_xi"].values)
    s = StokesSettings(eta_f=float(ds.attrs["viscosity"]), kappa=float(ds.attrs["stokes_kappa"]),
                       tol=float(ds.attrs["stokes_tolerance"]),
                       derivative={0: "spectral", 1: "fd"}[int(ds.attrs["stokes_derivative"])])
    t = float(ds["snapshot_time"].values[k])
    sol = solve_particles(P, [side] * 3, (grid,) * 3, shear_rate=float(ds.attrs["shear_rate"]),
                          shear_offset=lees_edwards_offset(t, float(ds.attrs["shear_rate"]), side), settings=s)
    return np.asarray(sol.stress)


def observed_order(h, f):
    """Observed order and extrapolation from three spacings (nan when not monotone)."""
    d1, d2 = f[0] - f[1], f[1] - f[2]
    if d1 == 0 or d2 == 0 or np.sign(d1) != np.sign(d2):
        return np.nan, np.nan
    r = d1 / d2
    lo, hi = 0.2, 6.0

    def g(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - r

    if g(lo) * g(hi) > 0:
        return np.nan, np.nan
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if g(lo) * g(mid) <= 0 else (mid, hi)
    p = 0.5 * (lo + hi)
    return p, f[2] - d2 / ((h[1] / h[2]) ** p - 1.0)  # f3 + (f3 - f2)/((h2/h3)^p - 1)


def run_dns(cfg: dict, runs: Path) -> Path:
    """The small/large Stokes fibre run (simulated once, reused afterwards)."""
    from pyfold.cli import main as cli_main

    scene = sheared_fibres(BETA, cfg["n_l3"], cfg["seed"], cfg["t_end"], interval=0.1, alpha_over_d=ALPHA_OVER_D,
                           hydrodynamics="stokes",
                           stokes={"cells_per_diameter": cfg["cells_per_diameter"], "tolerance": TOLERANCE,
                                   "kappa": KAPPA, "fft_plan": "estimate"}, time_scheme="ab2")
    snap = round(scene.t_end / cfg["snapshots"], 12)
    toml = scene.toml.replace(f"snapshot_interval = {scene.t_end!r}", f"snapshot_interval = {snap!r}")
    name = f"stokes_b{BETA:g}_nl3-{cfg['n_l3']:g}_cpd{cfg['cells_per_diameter']}_t{cfg['t_end']:g}_s{cfg['seed']}"
    out = runs / f"{name}.h5"
    path = runs / f"{name}.toml"
    if out.exists() and path.exists() and path.read_text(encoding="utf-8") == toml:
        return out
    runs.mkdir(parents=True, exist_ok=True)
    path.write_text(toml, encoding="utf-8")
    t0 = time.perf_counter()
    status = cli_main(["run", str(path), "-o", str(out), "--force"] if out.exists() else ["run", str(path), "-o", str(out)])
    if status != 0:
        raise RuntimeError(f"pyfold run {path} failed with status {status}")
    (runs / f"{name}.cost.json").write_text(json.dumps({"wall_s": time.perf_counter() - t0}), encoding="utf-8")
    return out


def analyse(path: Path, regrid) -> tuple[xr.Dataset, list[str]]:
    ds = open_run(path)
    scene = json.loads(ds.attrs["scene"])
    side = float(scene["cell"]["size"][0])
    eta_f = float(ds.attrs["viscosity"])
    rate = float(ds.attrs["shear_rate"])
    if rate != 1.0:
        raise ValueError(f"{path}: the analysis assumes shear_rate = 1, got {rate}")
    N = int(ds.sizes["particle"])
    L = float(ds["particle_length"].values[0])
    d = 2.0 * float(ds["particle_radius"].values[0])
    n = N / side ** 3
    t = ds["time"].values
    stress = ds["stress"].values
    a4 = ds["a4"].values
    a2 = ds["a2"].values
    sp = stress.copy()
    sp[:, 0, 1] -= eta_f * rate
    sp[:, 1, 0] -= eta_f * rate  # sigma_p = Sigma' - 2 eta_f E
    sxy = sp[:, 0, 1]
    n1 = sp[:, 0, 0] - sp[:, 1, 1]
    axy, an1 = a4_colon_shear(a4)
    coeffs = {kind: n_p(n, L, d, kind) for kind in ("aligned", "random")}
    fit = fit_law(sxy[1:], n1[1:], a4[1:], eta_f)  # the records after the start (t > 0)
    run_grid = scene.get("numerics", {}).get("stokes", {}).get("cells_per_diameter")
    # resolution: snapshots re-solved on three grids
    snaps = range(int(ds.sizes.get("snapshot", 0)))
    res = np.full((len(snaps), len(regrid), 2), np.nan)
    for k in snaps:
        for j, g in enumerate(regrid):
            s = resolve_snapshot(ds, k, side, g)
            res[k, j] = (s[0, 1] - eta_f * rate, s[0, 0] - s[1, 1])
        print(f"  snapshot t = {float(ds['snapshot_time'].values[k]):.2f}: sigma_p,xy "
              + " ".join(f"{v:.4f}" for v in res[k, :, 0]) + "; N1 " + " ".join(f"{v:.4f}" for v in res[k, :, 1]),
              flush=True)
    snap_t = ds["snapshot_time"].values if len(snaps) else np.array([])
    rec_at_snap = np.array([np.argmin(np.abs(t - ts)) for ts in snap_t], int)
    h = side / np.array(regrid, float)
    orders = np.full((len(snaps), 2), np.nan)
    extra = np.full((len(snaps), 2), np.nan)
    for k in snaps:
        for c in range(2):
            orders[k, c], extra[k, c] = observed_order(h, res[k, :, c])
    out = xr.Dataset(
        {
            "sigma_p_xy": (("time",), sxy, dict(units="Pa", long_name="particle shear stress (DNS)")),
            "N1": (("time",), n1, dict(units="Pa", long_name="first normal stress difference (DNS)")),
            "a4_xxyy": (("time",), axy, dict(units="1", long_name="(a4:D)_xy / gamma_dot")),
            "a4_N1": (("time",), an1, dict(units="1", long_name="((a4:D)_xx - (a4:D)_yy) / gamma_dot")),
            "a2": (("time", "i", "j"), a2, dict(units="1", long_name="a2 (DNS)")),
            "law_aligned_xy": (("time",), eta_f * coeffs["aligned"] * axy, dict(units="Pa", long_name="eta_f N_p a4:D, h = (nL)^-1/2")),
            "law_random_xy": (("time",), eta_f * coeffs["random"] * axy, dict(units="Pa", long_name="eta_f N_p a4:D, h = 1/(nL^2)")),
            "law_aligned_N1": (("time",), eta_f * coeffs["aligned"] * an1, dict(units="Pa", long_name="N1 of the law, h = (nL)^-1/2")),
            "law_random_N1": (("time",), eta_f * coeffs["random"] * an1, dict(units="Pa", long_name="N1 of the law, h = 1/(nL^2)")),
            "fit_xy": (("time",), eta_f * (fit["N_fit"] * axy + fit["B_fit"]), dict(units="Pa", long_name="eta_f (N_fit a4:D + 2 B_fit D)_xy")),
            "fit_N1": (("time",), eta_f * fit["N_fit"] * an1, dict(units="Pa", long_name="N1 of the fit")),
            "regrid_sigma_p_xy": (("snapshot", "regrid"), res[:, :, 0], dict(units="Pa", long_name="snapshot re-solved: sigma_p,xy")),
            "regrid_N1": (("snapshot", "regrid"), res[:, :, 1], dict(units="Pa", long_name="snapshot re-solved: N1")),
            "regrid_order": (("snapshot", "component"), orders, dict(units="1", long_name="observed order (xy, N1)")),
            "regrid_extrapolated": (("snapshot", "component"), extra, dict(units="Pa", long_name="extrapolated (xy, N1)")),
            "recorded_at_snapshot": (("snapshot", "component"), np.stack([sxy[rec_at_snap], n1[rec_at_snap]], -1) if len(snaps) else np.zeros((0, 2)),
                                     dict(units="Pa", long_name="run's recorded value at the snapshot time")),
        },
        coords=dict(time=("time", t, dict(units="s", long_name="time (strain, gamma_dot = 1)")),
                    i=["x", "y", "z"], j=["x", "y", "z"], snapshot_time=("snapshot", snap_t, dict(units="s")),
                    regrid=("regrid", np.array(regrid), dict(units="1", long_name="voxels per cell side")),
                    component=["xy", "N1"]),
        attrs=dict(run=str(path), beta=L / d, n_L3=n * L ** 3, count=N, side=side, eta_f=eta_f,
                   N_p_aligned=coeffs["aligned"], N_p_random=coeffs["random"],
                   h_aligned=spacing(n, L, "aligned"), h_random=spacing(n, L, "random"),
                   run_cells_per_diameter=str(run_grid), **{k: v for k, v in fit.items()}),
    )
    lines = [f"### {Path(path).name}", "",
             f"beta = {L / d:g}, {N} fibres, n L^3 = {n * L ** 3:.3g}, phi = {N * math.pi * d * d / 4 * L / side ** 3:.3f}, "
             f"cell {side:g} L, records to strain {t[-1]:g}.", "",
             "| coefficient | value | note |", "|---|---|---|",
             f"| N_p, h = (nL)^-1/2 = {spacing(n, L, 'aligned'):.3f} | {coeffs['aligned']:.3f} | Batchelor 1971 spacing |",
             f"| N_p, h = 1/(nL^2) = {spacing(n, L, 'random'):.3f} | {coeffs['random']:.3f} | Dinh & Armstrong 1984, random |",
             f"| N_fit (from N1) | {fit['N_fit']:.3f} | rms N1 residual {fit['rms_n1']:.2e} Pa |",
             f"| B_fit (2 B D term, from sigma_xy) | {fit['B_fit']:.3f} | rms sigma_xy residual {fit['rms_xy']:.2e} Pa |",
             f"| N from sigma_xy alone (B = 0) | {fit['N_xy_only']:.3f} | |", "",
             "| strain | a4_xxyy | sigma_p,xy DNS | law (aligned h) | law (random h) | fit | N1 DNS | N1 law (aligned h) | N1 law (random h) | N1 fit |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in np.unique(np.linspace(1, len(t) - 1, min(11, len(t) - 1)).round().astype(int)):
        lines.append(f"| {t[r]:.1f} | {axy[r]:.4f} | {sxy[r]:.4f} | {out['law_aligned_xy'].values[r]:.4f} | "
                     f"{out['law_random_xy'].values[r]:.4f} | {out['fit_xy'].values[r]:.4f} | {n1[r]:.4f} | "
                     f"{out['law_aligned_N1'].values[r]:.4f} | {out['law_random_N1'].values[r]:.4f} | {out['fit_N1'].values[r]:.4f} |")
    if len(snaps):
        lines += ["", "Resolution (snapshots re-solved; run's recorded value beside the re-solves):", "",
                  "| strain | recorded xy | " + " | ".join(f"xy {g}^3" for g in regrid) + " | xy extrap. (p) | recorded N1 | "
                  + " | ".join(f"N1 {g}^3" for g in regrid) + " | N1 extrap. (p) |",
                  "|" + "---|" * (2 * len(regrid) + 5)]
        for k in snaps:
            fx = "–" if np.isnan(extra[k, 0]) else f"{extra[k, 0]:.4f} ({orders[k, 0]:.1f})"
            fn = "–" if np.isnan(extra[k, 1]) else f"{extra[k, 1]:.4f} ({orders[k, 1]:.1f})"
            lines.append(f"| {snap_t[k]:.1f} | {sxy[rec_at_snap[k]]:.4f} | " + " | ".join(f"{v:.4f}" for v in res[k, :, 0])
                         + f" | {fx} | {n1[rec_at_snap[k]]:.4f} | " + " | ".join(f"{v:.4f}" for v in res[k, :, 1]) + f" | {fn} |")
    return out, lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true")
    ap.add_argument("--analyse", type=Path, nargs="+", help="existing Stokes fibre run files (no simulation)")
    ap.add_argument("--regrid", type=int, nargs=3, help="three re-solve grids (default: the form's)")
    ap.add_argument("--out", type=Path, default=Path("out/rheology"))
    args = ap.parse_args()
    cfg = LARGE if args.large else SMALL
    regrid = tuple(args.regrid or cfg["regrid"])
    args.out.mkdir(parents=True, exist_ok=True)
    cpu0 = time.process_time()
    # Run
    paths = args.analyse or [run_dns(cfg, args.out / "runs")]
    # Analyse / Save
    lines = ["# Fibre suspension stress vs the slender-body law", ""]
    sets = []
    for path in paths:
        print(f"analysing {path}", flush=True)
        ds, text = analyse(path, regrid)
        sets.append(ds)
        lines += text + [""]
    stem = "fibre_stress" if not args.analyse else "fibre_stress_analysed"
    combined = xr.concat(sets, dim="run", combine_attrs="drop") if len(sets) > 1 else sets[0]
    combined.attrs.update(command=command_line(["python", "studies/rheology/fibre_stress.py"]
                                               + (["--large"] if args.large else [])
                                               + (["--analyse", *args.analyse] if args.analyse else [])),
                          cpu_seconds_analysis=time.process_time() - cpu0)
    combined.to_netcdf(args.out / f"{stem}.nc", engine="h5netcdf")
    (args.out / f"{stem}.md").write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(11, 4))
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(1, 2)
    for r, ds in enumerate(sets):
        lab = dict(label="DNS") if r == 0 else {}
        ax1.plot(ds.time, ds.sigma_p_xy, "k-", lw=0.8, **lab)
        ax2.plot(ds.time, ds.N1, "k-", lw=0.8, **lab)
        for key, sty, name in (("law_aligned", "C0--", "N_p, h=(nL)^-1/2"), ("law_random", "C1--", "N_p, h=1/(nL²)"),
                               ("fit", "C3:", "fit N a4:D + 2BD")):
            kw = dict(label=name) if r == 0 else {}
            ax1.plot(ds.time, ds[f"{key}_xy"], sty, lw=1, **kw)
            ax2.plot(ds.time, ds[f"{key}_N1"], sty, lw=1, **kw)
    ax1.set(xlabel="strain γ̇t", ylabel="σ_p,xy / (η_f γ̇)", title=f"fibres β = {BETA:g}: particle shear stress")
    ax2.set(xlabel="strain γ̇t", ylabel="N1 / (η_f γ̇)", title="first normal stress difference")
    ax1.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out / f"{stem}.png", dpi=120)
    print(f"wrote {args.out}/{stem}.{{nc,md,png}}")


if __name__ == "__main__":
    main()
