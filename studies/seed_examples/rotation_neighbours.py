"""The seed's "hydrodynamical interactions": neighbours change a particle's rotation rate and period.

Question
    The seed's slide "Hydrodynamical Interactions" (after "Single Fiber Motion in shear
    flow": the Jeffery period T = (2 pi / gamma_dot)(beta_ref + 1/beta_ref)) says that the
    central particle moves because of hydrodynamic interactions and that "the period of
    rotation changes". How much, measured with pyfold's FFT Stokes solver in simple shear
    (periodic cubic cell, Lees-Edwards offset 0, fft backend), and is the change larger than
    the solver's own discretisation error and the seed-to-seed scatter?

Problem (lengths in the particle diameter d = 10 um; gamma_dot = 1/s; eta_f = 1 Pa s;
kappa = 1e3, CG tolerance 1e-6; every solve is solve_particles of pyfold.native.stokes)
    1. Sphere spin. A rigid sphere in unbounded simple shear u = gamma_dot y e_x spins at
       omega_z = -gamma_dot/2 (Jeffery 1922); s = omega_z / (-gamma_dot/2) is reported (1
       alone). (a) A single sphere in cubic cells of 1.5-4 d: a single sphere in a cubic
       periodic cell is a simple cubic array at phi = pi / (6 c^3). Its spin is exactly
       gamma_dot/2 for every c: the rate of strain is symmetric and the array has the cubic
       point group with inversion, whose only invariant third-rank pseudo-tensor is
       epsilon_ijk, so the strain cannot drive a rotation; the periodic images shift nothing.
       Measured: the sphere at a voxel corner (the voxelised body keeps the symmetry) and at
       3 random sub-voxel offsets (the voxelisation breaks it: the scatter is the solver's
       discretisation error of a spin). (b) The same spheres at random positions, volume
       fraction phi = 0.1, 0.2, 0.3 in a cell of 5 d (24, 48, 72 spheres), several seeds:
       the spin of every sphere (and of sphere 0, the "test sphere"); per seed the mean and
       the standard deviation over the spheres, then mean +- standard error over seeds
       (pyfold.ensemble.ensemble_mean). The same configurations are solved at every
       resolution (paired), so the resolution's effect on the change is measured directly.
    2. Fibre period. A flat-ended cylinder (pyfold "fibre") of aspect ratio beta = L/d = 5
       at the centre of a cubic cell 8 d = 1.6 L wide, axis in the flow-gradient plane at angle
       theta from the flow. Stokes flow has no memory, so d theta/dt = omega_z(theta) and
       T = int_0^{2 pi} d theta / |omega_z| = 2 int_0^pi d theta / |omega_z| (p and -p are
       the same body). Quadrature: the periodic trapezoid rule in Jeffery's angle phi
       (tan theta = tan phi / b, b = the Harris-Pittman beta_e, as in
       studies/jeffery_orbits/equivalent_aspect_ratio.py) over the half orbit, without the
       mirror symmetry omega(-theta) = omega(theta), which neighbours break; the same rule on
       every other node bounds the quadrature error. beta_e = (tau + sqrt(tau^2 - 4)) / 2,
       tau = gamma_dot T / (2 pi), beside pyfold.kinematics.equivalent_aspect_ratio and the
       measured beta_e of docs/jeffery_orbits.md. Then the same fibre among neighbour spheres
       (diameter d) at phi = 0.1, 0.2 (spheres' volume / cell volume), several seeds; every
       sphere's surface stays >= FIBRE_CLEARANCE = d/2 from the disc swept by the fibre over
       a whole orbit, so no orientation overlaps and the gap is resolved (>= 2 voxels).
       Statistics: omega_z >= 0 at a node means the frozen orbit has a fixed point (T
       infinite); near one, T is huge, so the periods of different environments are
       heavy-tailed. The orbit frequency f = 1/T (0 when stalled) is bounded, so the seed
       mean and standard error are taken of f and of f / f_alone - 1 (paired with the lone
       fibre at the same resolution); 1/<f> is quoted as the period, the median T beside it.
       Approximation ("frozen neighbours"): the neighbours stay where they were placed while
       the fibre turns; in a real suspension they are advected (by about gamma_dot T times
       their height, several cells, in one orbit), so each seed's T is the period the fibre
       would have in that frozen environment, and the ensemble over seeds samples
       environments. Out-of-plane rotation rates (omega_x, omega_y, zero alone by symmetry)
       are recorded, not integrated: the orbit is kept in the flow-gradient plane.
Placement
    Random uniform centres, then pairs closer than d + gap (minimum image) are pushed apart
    (and, for the fibre, spheres out of the swept disc) until every constraint holds:
    gap = d/6 between spheres, one voxel at 6 voxels per diameter, so no two spheres share
    a voxel there.
    A random, not an equilibrium hard-sphere, configuration; seeded (numpy default_rng).
Resolution and errors
    Voxels per diameter vpd = 4, 6 (small), 4, 6, 8 (--large). Discretisation error of a
    single-particle value: the difference between the two finest resolutions (the period
    converges monotonically from above at these vpd, docs/jeffery_orbits.md); of a seed
    mean: the same difference of the paired (same configurations) means. A change is
    reported as significant when it exceeds 2 standard errors over seeds plus that
    discretisation error.

Command
    nice -n 10 python studies/seed_examples/rotation_neighbours.py            # small form
    nice -n 10 python studies/seed_examples/rotation_neighbours.py --large
    Options: --seeds N, --vpd ..., --nphi N (even, >= 8), --out DIR,
    --reanalyse FILE.nc (tables and figure from a saved file, no solves).
Cost on 2 cores (one solve at a time, serial FFTW; CPU time; load ~4)
    one solve: 0.02-0.3 s (sphere cells 6^3-30^3), ~0.3 s (fibre cell 32^3) / ~0.6 s (48^3).
    small (8 seeds, vpd 4 and 6, 16 nodes per half orbit): ~640 solves, ~3 CPU minutes.
    large (10 seeds, vpd 4, 6, 8, 24 nodes): fibre cells up to 64^3, ~2200 solves; measured 910 CPU-s
    (20 min wall at load 3.6). Small form measured: 177 CPU-s (4 min wall at load ~3).
Outputs (under --out, default out/seed_examples/rotation_neighbours/)
    rotation_neighbours.nc   per-solve spins and per-orbit periods, seed means and errors
                             (xarray.open_dataset(path, engine="h5netcdf"))
    rotation_neighbours.md   the tables and the answer (also printed)
    rotation_neighbours.png  spin distribution and period against phi, with error bars
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import math
import sys
import time
from pathlib import Path

import numpy as np

from pyfold.command_line import command_line, git_revision
from pyfold.ensemble import ensemble_mean
from pyfold.errors import InputError
from pyfold.kinematics import equivalent_aspect_ratio
from pyfold.native.stokes import Particles, StokesSettings, solve_particles

# Parameters
DIAMETER = 10e-6  # particle diameter [m]; the Stokes problem is scale-free
SHEAR_RATE = 1.0  # [1/s]
ETA_F = 1.0  # [Pa s]
KAPPA = 1.0e3  # viscosity contrast (solver default)
TOL = 1.0e-6  # CG relative residual
BETA = 5.0  # fibre aspect ratio L/d
#: cubic cell edge of the fibre runs in d (1.6 L): an even voxel count at 4, 6 and 8 voxels per d, so
#: every resolution solves the same cell with the fibre's centre on a voxel corner
#: (docs/jeffery_orbits.md uses 1.5 L = 7.5 d, odd at 6 voxels per d)
FIBRE_CELL_D = 8.0
SPHERE_CELL = 5.0  # cell edge of the random sphere suspensions, in d
GAP = 1.0 / 6.0  # minimum surface gap between spheres, in d
#: minimum gap between a neighbour sphere and the disc swept by the fibre, in d: 2 voxels at 4 voxels
#: per d. With d/6 (sub-voxel at 4 vox/d) the fibre and a sphere near its tip share voxels and the
#: period moved by factors between 4 and 6 vox/d (up to 3600 s against 121 s in one configuration)
FIBRE_CLEARANCE = 0.5
#: docs/jeffery_orbits.md, beta = 5, cell 1.5 L, kappa 1e3: measured beta_e at 4 / 6 / 8 vpd and extrapolated
BETA_E_DOCS = {4: 4.398, 6: 4.235, 8: 4.170, "inf": (4.06, 0.11)}
PUSH_MARGIN = 1e-4  # overshoot of a placement push, in d
N_OFFSETS = 3  # random sub-voxel positions of the single sphere


@dataclasses.dataclass(frozen=True)
class Form:
    vpd: tuple[int, ...]
    seeds: int
    nphi: int
    single_cells: tuple[float, ...] = (1.5, 2.0, 3.0, 4.0)
    sphere_phis: tuple[float, ...] = (0.1, 0.2, 0.3)
    fibre_phis: tuple[float, ...] = (0.1, 0.2)


SMALL = Form(vpd=(4, 6), seeds=8, nphi=16)
LARGE = Form(vpd=(4, 6, 8), seeds=10, nphi=24)


def settings() -> StokesSettings:
    return StokesSettings(eta_f=ETA_F, kappa=KAPPA, tol=TOL, backend="fft")


def spin_ratio(omega_z):
    """omega_z / (-gamma_dot/2): 1 for a sphere alone in unbounded shear."""
    return np.asarray(omega_z, float) / (-0.5 * SHEAR_RATE)


def n_spheres(phi: float, cell: float) -> int:
    """Spheres of diameter 1 in a cubic cell of edge ``cell`` at volume fraction ``phi``."""
    return int(round(phi * cell**3 / (math.pi / 6)))


def fibre_grid(vpd: int) -> int:
    """Voxels per edge of the fibre cell; even, so that the centred fibre sits on a voxel corner
    (studies/jeffery_orbits/equivalent_aspect_ratio.py: grid_size)."""
    n = FIBRE_CELL_D * vpd
    if abs(n - round(n)) > 1e-9 or round(n) % 2:
        raise ValueError(f"vpd {vpd}: the fibre cell of {FIBRE_CELL_D:g} d is not an even voxel count")
    return int(round(n))


# Placement (lengths in d)
def _min_image(dx, cell):
    return dx - cell * np.round(dx / cell)


def swept_disc_push(x, centre, cell, clearance):
    """Displacements that move sphere centres ``x`` to a distance >= ``clearance`` from the disc
    swept by the fibre over an orbit in the x-y plane: radius sqrt((L/2)^2 + (d/2)^2) (the
    flat end's corner), half-thickness d/2, centred at ``centre``."""
    r_disc = math.hypot(BETA / 2, 0.5)
    rel = _min_image(x - centre, cell)
    r = np.hypot(rel[:, 0], rel[:, 1])
    dr, dz = np.maximum(r - r_disc, 0.0), np.maximum(np.abs(rel[:, 2]) - 0.5, 0.0)
    dist = np.hypot(dr, dz)
    push = np.zeros_like(x)
    bad = dist < clearance
    inside = bad & (dist == 0.0)
    out = bad & ~inside
    # inside the disc: leave along z (the short way out of a thin disc)
    push[inside, 2] = np.where(rel[inside, 2] >= 0, 1.0, -1.0) * (0.5 + clearance - np.abs(rel[inside, 2]))
    if np.any(out):
        er = rel[out, :2] / np.maximum(r[out], 1e-300)[:, None]
        scale = (clearance - dist[out]) / dist[out]
        push[out, :2] = er * (dr[out] * scale)[:, None]
        push[out, 2] = np.sign(rel[out, 2]) * dz[out] * scale
    return push, bool(np.any(bad))


def place_spheres(rng, n: int, cell: float, gap: float = GAP, fibre_centre=None, clearance: float = 0.0,
                  max_sweeps: int = 20000):
    """``n`` centres of unit spheres in the cubic cell, every pair >= 1 + gap apart (minimum
    image) and, with ``fibre_centre``, every sphere surface >= ``clearance`` from the fibre's
    swept disc.
    Random start, then overlapping pairs are pushed apart (each by half its deficit, 1 %
    and PUSH_MARGIN overshoot, without which the deficits only decay geometrically) until no
    constraint is violated; RuntimeError if that fails."""
    need = 1.0 + gap
    x = rng.uniform(0.0, cell, (n, 3))
    iu = np.triu_indices(n, 1)
    for _ in range(max_sweeps):
        moved = False
        if fibre_centre is not None:
            push, bad = swept_disc_push(x, np.asarray(fibre_centre, float), cell, 0.5 + clearance)
            if bad:
                x += 1.01 * push + PUSH_MARGIN * np.sign(push)
                moved = True
        dx = _min_image(x[:, None, :] - x[None, :, :], cell)
        dist = np.linalg.norm(dx, axis=-1)
        deficit = np.where(dist < need, need - dist, 0.0)
        np.fill_diagonal(deficit, 0.0)
        if np.any(deficit[iu] > 0):
            unit = dx / np.maximum(dist, 1e-12)[..., None]
            step = np.where(deficit > 0, 0.505 * deficit + 0.5 * PUSH_MARGIN, 0.0)
            x += np.sum(step[..., None] * unit, axis=1)
            moved = True
        x %= cell
        if not moved:
            return x
    raise RuntimeError(f"place_spheres: {n} spheres in a cell of {cell:g} d with gap {gap:g} not placed "
                       f"in {max_sweeps} sweeps")


# Solver
def sphere_spins(x, cell: float, vpd: int, s: StokesSettings):
    """omega (N, 3) [1/s] of unit spheres at centres ``x`` (in d) in the cubic cell (edge in d)."""
    n = int(round(cell * vpd))
    if abs(n - cell * vpd) > 1e-9:
        raise ValueError(f"cell {cell} d is not a whole number of voxels at vpd {vpd}")
    N = len(x)
    p = np.zeros((N, 3))
    p[:, 0] = 1.0
    L = cell * DIAMETER
    sol = solve_particles(Particles(x=np.asarray(x) * DIAMETER, p=p, radius=DIAMETER / 2, length=DIAMETER,
                                    shape="sphere"), [L] * 3, (n, n, n), shear_rate=SHEAR_RATE, settings=s)
    return sol.omega, sol.iterations


def jeffery_half_nodes(nphi: int, b: float):
    """theta_k = atan2(sin phi_k, b cos phi_k), phi_k = pi k / nphi, k = 0..nphi-1, and the periodic
    trapezoid weights (d theta / d phi included) with T = 2 sum_k w_k / |omega_k| over [0, pi)."""
    phi = np.pi * np.arange(nphi) / nphi
    theta = np.mod(np.arctan2(np.sin(phi), b * np.cos(phi)), np.pi)
    w = (np.pi / nphi) * b / (b**2 * np.cos(phi) ** 2 + np.sin(phi) ** 2)
    return theta, w


def period(omega_z, w) -> float:
    return float(2 * np.sum(w / np.abs(omega_z)))


def beta_from_period(T):
    tau = np.asarray(T, float) * SHEAR_RATE / (2 * np.pi)
    with np.errstate(invalid="ignore"):
        return np.where(tau >= 2, (tau + np.sqrt(np.maximum(tau**2 - 4, 0))) / 2, np.nan)


def fibre_orbit(spheres, vpd: int, nphi: int, s: StokesSettings):
    """omega (nphi, 3) of the centred fibre at the half-orbit nodes, with frozen neighbour
    spheres at ``spheres`` (in d, or None)."""
    n = fibre_grid(vpd)
    cell = n / vpd  # in d
    b = float(equivalent_aspect_ratio(BETA, "harris_pittman"))
    theta, _ = jeffery_half_nodes(nphi, b)
    ns = 0 if spheres is None else len(spheres)
    x = np.vstack([[[cell / 2] * 3], np.zeros((0, 3)) if spheres is None else spheres]) * DIAMETER
    shape = ["fibre"] + ["sphere"] * ns
    length = np.r_[BETA, np.ones(ns)] * DIAMETER
    om = np.empty((nphi, 3))
    its = np.empty(nphi, int)
    for k, th in enumerate(theta):
        p = np.zeros((ns + 1, 3))
        p[:, 0] = 1.0
        p[0] = [math.cos(th), math.sin(th), 0.0]
        sol = solve_particles(Particles(x=x, p=p, radius=DIAMETER / 2, length=length, shape=shape),
                              [cell * DIAMETER] * 3, (n, n, n), shear_rate=SHEAR_RATE, settings=s)
        om[k], its[k] = sol.omega[0], sol.iterations
    return om, its


# Run
def run(form: Form, log=print):
    import xarray as xr

    s = settings()
    vpds = np.array(form.vpd)
    seeds = np.arange(1, form.seeds + 1)
    t0 = time.process_time()
    # 1a single sphere: centred (voxel corner) and random sub-voxel offsets
    cells = np.array(form.single_cells)
    single = np.full((len(vpds), len(cells), 1 + N_OFFSETS), np.nan)
    for i, v in enumerate(vpds):
        for j, c in enumerate(cells):
            if abs(c * v - round(c * v)) > 1e-9:
                continue  # not a whole number of voxels at this resolution
            rng = np.random.default_rng(1000 + int(v))
            offs = np.vstack([np.zeros(3), rng.uniform(0, 1.0 / v, (N_OFFSETS, 3))])
            try:
                for k, o in enumerate(offs):
                    om, _ = sphere_spins(np.array([[c / 2] * 3]) + o, c, int(v), s)
                    single[i, j, k] = spin_ratio(om[0, 2])
            except InputError as err:  # the voxelised sphere touches its own image at this grid
                log(f"  single sphere vpd {v} cell {c:g} d skipped: {err}")
        log(f"  single sphere vpd {v}: s = " + ", ".join(f"{x:.5f}" for x in single[i].ravel() if np.isfinite(x)))
    # 1b random spheres
    phis = np.array(form.sphere_phis)
    counts = np.array([n_spheres(p, SPHERE_CELL) for p in phis])
    nmax = int(counts.max())
    sp_omega = np.full((len(phis), len(seeds), len(vpds), nmax, 3), np.nan)
    sp_x = np.full((len(phis), len(seeds), nmax, 3), np.nan)
    for a, (phi, N) in enumerate(zip(phis, counts)):
        for b_, seed in enumerate(seeds):
            x = place_spheres(np.random.default_rng([int(seed), int(round(phi * 1000)), 1]), int(N), SPHERE_CELL)
            sp_x[a, b_, :N] = x
            for i, v in enumerate(vpds):
                om, _ = sphere_spins(x, SPHERE_CELL, int(v), s)
                sp_omega[a, b_, i, :N] = om
        sr = spin_ratio(sp_omega[a, :, :, :N, 2])
        log(f"  spheres phi {phi:g} ({N}): mean s per vpd " + ", ".join(f"{m:.4f}" for m in np.nanmean(sr, axis=(0, 2)))
            + ", sd over spheres " + ", ".join(f"{m:.4f}" for m in np.nanmean(np.nanstd(sr, axis=2, ddof=1), axis=0)))
    # 2 fibre
    fb_single = np.empty((len(vpds), form.nphi, 3))
    fb_single_its = np.empty((len(vpds), form.nphi), int)
    for i, v in enumerate(vpds):
        fb_single[i], fb_single_its[i] = fibre_orbit(None, int(v), form.nphi, s)
    fphis = np.array(form.fibre_phis)
    fcell = FIBRE_CELL_D
    fcounts = np.array([n_spheres(p, fcell) for p in fphis])
    fmax = int(fcounts.max())
    fb_omega = np.full((len(fphis), len(seeds), len(vpds), form.nphi, 3), np.nan)
    fb_x = np.full((len(fphis), len(seeds), fmax, 3), np.nan)
    for a, (phi, N) in enumerate(zip(fphis, fcounts)):
        for b_, seed in enumerate(seeds):
            x = place_spheres(np.random.default_rng([int(seed), int(round(phi * 1000)), 2]), int(N), fcell,
                              fibre_centre=[fcell / 2] * 3, clearance=FIBRE_CLEARANCE)
            fb_x[a, b_, :N] = x
            for i, v in enumerate(vpds):
                fb_omega[a, b_, i] = fibre_orbit(x, int(v), form.nphi, s)[0]
            log(f"  fibre phi {phi:g} seed {seed}: T = "
                + ", ".join(f"{period(fb_omega[a, b_, i, :, 2], _w(form.nphi)):.3f}" for i in range(len(vpds))) + " s")
    cpu = time.process_time() - t0
    b = float(equivalent_aspect_ratio(BETA, "harris_pittman"))
    theta, w = jeffery_half_nodes(form.nphi, b)
    c = dict(vpd=("vpd", vpds, {"units": "1", "long_name": "voxels per diameter"}),
             cell=("cell", cells, {"units": "d", "long_name": "cubic cell edge of the single sphere"}),
             position=("position", np.arange(1 + N_OFFSETS), {"long_name": "0: voxel corner; >0: random offset"}),
             phi=("phi", phis, {"units": "1", "long_name": "sphere volume fraction (random spheres)"}),
             seed=("seed", seeds), sphere=("sphere", np.arange(nmax)), xyz=("xyz", ["x", "y", "z"]),
             fibre_phi=("fibre_phi", fphis, {"units": "1", "long_name": "neighbour sphere volume fraction"}),
             neighbour=("neighbour", np.arange(fmax)),
             node=("node", np.arange(form.nphi), {"long_name": "half-orbit node k, phi = pi k / nphi"}))
    V = lambda dims, x, units, name: (dims, np.asarray(x), {"units": units, "long_name": name})  # noqa: E731
    data = dict(
        single_spin=V(("vpd", "cell", "position"), single, "1", "single sphere omega_z / (-gamma_dot/2)"),
        n_spheres=V(("phi",), counts, "1", "spheres in the cell"),
        sphere_x=V(("phi", "seed", "sphere", "xyz"), sp_x, "d", "sphere centres (NaN: padding)"),
        sphere_omega=V(("phi", "seed", "vpd", "sphere", "xyz"), sp_omega, "1/s", "sphere rotation rates"),
        theta=V(("node",), theta, "rad", "fibre orientation from the flow direction"),
        weight=V(("node",), w, "rad", "periodic trapezoid weight in theta (T = 2 sum w/|omega_z|)"),
        fibre_single_omega=V(("vpd", "node", "xyz"), fb_single, "1/s", "fibre alone: rotation rate"),
        fibre_single_iterations=V(("vpd", "node"), fb_single_its, "1", "CG iterations"),
        n_neighbours=V(("fibre_phi",), fcounts, "1", "neighbour spheres around the fibre"),
        neighbour_x=V(("fibre_phi", "seed", "neighbour", "xyz"), fb_x, "d", "neighbour centres (NaN: padding)"),
        fibre_omega=V(("fibre_phi", "seed", "vpd", "node", "xyz"), fb_omega, "1/s",
                      "fibre among frozen neighbours: rotation rate"),
    )
    return xr.Dataset(data, coords=c, attrs=dict(
        format="pyfold.study.rotation_neighbours", format_version="1.0",
        creator=f"pyfold {git_revision(Path(__file__).resolve().parent)}",
        created=datetime.datetime.now(datetime.timezone.utc).isoformat(), command=command_line(sys.argv),
        shear_rate=SHEAR_RATE, diameter=DIAMETER, eta_f=ETA_F, kappa=KAPPA, tol=TOL, beta=BETA,
        fibre_cell_d=fcell, sphere_cell_d=SPHERE_CELL, gap_d=GAP, fibre_clearance_d=FIBRE_CLEARANCE, nphi=form.nphi,
        backend="fft", cpu_time_total=cpu))


def _w(nphi: int):
    return jeffery_half_nodes(nphi, float(equivalent_aspect_ratio(BETA, "harris_pittman")))[1]


# Analysis
def _em(values):
    e = ensemble_mean(values)
    return e.mean, e.stderr_across


def analyse(raw):
    """Seed means and errors, periods, beta_e, relative changes, the markdown table."""
    ds = raw.copy()
    vpds = raw.vpd.values
    nv = len(vpds)
    w = raw.weight.values
    nphi = w.size
    b = float(equivalent_aspect_ratio(BETA, "harris_pittman"))
    _, w_half = jeffery_half_nodes(nphi // 2, b)
    # spheres
    sr = spin_ratio(raw.sphere_omega.values[..., 2])  # phi, seed, vpd, sphere
    perp = np.hypot(raw.sphere_omega.values[..., 0], raw.sphere_omega.values[..., 1]) / (0.5 * SHEAR_RATE)
    seed_mean = np.nanmean(sr, axis=-1)
    seed_sd = np.nanstd(sr, axis=-1, ddof=1)
    test = sr[..., 0]
    seed_perp = np.nanmean(perp, axis=-1)
    nphi_s, nseed = sr.shape[0], sr.shape[1]
    stats = {}
    for name, arr in (("mean", seed_mean), ("sd", seed_sd), ("test", test), ("perp", seed_perp),
                      ("mean_shift_vs_finest", seed_mean - seed_mean[:, :, -1:]),
                      ("sd_shift_vs_finest", seed_sd - seed_sd[:, :, -1:])):
        m = np.empty((nphi_s, nv))
        e = np.empty((nphi_s, nv))
        for a in range(nphi_s):
            for i in range(nv):
                m[a, i], e[a, i] = _em(arr[a, :, i])
        stats[name] = (m, e)
    for name, (m, e) in stats.items():
        ds[f"sphere_spin_{name}"] = (("phi", "vpd"), m, {"units": "1", "long_name": f"seed mean of the {name}"})
        ds[f"sphere_spin_{name}_se"] = (("phi", "vpd"), e, {"units": "1", "long_name": "standard error over seeds"})
    # fibre
    T1 = np.array([period(raw.fibre_single_omega.values[i, :, 2], w) for i in range(nv)])
    T1h = np.array([period(raw.fibre_single_omega.values[i, ::2, 2], w_half) for i in range(nv)])
    om = raw.fibre_omega.values[..., 2]  # fphi, seed, vpd, node
    # omega_z >= 0 at a node: with frozen neighbours the orbit has a fixed point (T infinite,
    # orbit frequency 0). The period's distribution over environments is heavy-tailed (T grows
    # without bound as omega_z -> 0 at some node), the frequency f = 1/T lies in [0, f_max]:
    # means and standard errors are taken of f, the period quoted is 1/<f>.
    stalled = np.any(om >= 0, axis=-1)
    with np.errstate(divide="ignore"):
        f = np.where(stalled, 0.0, 1.0 / (2 * np.sum(w / np.abs(om), axis=-1)))
        fh = np.where(np.any(om[..., ::2] >= 0, axis=-1), 0.0, 1.0 / (2 * np.sum(w_half / np.abs(om[..., ::2]), axis=-1)))
        T = np.where(stalled, np.inf, 1.0 / np.where(stalled, 1.0, f))
    f1 = 1.0 / T1
    rel = f / f1[None, None, :] - 1
    Fm, Fe, Rm, Re = (np.empty(f.shape[::2]) for _ in range(4))
    for a in range(f.shape[0]):
        for i in range(nv):
            Fm[a, i], Fe[a, i] = _em(f[a, :, i])
            Rm[a, i], Re[a, i] = _em(rel[a, :, i])
    perp_f = np.hypot(raw.fibre_omega.values[..., 0], raw.fibre_omega.values[..., 1])
    ds["fibre_single_period"] = (("vpd",), T1, {"units": "s", "long_name": "Jeffery period of the fibre alone"})
    ds["fibre_single_period_half_nodes"] = (("vpd",), T1h, {"units": "s", "long_name": "same, every other node"})
    ds["fibre_single_beta_e"] = (("vpd",), beta_from_period(T1), {"units": "1", "long_name": "beta_e from T"})
    ds["fibre_stalled"] = (("fibre_phi", "seed", "vpd"), stalled.astype(np.int8),
                           {"units": "1", "long_name": "1: omega_z >= 0 at a node (fixed point, T infinite)"})
    ds["fibre_period"] = (("fibre_phi", "seed", "vpd"), T, {"units": "s", "long_name": "period among frozen neighbours"})
    ds["fibre_frequency"] = (("fibre_phi", "seed", "vpd"), f, {"units": "1/s", "long_name": "orbit frequency 1/T"})
    ds["fibre_frequency_half_nodes"] = (("fibre_phi", "seed", "vpd"), fh, {"units": "1/s", "long_name": "every other node"})
    ds["fibre_frequency_change"] = (("fibre_phi", "seed", "vpd"), rel, {"units": "1", "long_name": "f / f_alone - 1"})
    ds["fibre_frequency_mean"] = (("fibre_phi", "vpd"), Fm, {"units": "1/s", "long_name": "seed mean of f"})
    ds["fibre_frequency_se"] = (("fibre_phi", "vpd"), Fe, {"units": "1/s", "long_name": "standard error over seeds"})
    ds["fibre_frequency_change_mean"] = (("fibre_phi", "vpd"), Rm, {"units": "1", "long_name": "seed mean of f/f_alone - 1"})
    ds["fibre_frequency_change_se"] = (("fibre_phi", "vpd"), Re, {"units": "1", "long_name": "standard error over seeds"})
    ds["fibre_period_of_mean_frequency"] = (("fibre_phi", "vpd"), 1.0 / Fm, {"units": "s", "long_name": "1 / <f>"})
    ds["fibre_period_of_mean_frequency_se"] = (("fibre_phi", "vpd"), Fe / Fm**2,
                                               {"units": "s", "long_name": "its standard error, se(f) / <f>^2"})

    # table
    at = raw.attrs
    fin, prev = -1, -2
    L = [f"Rotation with and without neighbours (FFT Stokes solver, fft backend, periodic cubic cell, "
         f"Lees-Edwards offset 0; gamma_dot = {SHEAR_RATE:g}/s, kappa {KAPPA:g}, tol {TOL:g}; "
         f"{nseed} seeds; CPU {float(at['cpu_time_total']):.0f} s).", "",
         "Sphere spin s = omega_z / (-gamma_dot/2) (1 alone in unbounded shear).", "",
         "Single sphere in a cubic cell of edge c (= simple cubic array at phi = pi/(6 c^3)): "
         "voxel-corner centre / range over random sub-voxel offsets", "",
         "| vpd | " + " | ".join(f"c = {c:g} d (phi {math.pi / 6 / c**3:.3f})" for c in raw.cell.values) + " |",
         "|---" * (1 + raw.cell.size) + "|"]
    ss = raw.single_spin.values
    for i, v in enumerate(vpds):
        cellstr = []
        for j in range(raw.cell.size):
            x = ss[i, j]
            if not np.isfinite(x[0]):
                cellstr.append("-")
                continue
            off = x[1:][np.isfinite(x[1:])]
            cellstr.append(f"{x[0]:.5f} / {off.min():.4f}-{off.max():.4f}")
        L.append(f"| {v} | " + " | ".join(cellstr) + " |")
    off_dev = np.nanmax(np.abs(ss[fin, :, 1:] - 1))
    L += ["", f"Random spheres in a cell of {float(at['sphere_cell_d']):g} d (gap >= {float(at['gap_d']):.3f} d): "
          "mean over seeds +- standard error of the per-seed values", "",
          "| phi | N | vpd | mean s (all spheres) | sd of s over the spheres | test sphere s | "
          "mean |omega_xy| / (gamma_dot/2) | mean s minus its finest-vpd value | sd minus its finest-vpd value |",
          "|---|---|---|---|---|---|---|---|---|"]
    for a, phi in enumerate(raw.phi.values):
        for i, v in enumerate(vpds):
            fmt = lambda k: f"{stats[k][0][a, i]:.4f} +- {stats[k][1][a, i]:.4f}"  # noqa: E731
            L.append(f"| {phi:g} | {int(raw.n_spheres.values[a])} | {v} | {fmt('mean')} | {fmt('sd')} | {fmt('test')} | "
                     f"{fmt('perp')} | {fmt('mean_shift_vs_finest') if i < nv - 1 else '-'} | "
                     f"{fmt('sd_shift_vs_finest') if i < nv - 1 else '-'} |")
    be = beta_from_period(T1)
    rules = {k: float(equivalent_aspect_ratio(BETA, k)) for k in ("cox", "harris_pittman", "zhang")}
    L += ["", f"Fibre (flat-ended cylinder, beta = {BETA:g}) alone, cell {float(at['fibre_cell_d']) / BETA:g} L = "
          f"{float(at['fibre_cell_d']):g} d, {nphi} nodes per half orbit", "",
          "| vpd | grid | T [s] | quadrature bound [s] | beta_e | beta_e in docs/jeffery_orbits.md (cell 1.5 L) |", "|---|---|---|---|---|---|"]
    for i, v in enumerate(vpds):
        L.append(f"| {v} | {fibre_grid(int(v))}^3 | {T1[i]:.3f} | {abs(T1[i] - T1h[i]):.3f} | {be[i]:.3f} | "
                 f"{BETA_E_DOCS.get(int(v), float('nan')):.3f} |")
    L += [f"Rules: Cox {rules['cox']:.2f}, Harris & Pittman {rules['harris_pittman']:.2f}, Zhang {rules['zhang']:.2f}; "
          f"docs/jeffery_orbits.md extrapolated {BETA_E_DOCS['inf'][0]} +- {BETA_E_DOCS['inf'][1]}.",
          f"Discretisation error of T alone (vpd {vpds[prev]} -> {vpds[fin]}): {abs(T1[fin] - T1[prev]):.3f} s "
          f"({100 * abs(T1[fin] / T1[prev] - 1):.1f} %).", "",
          f"Fibre among frozen neighbour spheres (surface >= {float(at['fibre_clearance_d']):g} d from the disc the fibre "
          "sweeps): orbit frequency f = 1/T (0 if omega_z >= 0 at a node: stalled); change = f / f_alone - 1 at the "
          "same vpd (paired), mean +- s.e. over seeds; 1/<f> the period of the mean frequency; disc. = |change(finest) - "
          "change(previous vpd)|; quad. = max |f - f(every other node)| / f_alone", "",
          "| phi | N | vpd | stalled seeds | median T [s] | 1/<f> [s] | change of f | disc. | quad. | "
          "max |omega_xy| / (gamma_dot/2) | significant |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for a, phi in enumerate(raw.fibre_phi.values):
        disc = abs(Rm[a, fin] - Rm[a, prev]) if nv > 1 else np.nan
        for i, v in enumerate(vpds):
            sig = abs(Rm[a, i]) > 2 * Re[a, i] + (disc if np.isfinite(disc) else 0)
            quad = np.max(np.abs(f[a, :, i] - fh[a, :, i])) / f1[i]
            L.append(f"| {phi:g} | {int(raw.n_neighbours.values[a])} | {v} | {int(stalled[a, :, i].sum())} / {nseed} | "
                     f"{np.median(T[a, :, i]):.2f} | {1 / Fm[a, i]:.2f} +- {Fe[a, i] / Fm[a, i] ** 2:.2f} | "
                     f"{100 * Rm[a, i]:+.1f} +- {100 * Re[a, i]:.1f} % | {100 * disc:.1f} % | {100 * quad:.1f} % | "
                     f"{np.max(perp_f[a, :, i]) / (0.5 * SHEAR_RATE):.3f} | {'yes' if sig else 'no'} |")
    L += ["", f"Nodes where the fibre's omega_z >= 0 (fixed point of the frozen orbit): {int(np.sum(om >= 0))}.",
          f"Largest single-sphere spin deviation at random sub-voxel offsets, vpd {vpds[fin]}: {off_dev:.1e}."]
    return ds, "\n".join(L) + "\n"


def figure(ds, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    vpds = ds.vpd.values
    sr = spin_ratio(ds.sphere_omega.values[..., -1, :, 2])  # finest vpd: phi, seed, sphere
    for a, phi in enumerate(ds.phi.values):
        x = sr[a][np.isfinite(sr[a])]
        a1.hist(x, bins=30, histtype="step", density=True, label=f"random, phi = {phi:g} ({x.size} spins)")
    a1.axvline(1.0, color="k", lw=1, label="alone / regular array (exact 1)")
    a1.set_xlabel(r"sphere spin $\omega_z / (-\dot\gamma/2)$" + f" ({vpds[-1]} vox/d)")
    a1.set_ylabel("density")
    a1.legend(fontsize=7)
    for i, v in enumerate(vpds):
        phis = np.r_[0.0, ds.fibre_phi.values]
        m = np.r_[1.0, 1.0 + ds.fibre_frequency_change_mean.values[:, i]]
        e = np.r_[0.0, ds.fibre_frequency_change_se.values[:, i]]
        a2.errorbar(phis + 0.004 * i, m, e, fmt="o-", capsize=3, label=f"{v} vox/d, mean +- s.e.")
        for a, phi in enumerate(ds.fibre_phi.values):
            a2.plot(np.full(ds.seed.size, phi + 0.004 * i), 1.0 + ds.fibre_frequency_change.values[a, :, i], ".",
                    color=f"C{i}", alpha=0.4)
    a2.axhline(1.0, color="k", lw=1)
    a2.set_xlabel(r"neighbour sphere volume fraction $\phi$")
    a2.set_ylabel(r"orbit frequency $f / f_{alone}$ ($f = 1/T$, 0: stalled)")
    a2.set_title(f"beta = {BETA:g} cylinder among frozen neighbour spheres (dots: seeds)", fontsize=9)
    a2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="10 seeds, vpd 4 6 8, 24 nodes per half orbit")
    ap.add_argument("--seeds", type=int, help="seeds per concentration, >= 2")
    ap.add_argument("--vpd", type=int, nargs="+", help="voxels per diameter, even, >= 2 values")
    ap.add_argument("--nphi", type=int, help="nodes per half orbit, even, >= 8")
    ap.add_argument("--out", type=Path, default=Path("out/seed_examples/rotation_neighbours"))
    ap.add_argument("--reanalyse", type=Path, help="tables and figure from a saved .nc (no solves)")
    a = ap.parse_args(argv)
    base = LARGE if a.large else SMALL
    # "is not None": an explicit 0 is a value to refuse, not a request for the default
    form = Form(vpd=tuple(sorted(a.vpd)) if a.vpd else base.vpd,
                seeds=a.seeds if a.seeds is not None else base.seeds,
                nphi=a.nphi if a.nphi is not None else base.nphi)
    if form.seeds < 2:
        ap.error(f"--seeds: need >= 2 (a standard error over seeds), got {form.seeds}")
    if len(set(form.vpd)) < 2 or any(v < 2 or v % 2 for v in form.vpd):
        ap.error(f"--vpd: need >= 2 distinct even voxel counts per diameter >= 2, got {list(form.vpd)}")
    if form.nphi < 8 or form.nphi % 2:
        ap.error(f"--nphi: must be even and >= 8 (the error bound halves it), got {form.nphi}")
    return a, form


def main(argv=None) -> int:
    a, form = _args(argv)
    if a.reanalyse is not None:
        import xarray as xr

        with xr.open_dataset(a.reanalyse, engine="h5netcdf") as f:
            raw = f.load()
    else:
        raw = run(form)
        a.out.mkdir(parents=True, exist_ok=True)
        raw.to_netcdf(a.out / "rotation_neighbours.nc", engine="h5netcdf")  # the solves, kept if the analysis fails
    a.out.mkdir(parents=True, exist_ok=True)
    ds, table = analyse(raw)
    ds.to_netcdf(a.out / "rotation_neighbours.nc", engine="h5netcdf")
    (a.out / "rotation_neighbours.md").write_text(table, encoding="utf-8")
    print(table)
    figure(ds, a.out / "rotation_neighbours.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
