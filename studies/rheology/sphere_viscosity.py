"""Effective viscosity of sphere suspensions against volume fraction (FFT Stokes solver).

Question: does the fictitious-domain Stokes solver (pyfold.native.stokes) give the
effective viscosity of (a) a simple cubic (SC) array of spheres in its two independent
shear orientations and (b) random sphere suspensions at fixed configurations, as the
dilute theory and the published laws predict, and how large is its resolution error?

Method. Stokes flow has no memory, so a viscosity is one solve at a fixed
configuration. ``eta_eff = Sigma':E / (2 E:E)`` (docs/physics.md#bulk-stress-and-effective-viscosity).

(a) SC array: one sphere of radius R in the unit periodic cube, phi = 4 pi R^3 / 3.
A cubic array has two independent shear viscosities (Nunan & Keller 1984, *J. Fluid
Mech.* 142:269):

* ``eta_face``: shear u = (gamma_dot y, 0, 0) with the flow and gradient along cube
  edges (E_xy; the sphere layers y = const slide past each other);
* ``eta_diag``: the same shear turned by 45 degrees about z, i.e. the pure strain
  E = diag(e, -e, 0) along the cube edges (nearest neighbours approach along y).

Reference in the dilute regime (point-stresslet lattice sum, the construction of
Zuzovsky, Adler & Brenner 1983, *Phys. Fluids* 26:1714, at its first lattice order):
each sphere carries the stresslet S = (20/3) pi eta_f R^3 E_loc of a rigid sphere in
the local strain E_loc = E + (strain of the periodic images, mean zero), hence

    eta_i = 1 + 2.5 phi - 12.5 q_i phi^2 + (higher orders: finite-size terms),

with q_i the eigenvalue of the regularised SC lattice sum of the stresslet strain
field on the E_xy and diag(1, -1, 0) subspaces (:func:`sc_lattice_sums`, computed here
by an Ewald-type Gaussian-cut Fourier sum extrapolated in 1/K^2). It gives
q_face = +0.1716, q_diag = -0.7574 (3 q_face + 2 q_diag = -1 exactly: the isotropic
part is the mean-field term +2.5 phi^2), i.e. phi^2 coefficients -2.14 (face) and
+9.47 (diag). The published coefficients of Zuzovsky et al. and the tables of Nunan &
Keller were not available to this study (docs/rheology.md); this O(phi^2) result is
what their expansion must reduce to. The resummed form 1 + 2.5 phi/(1 + 5 q phi) is not
used: it adds uncontrolled phi^3 terms (it overshoots eta_diag by 3 % at phi = 0.1).
Near close packing (phi -> pi/6) the diag viscosity
diverges like the squeeze film between neighbours: leading term
``(3 pi / 4) R^2 L^2 / delta`` (gap delta = L - 2R, L = 1), while the face viscosity
(tangential sliding) diverges only logarithmically (Nunan & Keller 1984, section 6).

(b) Random suspensions: N equal spheres placed by pyfold's seeded placement
(``pyfold.native.geometry.place_particles``: random sequential addition, then
relaxation sweeps; gap >= alpha = ALPHA_OVER_R R between surfaces), several seeds per phi,
mean +- standard error of eta_eff in simple shear, against Einstein 1 + 2.5 phi
(Einstein 1906/1911), Batchelor & Green (1972, *J. Fluid Mech.* 56:401)
1 + 2.5 phi + 5.2 phi^2 (the hydrodynamic coefficient for a uniform pair distribution,
which a fixed random placement has; 6.2 adds the Brownian stress, Batchelor 1977,
absent here) and Krieger & Dougherty (1959, *Trans. Soc. Rheol.* 3:137)
(1 - phi/phi_m)^(-[eta] phi_m) with [eta] = 2.5, phi_m = 0.64 (random close packing).

The voxeliser keeps a particle clear of its own periodic image (2 R n <= n - 2 voxels,
fortran/grid/fold_voxelise.f90), so a one-sphere cell on an n^3 grid reaches at most
phi = (pi/6)(1 - 2/n)^3: 0.431 at n = 32, 0.461 at 48 (the small form stops at 0.4,
the large one at 0.45; phi -> pi/6 = 0.524 would need a 2^3 supercell).

Resolution: every case is solved on three grids; the observed order p and a
Richardson extrapolation are reported where the three values are monotone (the
asymptotic range); elsewhere the spread of the grids is the stated error.

Command:  python studies/rheology/sphere_viscosity.py            (small form)
          python studies/rheology/sphere_viscosity.py --large    (large form)
Cost on 2 cores (nice 10): small form (SC 8 fractions x 2 orientations x 3 grids
32/48/64; random N = 16, 6 fractions x 6 seeds x 3 grids) 147 CPU-s, 10 min wall at a
load average of 8; large form (grids 48/64/96, N = 32, 8 seeds) not run, estimated
(n^3 log n and iteration growth) 15-20 CPU-min. Finished solves are cached in
out/rheology/sphere_viscosity_cache*.json, so an interrupted study resumes.
Outputs: out/rheology/sphere_viscosity.{nc,md,png} (``xarray.open_dataset``).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import xarray as xr

from pyfold.errors import InputError
from pyfold.native import geometry as geo
from pyfold.native.stokes import Particles, StokesSettings, solve_chi, solve_particles

# Parameters
KAPPA = 1e3          # penalty contrast (solver default; rigidity error ~1/kappa)
TOL = 1e-6           # CG relative residual
ETA_INTRINSIC = 2.5  # Einstein
BG_C2 = 5.2          # Batchelor & Green (1972), uniform pair distribution
PHI_M = 0.64         # Krieger-Dougherty maximum packing (random close packing)
ALPHA_OVER_R = 0.1   # minimum surface gap of the random placements, in radii
SMALL = dict(sc_phi=[0.01, 0.03, 0.065, 0.1, 0.2, 0.3, 0.35, 0.4], grids=[32, 48, 64],
             rnd_phi=[0.05, 0.1, 0.2, 0.3, 0.4, 0.5], n_spheres=16, seeds=[1, 2, 3, 4, 5, 6])
LARGE = dict(sc_phi=[0.005, 0.01, 0.03, 0.065, 0.1, 0.15, 0.2, 0.3, 0.35, 0.4, 0.45], grids=[48, 64, 96],
             rnd_phi=[0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5], n_spheres=32, seeds=list(range(1, 9)))


def sc_lattice_sums(k_cuts=(5.0, 8.0)) -> tuple[float, float]:
    """Eigenvalues (q_face, q_diag) of the regularised simple-cubic lattice sum of the
    point-stresslet strain field (unit cell, L = 1).

    A periodic array of stresslets S (force density div(S delta), mean strain zero) has,
    at a lattice point and without the point's own field, the strain
    E'_ij = -(1/eta V) lim_K [sum_{k != 0} h(k/K) sym(P(k) S k^ k^)_ij - V/(2 pi)^3 int h sym(...) d^3k],
    P = I - k^ k^, k the reciprocal lattice 2 pi m, h = exp(-k^2/K^2); the integral
    removes the self field (its angular mean is S/5). The difference converges like 1/K^2
    (the Poisson-dual terms are the real-space 1/r^3 kernel smoothed over 1/K), so two
    cuts K = 2 pi k_cut are Richardson-extrapolated. With S = 5 eta_f v E_loc this gives
    E_loc = E - 5 phi q E_loc, hence eta = 1 + 2.5 phi - 12.5 q phi^2 + ...
    """
    def q(S, K):
        mmax = int(6 * K / (2 * np.pi)) + 1
        r = np.arange(-mmax, mmax + 1)
        m = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3).astype(float)
        m = m[np.any(m != 0, axis=1)]
        k = 2 * np.pi * m
        kk = np.linalg.norm(k, axis=1)
        kh = k / kk[:, None]
        h = np.exp(-(kk / K) ** 2)
        sk = kh @ S
        psk = sk - kh * np.sum(kh * sk, axis=1)[:, None]
        E = np.einsum("n,ni,nj->ij", h, psk, kh)
        E = 0.5 * (E + E.T) - 0.2 * S * np.sqrt(np.pi) * K ** 3 / (8 * np.pi ** 2)
        return E
    S_face = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    S_diag = np.diag([1.0, -1.0, 0.0])
    out = []
    for S, idx in ((S_face, (0, 1)), (S_diag, (0, 0))):
        v = [q(S, 2 * np.pi * kc)[idx] for kc in k_cuts]
        a, b = np.array(k_cuts, float) ** 2
        out.append((b * v[1] - a * v[0]) / (b - a))  # eliminate the 1/K^2 term
    return out[0], out[1]


def sc_dilute(phi, q) -> np.ndarray:
    """Point-stresslet lattice result to O(phi^2): eta/eta_f = 1 + 2.5 phi - 12.5 q phi^2."""
    phi = np.asarray(phi, float)
    return 1.0 + ETA_INTRINSIC * phi - 5.0 * ETA_INTRINSIC * q * phi ** 2


def sc_squeeze(phi) -> np.ndarray:
    """Leading squeeze-film term of eta_diag near close packing, (3 pi/4) R^2 / delta with
    L = 1: two neighbour pairs per cell, force (3/2) pi eta R^2 (e L)/delta each, lever L."""
    R = (3 * np.asarray(phi, float) / (4 * np.pi)) ** (1 / 3)
    return 0.75 * np.pi * R ** 2 / (1.0 - 2.0 * R)


def einstein(phi):
    return 1.0 + ETA_INTRINSIC * np.asarray(phi, float)


def batchelor_green(phi):
    phi = np.asarray(phi, float)
    return 1.0 + ETA_INTRINSIC * phi + BG_C2 * phi ** 2


def krieger_dougherty(phi, phi_m=PHI_M):
    return (1.0 - np.asarray(phi, float) / phi_m) ** (-ETA_INTRINSIC * phi_m)


def settings() -> StokesSettings:
    return StokesSettings(kappa=KAPPA, tol=TOL)


def sc_viscosities(phi: float, n: int) -> dict:
    """eta_face (shear E_xy) and eta_diag (E = diag(1/2, -1/2, 0)) of the SC array on n^3."""
    R = (3 * phi / (4 * np.pi)) ** (1 / 3)
    P = Particles(x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=R, length=2 * R, shape="sphere")
    face = solve_particles(P, [1, 1, 1], (n, n, n), settings=settings())
    G = np.diag([0.5, -0.5, 0.0])  # gamma_dot = sqrt(2 E:E) = 1, as the shear
    diag = solve_chi(face.chi, np.eye(3), G, settings())
    return dict(face=face.eta_eff, diag=diag.eta_eff, phi_voxel=float(face.chi.mean()), R_vox=R * n,
                hill=max(abs(face.eta_dissipation / face.eta_eff - 1), abs(diag.eta_dissipation / diag.eta_eff - 1)),
                rigidity=float(face.rigidity.max()), iterations=face.iterations + diag.iterations)


def random_configuration(phi: float, n_spheres: int, seed: int, retries: int = 5):
    """Seeded non-overlapping placement of n_spheres equal spheres at volume fraction phi.

    Near phi = 0.5 the placement's relaxation can stall for a given seed (an InputError
    naming the fraction reached); the seeds seed + 1000 k, k = 1..retries, are then tried
    in turn, and the seed actually used is returned (so every configuration is reproducible).
    """
    R = (3 * phi / (4 * np.pi * n_spheres)) ** (1 / 3)
    cell = geo.Cell((1.0, 1.0, 1.0), shear_rate=1.0)
    shape = np.full(n_spheres, geo.SPHERE)
    for k in range(retries + 1):
        try:
            pl = geo.place_particles(cell, shape, np.full(n_spheres, R), np.full(n_spheres, 2 * R),
                                     alpha=ALPHA_OVER_R * R, seed=seed + 1000 * k)
        except InputError as exc:
            print(f"placement phi {phi} seed {seed + 1000 * k}: {str(exc)[:90]}...; next seed", flush=True)
            continue
        return Particles(x=pl.x, p=pl.p, radius=R, length=2 * R, shape="sphere"), R, seed + 1000 * k
    raise InputError(f"placement: phi = {phi} not reached with seeds {seed} + 1000 k, k <= {retries}")


class Cache:
    """Finished solves by case name in a JSON file beside the outputs, so that an
    interrupted study resumes (delete the file to recompute)."""

    def __init__(self, path: Path, key: str):
        self.path = path
        self.key = key
        data = json.loads(path.read_text()) if path.exists() else {}
        self.data = data if data.get("key") == key else {"key": key}

    def get(self, name, compute):
        if name not in self.data:
            self.data[name] = compute()
            self.path.write_text(json.dumps(self.data))
        return self.data[name]


def random_viscosity(P: Particles, n: int) -> tuple[float, float, float]:
    sol = solve_particles(P, [1, 1, 1], (n, n, n), settings=settings())
    return sol.eta_eff, abs(sol.eta_dissipation / sol.eta_eff - 1), float(sol.rigidity.max())


def richardson(h, f) -> tuple[float, float]:
    """Observed order p and extrapolated value from three grid spacings h (coarse first).

    Solves (f1 - f2)/(f2 - f3) = (h1^p - h2^p)/(h2^p - h3^p) by bisection on p in [0.3, 6];
    returns (nan, nan) when the differences change sign (not in the asymptotic range).
    """
    h = np.asarray(h, float)
    f = np.asarray(f, float)
    d1, d2 = f[0] - f[1], f[1] - f[2]
    if d1 == 0 or d2 == 0 or np.sign(d1) != np.sign(d2):
        return np.nan, np.nan
    r = d1 / d2

    def g(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - r

    lo, hi = 0.3, 6.0
    if g(lo) * g(hi) > 0:
        return np.nan, np.nan
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if g(lo) * g(mid) <= 0:
            hi = mid
        else:
            lo = mid
    p = 0.5 * (lo + hi)
    return p, f[2] - d2 / ((h[1] / h[2]) ** p - 1.0)  # f3 + (f3 - f2)/((h2/h3)^p - 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="the large form (about an hour)")
    ap.add_argument("--out", type=Path, default=Path("out/rheology"))
    args = ap.parse_args()
    cfg = LARGE if args.large else SMALL
    args.out.mkdir(parents=True, exist_ok=True)
    grids = cfg["grids"]
    t0 = time.process_time()
    cache = Cache(args.out / ("sphere_viscosity_cache_large.json" if args.large else "sphere_viscosity_cache.json"),
                  key=f"kappa {KAPPA} tol {TOL} alpha {ALPHA_OVER_R} N {cfg['n_spheres']}")

    # Problem: SC array
    q_face, q_diag = sc_lattice_sums()
    print(f"SC lattice sums: q_face = {q_face:.4f}, q_diag = {q_diag:.4f}, 3 q_face + 2 q_diag = "
          f"{3 * q_face + 2 * q_diag:.2e} (exact: -1)", flush=True)
    sc_phi = np.array(cfg["sc_phi"])
    sc = {k: np.full((len(sc_phi), len(grids)), np.nan) for k in
          ("face", "diag", "phi_voxel", "R_vox", "hill", "rigidity", "iterations")}
    # Run
    for i, phi in enumerate(sc_phi):
        for j, n in enumerate(grids):
            r = cache.get(f"sc {phi} {n}", lambda: sc_viscosities(phi, n))
            for k in sc:
                sc[k][i, j] = r[k]
            print(f"SC phi {phi:5.3f} n {n:3d} R/h {r['R_vox']:5.2f}: face {r['face']:.5f} diag {r['diag']:.5f} "
                  f"(hill {r['hill']:.1e}, its {r['iterations']})", flush=True)

    # Problem: random suspensions
    rnd_phi = np.array(cfg["rnd_phi"])
    seeds = cfg["seeds"]
    N = cfg["n_spheres"]
    rnd = np.full((len(rnd_phi), len(seeds), len(grids)), np.nan)
    rnd_hill = np.full_like(rnd, np.nan)
    rnd_rig = np.full_like(rnd, np.nan)
    rnd_R = np.zeros(len(rnd_phi))
    used_seed = np.zeros((len(rnd_phi), len(seeds)), int)
    for i, phi in enumerate(rnd_phi):
        for s, seed in enumerate(seeds):
            P, R, used_seed[i, s] = random_configuration(phi, N, seed)
            rnd_R[i] = R
            for j, n in enumerate(grids):
                rnd[i, s, j], rnd_hill[i, s, j], rnd_rig[i, s, j] = cache.get(
                    f"random {phi} {used_seed[i, s]} {n}", lambda: random_viscosity(P, n))
            print(f"random phi {phi:4.2f} seed {seed} R/h {R * grids[0]:.1f}-{R * grids[-1]:.1f}: "
                  + " ".join(f"{v:.4f}" for v in rnd[i, s]), flush=True)
    cpu = time.process_time() - t0

    # Save
    h = 1.0 / np.array(grids, float)
    sc_order = np.full((len(sc_phi), 2), np.nan)
    sc_extra = np.full((len(sc_phi), 2), np.nan)
    for i in range(len(sc_phi)):
        for c, key in enumerate(("face", "diag")):
            sc_order[i, c], sc_extra[i, c] = richardson(h, sc[key][i])
    mean = rnd.mean(axis=1)
    se = rnd.std(axis=1, ddof=1) / np.sqrt(len(seeds))
    rnd_order = np.full(len(rnd_phi), np.nan)
    rnd_extra = np.full(len(rnd_phi), np.nan)
    for i in range(len(rnd_phi)):
        rnd_order[i], rnd_extra[i] = richardson(h, mean[i])

    ds = xr.Dataset(
        {
            "sc_eta_face": (("sc_phi", "grid"), sc["face"], dict(units="1", long_name="SC array, shear E_xy along cube edges: eta_eff/eta_f")),
            "sc_eta_diag": (("sc_phi", "grid"), sc["diag"], dict(units="1", long_name="SC array, strain diag(1,-1,0) (shear at 45 deg): eta_eff/eta_f")),
            "sc_phi_voxel": (("sc_phi", "grid"), sc["phi_voxel"], dict(units="1", long_name="solid fraction of the voxelised chi")),
            "sc_radius_voxels": (("sc_phi", "grid"), sc["R_vox"], dict(units="1", long_name="sphere radius in voxels")),
            "sc_hill_defect": (("sc_phi", "grid"), sc["hill"], dict(units="1", long_name="|eta_dissipation/eta_eff - 1| (solver balance)")),
            "sc_rigidity": (("sc_phi", "grid"), sc["rigidity"], dict(units="1", long_name="rigidity residual of the sphere")),
            "sc_order": (("sc_phi", "orientation"), sc_order, dict(units="1", long_name="observed convergence order in h")),
            "sc_extrapolated": (("sc_phi", "orientation"), sc_extra, dict(units="1", long_name="Richardson-extrapolated eta_eff/eta_f")),
            "sc_dilute_theory": (("sc_phi", "orientation"), np.stack([sc_dilute(sc_phi, q_face), sc_dilute(sc_phi, q_diag)], -1),
                                 dict(units="1", long_name="1 + 2.5 phi - 12.5 q phi^2, point-stresslet lattice sum")),
            "sc_squeeze_asymptote": (("sc_phi",), sc_squeeze(sc_phi), dict(units="1", long_name="leading squeeze-film term of eta_diag")),
            "random_eta": (("random_phi", "seed", "grid"), rnd, dict(units="1", long_name="random suspension, simple shear: eta_eff/eta_f")),
            "random_mean": (("random_phi", "grid"), mean, dict(units="1", long_name="mean over seeds")),
            "random_se": (("random_phi", "grid"), se, dict(units="1", long_name="standard error over seeds")),
            "random_order": (("random_phi",), rnd_order, dict(units="1", long_name="observed order of the seed mean")),
            "random_extrapolated": (("random_phi",), rnd_extra, dict(units="1", long_name="Richardson-extrapolated seed mean")),
            "random_radius": (("random_phi",), rnd_R, dict(units="1", long_name="sphere radius / cell side")),
            "random_hill_defect": (("random_phi", "seed", "grid"), rnd_hill, dict(units="1", long_name="|eta_dissipation/eta_eff - 1|")),
            "random_rigidity": (("random_phi", "seed", "grid"), rnd_rig, dict(units="1", long_name="max rigidity residual")),
            "random_seed_used": (("random_phi", "seed"), used_seed, dict(units="1", long_name="placement seed used")),
            "einstein": (("random_phi",), einstein(rnd_phi), dict(units="1", long_name="1 + 2.5 phi")),
            "batchelor_green": (("random_phi",), batchelor_green(rnd_phi), dict(units="1", long_name="1 + 2.5 phi + 5.2 phi^2")),
            "krieger_dougherty": (("random_phi",), krieger_dougherty(rnd_phi), dict(units="1", long_name="(1 - phi/0.64)^(-1.6)")),
        },
        coords=dict(sc_phi=("sc_phi", sc_phi, dict(units="1", long_name="volume fraction")),
                    grid=("grid", np.array(grids), dict(units="1", long_name="voxels per cell side")),
                    orientation=("orientation", ["face", "diag"]),
                    random_phi=("random_phi", rnd_phi, dict(units="1", long_name="volume fraction")),
                    seed=("seed", np.array(seeds))),
        attrs=dict(title="Effective viscosity of sphere suspensions (FFT Stokes solver)", kappa=KAPPA, tol=TOL,
                   q_face=q_face, q_diag=q_diag, n_spheres=N, alpha_over_R=ALPHA_OVER_R, phi_m=PHI_M,
                   cpu_seconds=cpu, command="python studies/rheology/sphere_viscosity.py" + (" --large" if args.large else "")),
    )
    ds.to_netcdf(args.out / "sphere_viscosity.nc", engine="h5netcdf")

    lines = [f"# Sphere suspension viscosity ({'large' if args.large else 'small'} form)", "",
             f"kappa = {KAPPA:g}, CG tol = {TOL:g}; CPU of this invocation {cpu:.0f} s (solves found in the cache "
             "are not redone). eta in units of eta_f.", "",
             "## Simple cubic array", "",
             f"Dilute reference 1 + 2.5 phi - 12.5 q phi^2: q_face = {q_face:.4f}, q_diag = {q_diag:.4f}.", "",
             "| phi | R/h | face " + " | ".join(f"n={n}" for n in grids) + " | face extrap. (p) | face dilute | diag "
             + " | ".join(f"n={n}" for n in grids) + " | diag extrap. (p) | diag dilute | diag squeeze |",
             "|" + "---|" * (2 * len(grids) + 7)]
    for i, phi in enumerate(sc_phi):
        fx = "–" if np.isnan(sc_extra[i, 0]) else f"{sc_extra[i, 0]:.4f} ({sc_order[i, 0]:.1f})"
        dx = "–" if np.isnan(sc_extra[i, 1]) else f"{sc_extra[i, 1]:.4f} ({sc_order[i, 1]:.1f})"
        lines.append(f"| {phi:.3f} | {sc['R_vox'][i, 0]:.1f}–{sc['R_vox'][i, -1]:.1f} | "
                     + " | ".join(f"{v:.4f}" for v in sc["face"][i]) + f" | {fx} | {sc_dilute(phi, q_face):.4f} | "
                     + " | ".join(f"{v:.4f}" for v in sc["diag"][i]) + f" | {dx} | {sc_dilute(phi, q_diag):.4f} | "
                     + f"{sc_squeeze(phi):.3f} |")
    lines += ["", f"## Random suspensions (N = {N}, {len(seeds)} seeds, gap >= {ALPHA_OVER_R} R)", "",
              "| phi | " + " | ".join(f"n={n} (R/h)" for n in grids) + " | extrap. (p) | Einstein | Batchelor–Green | Krieger–Dougherty |",
              "|" + "---|" * (len(grids) + 5)]
    for i, phi in enumerate(rnd_phi):
        ex = "–" if np.isnan(rnd_extra[i]) else f"{rnd_extra[i]:.3f} ({rnd_order[i]:.1f})"
        lines.append(f"| {phi:.2f} | " + " | ".join(f"{mean[i, j]:.3f} ± {se[i, j]:.3f} ({rnd_R[i] * n:.1f})"
                                                  for j, n in enumerate(grids))
                     + f" | {ex} | {einstein(phi):.3f} | {batchelor_green(phi):.3f} | {krieger_dougherty(phi):.3f} |")
    lines += ["", f"max |eta_dissipation/eta_eff - 1|: SC {np.nanmax(sc['hill']):.1e}, random {np.nanmax(rnd_hill):.1e}; "
              f"max rigidity residual: SC {np.nanmax(sc['rigidity']):.1e}, random {np.nanmax(rnd_rig):.1e}"]
    (args.out / "sphere_viscosity.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(11, 4.2))
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(1, 2)
    pf = np.linspace(0, 0.5, 200)
    for key, q, col in (("face", q_face, "C0"), ("diag", q_diag, "C3")):
        for j, n in enumerate(grids):
            ax1.plot(sc_phi, sc[key][:, j], "o", mfc="none" if j < len(grids) - 1 else col, color=col, ms=3 + 2 * j,
                     label=f"{key}, n={n}")
        ax1.plot(pf[pf < 0.3], sc_dilute(pf[pf < 0.3], q), "-", color=col, lw=1, label=f"{key}: 1+2.5φ-12.5qφ²")
    pe = np.linspace(0.3, 0.5, 50)
    ax1.plot(pe, sc_squeeze(pe), ":", color="C3", label="diag squeeze asymptote")
    ax1.plot(pf, einstein(pf), "k--", lw=0.8, label="Einstein")
    ax1.set(xlabel="φ", ylabel="η_eff/η_f", title="simple cubic array", yscale="log")
    ax1.legend(fontsize=6)
    for j, n in enumerate(grids):
        ax2.errorbar(rnd_phi + 0.004 * (j - 1), mean[:, j], yerr=se[:, j], fmt="o", ms=4, label=f"n={n}")
    ax2.plot(pf, einstein(pf), "k--", lw=0.8, label="Einstein")
    ax2.plot(pf, batchelor_green(pf), "g-", lw=1, label="Batchelor–Green 5.2")
    ax2.plot(pf, krieger_dougherty(pf), "m-", lw=1, label="Krieger–Dougherty φm=0.64")
    ax2.set(xlabel="φ", ylabel="η_eff/η_f", title=f"random, N = {N}, mean ± s.e. of {len(seeds)} seeds", yscale="log")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out / "sphere_viscosity.png", dpi=120)
    print(f"wrote {args.out}/sphere_viscosity.{{nc,md,png}}")


if __name__ == "__main__":
    main()
