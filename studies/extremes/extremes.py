"""Stability at the extremes: does every extreme scene give an accurate run or a detected failure?

Question
    At the edges of the parameter space -- aspect ratio up to 100, volume fractions towards
    random close packing (spheres) and n L^3 >> L/d (fibres), viscosity contrast kappa up to
    1e6, time steps in which a fibre tip moves more than alpha and more than a radius, 1-2
    voxels per diameter, alpha = 0, elongational flows to large strain, very long runs --
    does `pyfold run` give either an accurate run (with its error against an exact reference
    where one exists) or a detected failure (exit 2 naming the key and its allowed range, or
    exit 1 with a diagnostic and the last good state kept), and never silent garbage (NaN,
    overlaps or a broken contact guarantee under status "ok"), a hang or a crash?

Command
    nice -n 10 python studies/extremes/extremes.py            # small form
    nice -n 10 python studies/extremes/extremes.py --large    # full sizes (10^6 steps, ...)
    python studies/extremes/extremes.py --cases beta100_single_orbit alpha0_fibres
    fold_run is taken from $PYFOLD_FOLD_RUN when set (as `pyfold run` does).

Cost on 2 cores
    small form: 2.7 min of CPU (measured: 10.5 min wall on the shared machine at load 8.5;
    one simulation at a time, the crossing and orbit checks included); --large: about an hour
    (dominated by the 10^6-step runs; not measured).

Outputs (under out/extremes/, or --out)
    extremes.nc   one row per case: category, error and its bound, smallest gap / alpha,
                  steps done, exit status, diagnostic (xarray.open_dataset, engine h5netcdf)
    extremes.md   the table (docs/extremes.md explains it)
    a printed table, and the counts per category

Classification (docs/extremes.md):
    accurate           exit 0, status "ok", every check passed; the error column gives the
                       deviation from the exact reference (single-fibre Jeffery propagator) or,
                       without one, the worst invariant defect checked (a2 trace, unit norm)
    detected failure   exit 2 with a message naming the key and the allowed range, or exit 1
                       with status "failed: step N, ...: cause" in the run file and a last good
                       state (records up to steps_done) that passes every check
    silent garbage     a run that claims success (or a last good state) that fails a check:
                       NaN/inf, a2 not an orientation tensor, capsules closer than alpha
                       (overlapping or not) without a capped contact step, a Stokes residual
                       above the tolerance, an orbit error above its round-off bound
    hang               no answer within the case's time limit (the process group is killed)
    crash              killed by a signal, an exit status other than 0/1/2, a Python traceback,
                       or exit 1 without a recorded cause
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

# Parameters
EPS = float(np.finfo(np.float64).eps)
GAP_TOL_ULPS = 64          # fold_contacts: the loop stops when every gap >= -64 eps max L_cell
SCAN_ULPS = 2 * GAP_TOL_ULPS  # this scan's own distance round-off adds at most as much again
ROUNDOFF_PER_STEP = 16     # relative round-off of one exact rigid-rotation step (3x3 products,
                           # normalisation), in units of eps, bounded generously
CATEGORIES = ("accurate", "detected failure", "silent garbage", "hang", "crash")
ROOT = Path(__file__).resolve().parents[2]
STOKES_SMALL = ROOT / "data" / "scenes" / "stokes_small.toml"


@dataclasses.dataclass
class Case:
    name: str
    extreme: str                 # the extreme probed, in words
    scene: dict
    timeout: float               # seconds before the run counts as a hang
    reference: str | None = None  # "jeffery": single fibre, exact propagator exp(M t) p0 / |.|


@dataclasses.dataclass
class Outcome:
    name: str
    extreme: str
    category: str
    error: float = float("nan")
    bound: float = float("nan")
    error_kind: str = ""
    min_gap_over_alpha: float = float("nan")
    crossings: int = -1          # fibre pairs crossed within a step (-1: not checked)
    norm_drift: float = float("nan")  # largest |1 - |p|| over the records kept
    steps_done: int = -1
    n_steps: int = -1
    exit_status: int = -99
    seconds: float = float("nan")
    diagnostic: str = ""


# Problem: the scenes
def _fibre_scene(*, beta: float, count: int, side, alpha_over_d: float = 0.1, alpha: float | None = None,
                 dt: float, t_end: float, flow: dict | None = None, hydrodynamics: str = "jeffery",
                 collisions: str = "strategy", seed: int = 1, interval: float | None = None,
                 orientation: dict | None = None, on_cap: str | None = None) -> dict:
    """Fibres of length 1 m, radius 1/(2 beta), in a periodic cell (side: one value or 3)."""
    radius = 0.5 / beta
    sizes = list(side) if isinstance(side, (list, tuple)) else [float(side)] * 3
    fam = {"name": "fibres", "shape": "fibre", "length": 1.0, "radius": radius, "count": int(count)}
    fam.update(orientation or {"orientation": "isotropic"})
    model = {"hydrodynamics": hydrodynamics, "collisions": collisions,
             "alpha": float(alpha if alpha is not None else round(alpha_over_d * 2 * radius, 12))}
    if on_cap:
        model["on_contact_cap"] = on_cap
    n = round(t_end / dt)
    rec = interval if interval is not None else dt * max(1, n // 50)
    return {"title": "extremes", "cell": {"dim": 3, "size": sizes},
            "flow": flow or {"type": "simple_shear", "rate": 1.0},
            "particles": [fam], "model": model,
            "numerics": {"dt": dt, "t_end": t_end, "seed": seed},
            "output": {"interval": rec, "snapshot_interval": t_end, "checkpoint_interval": t_end}}


def _sheared(beta, n_l3, t_end, *, seed=1, dt=None, alpha=None, hydrodynamics="jeffery", stokes=None,
             every_step=False):
    """The studies' contacts-only scene (pyfold.scene.sheared_fibres), as a dict to edit;
    ``every_step``: a snapshot every step, for the crossing check (:func:`count_crossings`)."""
    import tomllib

    from pyfold.scene.sheared_fibres import sheared_fibres

    s = sheared_fibres(beta, n_l3, seed, t_end, dt=dt, hydrodynamics=hydrodynamics, stokes=stokes)
    scene = tomllib.loads(s.toml)
    if alpha is not None:
        scene["model"]["alpha"] = float(alpha)
    n = round(s.t_end / s.dt)
    scene["output"] = {"interval": round(s.dt * max(1, n // 50), 12),
                       "snapshot_interval": s.dt if every_step else s.t_end,
                       "checkpoint_interval": s.t_end}
    return scene


def _spheres(phi, *, alpha_over_r=0.01, dt=0.01, t_end=1.0, seed=1, radius=0.1, side=1.0):
    return {"title": "extremes", "cell": {"dim": 3, "size": [side] * 3},
            "flow": {"type": "simple_shear", "rate": 1.0},
            "particles": [{"name": "beads", "shape": "sphere", "radius": radius, "volume_fraction": phi}],
            "model": {"hydrodynamics": "jeffery", "collisions": "strategy", "alpha": alpha_over_r * radius},
            "numerics": {"dt": dt, "t_end": t_end, "seed": seed},
            "output": {"interval": t_end / 10, "snapshot_interval": t_end, "checkpoint_interval": t_end}}


def _stokes_small(t_end=0.05, **stokes):
    import tomllib

    scene = tomllib.loads(STOKES_SMALL.read_text())
    scene["model"]["hydrodynamics"] = "stokes"
    scene["numerics"]["t_end"] = t_end
    scene["numerics"]["stokes"].update(stokes)
    scene["output"] = {"interval": scene["numerics"]["dt"], "snapshot_interval": t_end,
                       "checkpoint_interval": t_end}
    return scene


def build_cases(large: bool) -> list[Case]:
    # An orbit through a generic direction (not in a symmetry plane).
    tilted = {"orientation": "aligned", "direction": [0.3, 0.8, 0.52]}
    single_side = 1.2  # one particle per cell: no pair, no range rule (docs/scenes.md)
    cases = []
    # aspect ratio 100
    t_orbit = 800.0 if large else 400.0  # Jeffery period of beta = 100 (cox): 2 pi (57.8 + 1/57.8) = 363
    cases.append(Case("beta100_single_orbit", "beta = 100, one fibre, contacts-only, >1 Jeffery period",
                      _fibre_scene(beta=100, count=1, side=single_side, dt=0.01, t_end=t_orbit,
                                   orientation=tilted, interval=2.0), 300, reference="jeffery"))
    for seed in ((1, 2) if not large else (1, 2, 3)):
        cases.append(Case(f"beta100_contacts_s{seed}", "beta = 100, n L^3 = 5 (semi-dilute), contacts",
                          _sheared(100, 5.0 if not large else 20.0, 1.0 if not large else 5.0, seed=seed,
                                   every_step=True), 300))
    cases.append(Case("beta100_stokes", "beta = 100 with the Stokes solver (grid far beyond the budget)",
                      _sheared(100, 5.0, 0.01, hydrodynamics="stokes"), 120))
    # towards random close packing (spheres; placement grows each sphere by alpha/2)
    for phi in (0.45, 0.55, 0.60, 0.63):
        cases.append(Case(f"spheres_phi{phi:.2f}", f"spheres, phi = {phi} (random close packing 0.64)",
                          _spheres(phi, t_end=1.0 if not large else 10.0), 300))
    # n L^3 >> L/d (fibres, beta = 10: L/d = 10)
    for n_l3, seeds in ((12.0, (1, 2)), (20.0, (1,)), (30.0, (1,)), (60.0, (1,))):
        for seed in seeds:
            cases.append(Case(f"fibres_nl3_{n_l3:g}_s{seed}", f"fibres beta = 10, n L^3 = {n_l3:g} (L/d = 10)",
                              _sheared(10, n_l3, 1.0 if not large else 10.0, seed=seed, every_step=True), 300))
    # kappa up to 1e6 (Stokes)
    for kappa in (1e4, 1e6):
        cases.append(Case(f"stokes_kappa{kappa:.0e}", f"Stokes, kappa = {kappa:.0e}",
                          _stokes_small(0.05 if not large else 0.5, kappa=kappa), 300))
    # a fibre tip moving more than alpha, more than a radius, 10 radii per step (alpha = R/5)
    for label, dt in (("2alpha", 0.04), ("2radius", 0.2), ("10radius", 1.0)):
        cases.append(Case(f"dt_tip_{label}", f"dt: tip moves {label.replace('alpha', ' alpha').replace('radius', ' R')} "
                          "per step, n L^3 = 5", _sheared(10, 5.0, 20.0 if not large else 200.0, dt=dt, every_step=True), 300))
    cases.append(Case("dt_spheres_2radius", "dt: neighbouring spheres pass 2 R per step, phi = 0.3",
                      _spheres(0.30, dt=2.0, t_end=20.0, alpha_over_r=0.1), 300))
    # 1-2 voxels per diameter (Stokes)
    for cpd in (1, 2):
        cases.append(Case(f"stokes_cpd{cpd}", f"Stokes, {cpd} voxel(s) per diameter",
                          _stokes_small(0.05 if not large else 0.5, cells_per_diameter=cpd), 300))
    # alpha = 0
    cases.append(Case("alpha0_fibres", "alpha = 0, fibres n L^3 = 5",
                      _sheared(10, 5.0, 5.0 if not large else 50.0, alpha=0.0, every_step=True), 300))
    cases.append(Case("alpha0_spheres", "alpha = 0, spheres phi = 0.5",
                      _spheres(0.5, alpha_over_r=0.0, t_end=1.0 if not large else 10.0), 300))
    # elongational flows to large strain
    strain = 20.0 if not large else 60.0
    cases.append(Case("planar_single", f"planar elongation, one fibre, Hencky strain {strain:g}",
                      _fibre_scene(beta=10, count=1, side=single_side, dt=0.01, t_end=strain, interval=0.2,
                                   flow={"type": "planar_elongation", "rate": 1.0}, orientation=tilted),
                      300, reference="jeffery"))
    # a deforming lattice without remap stretches the cell: the imposed displacement per step
    # at its corners outgrows half the cell near Hencky strain 4.6 at dt = 0.01 (validation's rule)
    cases.append(Case("uniaxial_single", "uniaxial elongation, one fibre, Hencky strain 4.5",
                      _fibre_scene(beta=10, count=1, side=single_side, dt=0.01, t_end=4.5, interval=0.05,
                                   flow={"type": "uniaxial_elongation", "rate": 1.0}, orientation=tilted),
                      300, reference="jeffery"))
    cases.append(Case("uniaxial_single_strain20", "uniaxial elongation, one fibre, Hencky strain 20",
                      _fibre_scene(beta=10, count=1, side=single_side, dt=0.01, t_end=20.0, interval=0.2,
                                   flow={"type": "uniaxial_elongation", "rate": 1.0}, orientation=tilted),
                      300, reference="jeffery"))
    # Kraynik-Reinelt: the reduced cell thins to 0.864 L over a period, so L = 2.8 > 2 rc / 0.864
    cases.append(Case("planar_contacts", f"planar elongation (Kraynik-Reinelt), n L^3 = 5, strain {strain:g}",
                      _fibre_scene(beta=10, count=110, side=2.8, dt=0.01, t_end=strain,
                                   flow={"type": "planar_elongation", "rate": 1.0}), 300))
    cases.append(Case("uniaxial_contacts", "uniaxial elongation, n L^3 = 5, beyond the lattice's strain",
                      _fibre_scene(beta=10, count=69, side=2.4, dt=0.01, t_end=strain,
                                   flow={"type": "uniaxial_elongation", "rate": 1.0}), 120))
    # very long runs, contacts only
    n_long = 10 ** 6 if large else 10 ** 5
    cases.append(Case(f"long_single_{n_long:.0e}", f"{n_long:.0e} steps, one fibre, contacts-only",
                      _fibre_scene(beta=10, count=1, side=single_side, dt=0.01, t_end=n_long * 0.01,
                                   orientation=tilted, interval=n_long * 0.01 / 100), 1200 if large else 300,
                      reference="jeffery"))
    n_many = 10 ** 6 if large else 2 * 10 ** 4
    cases.append(Case(f"long_contacts_{n_many:.0e}", f"{n_many:.0e} steps, n L^3 = 5, contacts",
                      _sheared(10, 5.0, n_many * 0.01), 3600 if large else 300))
    return cases


# Checks
def _segment_gaps(x1, p1, h1, r1, x2, p2, h2, r2):
    """Surface gaps of capsules (segments x +- h p, radius r), vectorised over rows; the closest
    points of two segments (Ericson 2005, Real-Time Collision Detection, 5.1.9), written here
    independently of fortran/geometry/fold_segment.f90 so that a defect there cannot hide."""
    d1, d2 = 2 * h1[:, None] * p1, 2 * h2[:, None] * p2
    a1, a2 = x1 - h1[:, None] * p1, x2 - h2[:, None] * p2
    r = a1 - a2
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    denom = a * e - b * b
    tiny = 1e-300
    s = np.where((a > tiny) & (denom > 1e-14 * np.maximum(a * e, tiny)),
                 np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0, 1.0), 0.0)
    t = np.where(e > tiny, (b * s + f) / np.where(e > tiny, e, 1.0), 0.0)
    s = np.where(t < 0.0, np.where(a > tiny, np.clip(-c / np.where(a > tiny, a, 1.0), 0.0, 1.0), 0.0), s)
    s = np.where(t > 1.0, np.where(a > tiny, np.clip((b - c) / np.where(a > tiny, a, 1.0), 0.0, 1.0), 0.0), s)
    t = np.clip(t, 0.0, 1.0)
    dist = np.linalg.norm(a1 + s[:, None] * d1 - a2 - t[:, None] * d2, axis=1)
    return dist - r1 - r2


def lattice_vectors(f, t: float) -> np.ndarray:
    """Rows: the periodic lattice at time t. Simple shear: Lees-Edwards, a2 = (gamma t Ly, Ly, 0)
    (computed here); deforming lattices: fold_cell's reduced basis (pyfold.native.geometry)."""
    res = f["setup/resolved"]
    lengths = np.asarray(res["cell_lengths"][()], dtype=float)
    dim = int(res["dim"][()])
    g = np.asarray(res["velocity_gradient"][()], dtype=float)
    off = g.copy()
    off[0, 1] = 0.0
    if not np.any(off):
        vec = np.diag(lengths[:dim])
        vec[1, 0] = (g[0, 1] * t * lengths[1]) % lengths[0]
        return vec
    from pyfold.native import geometry as geo

    cell = geo.Cell(tuple(lengths[:dim]), velocity_gradient=g[:dim, :dim]).at_time(t)
    return cell.lattice().vectors


def min_gap_scan(x, p, half, rad, alpha, vectors) -> float:
    """Smallest capsule surface gap over all pairs and periodic images (shifts -2..2 along each
    reduced lattice vector), +inf for a single particle."""
    n, dim = x.shape
    if n < 2:
        return float("inf")
    i, j = np.triu_indices(n, 1)
    # pairs beyond this centre distance have a gap > 2 alpha + max R: the gap reported is then
    # at least that (+inf if no pair is that close)
    reach = half[i] + rad[i] + half[j] + rad[j] + 2 * alpha + float(np.max(rad))
    best = float("inf")
    grid = np.stack(np.meshgrid(*[np.arange(-2, 3)] * dim, indexing="ij"), -1).reshape(-1, dim)
    base = x[j] - x[i]
    for shift in grid @ vectors:
        d = base + shift
        near = np.flatnonzero(np.einsum("ij,ij->i", d, d) < reach ** 2)
        if near.size == 0:
            continue
        ii, jj = i[near], j[near]
        gaps = _segment_gaps(np.zeros((near.size, dim)), p[ii], half[ii], rad[ii], d[near], p[jj], half[jj],
                             rad[jj])
        best = min(best, float(gaps.min()))
    return best


def _min_image(dx, vectors):
    """Shortest image of each row of dx among shifts -2..2 along the lattice vectors."""
    dim = dx.shape[1]
    grid = np.stack(np.meshgrid(*[np.arange(-2, 3)] * dim, indexing="ij"), -1).reshape(-1, dim)
    cand = dx[:, None, :] + (grid @ vectors)[None, :, :]
    k = np.argmin(np.einsum("nsi,nsi->ns", cand, cand), axis=1)
    return cand[np.arange(len(dx)), k]


def _slerp(p, q, u):
    """Axes along the great circle from p to q (rows), fraction u."""
    c = np.clip(np.einsum("ij,ij->i", p, q), -1.0, 1.0)
    ang = np.arccos(c)
    small = ang < 1e-8
    sa = np.where(small, 1.0, np.sin(ang))
    a = np.where(small, 1.0 - u, np.sin((1.0 - u) * ang) / sa)
    b = np.where(small, u, np.sin(u * ang) / sa)
    out = a[:, None] * p + b[:, None] * q
    return out / np.linalg.norm(out, axis=1)[:, None]


def count_crossings(f, half, rad, alpha, dt, substeps: int = 16) -> int:
    """Pairs of fibres whose axes pass through each other between consecutive snapshots.

    Between two snapshots the motion is interpolated (centres on straight lines: the rigid
    update translates by v dt; axes along great circles, close to the exact rotation). The
    sign of (p_i x p_j) . d_ij says on which side of fibre i the axis of fibre j passes; a
    sign change between two sub-steps at both of which the closest points of the two lines
    lie inside both segments means the two axes met inside the fibres: they crossed through
    each other, which no end-of-step gap check can see. Needs a snapshot every step."""
    n_snap = int(f.attrs.get("snapshots_complete", f["snapshot"].shape[0]))
    steps = np.asarray(f["snapshot"][:n_snap])
    g = np.asarray(f["setup/resolved/velocity_gradient"][()], dtype=float)
    shear = float(g[0, 1])
    g[0, 1] = 0.0
    if n_snap < 2 or np.any(np.diff(steps) != 1) or np.all(half == 0) or np.any(g):
        return -1  # simple shear only
    n = len(half)
    i, j = np.triu_indices(n, 1)
    fib = (half[i] > 0) & (half[j] > 0)
    i, j = i[fib], j[fib]
    dim = f["x"].shape[2]
    grid = np.stack(np.meshgrid(*[np.arange(-2, 3)] * dim, indexing="ij"), -1).reshape(-1, dim)
    crossed = set()
    x0 = np.asarray(f["x"][0], dtype=float)
    p0 = np.asarray(f["p"][0], dtype=float)
    for k in range(n_snap - 1):
        x1 = np.asarray(f["x"][k + 1], dtype=float)
        p1 = np.asarray(f["p"][k + 1], dtype=float)
        # Lees-Edwards: the sliding image moves on continuously over the step (the offset is
        # not wrapped between the two ends, so an image keeps its integer label)
        va = lattice_vectors(f, steps[k] * dt)
        vb = va.copy()
        vb[1, 0] += shear * dt * float(va[1, 1])
        x1u = x0 + _min_image(x1 - x0, vb)  # each particle's displacement in the step
        # candidates: (pair, image) whose centre separation, linear in the step, comes
        # within the sum of the capsules' half extents (the closest approach of the segment
        # d0 -> d1 to the origin)
        reach = half[i] + half[j] + rad[i] + rad[j] + alpha
        base0, base1 = x0[j] - x0[i], x1u[j] - x1u[i]
        # images: the 3^dim lattice points around the nearest one at the start of the step
        # (a step moves a pair far less than a cell, so its closest image stays among them)
        nearest = -np.rint(np.linalg.solve(va.T, base0.T).T)
        shifts = nearest[:, None, :] + grid[np.all(np.abs(grid) <= 1, axis=1)][None, :, :]
        c0 = base0[:, None, :] + shifts @ va
        c1 = base1[:, None, :] + shifts @ vb
        dd = c1 - c0
        w = np.clip(-np.einsum("nsi,nsi->ns", c0, dd) / np.maximum(np.einsum("nsi,nsi->ns", dd, dd), 1e-300),
                    0.0, 1.0)
        closest = c0 + w[..., None] * dd
        pair, image = np.nonzero(np.einsum("nsi,nsi->ns", closest, closest) < (reach ** 2)[:, None])
        near = pair
        if near.size:
            d0 = c0[pair, image]
            d1 = c1[pair, image]  # the same image, carried by the lattice
            ii, jj = i[near], j[near]
            prev_sign = prev_inside = None
            for u in np.linspace(0.0, 1.0, substeps + 1):
                d = (1 - u) * d0 + u * d1
                pa, pb = _slerp(p0[ii], p1[ii], u), _slerp(p0[jj], p1[jj], u)
                cross = np.cross(pa, pb)
                sigma = np.einsum("ij,ij->i", cross, d)
                c2 = np.einsum("ij,ij->i", cross, cross)
                # closest points of the two lines: x_i + s pa, x_j + t pb (d = x_j - x_i)
                b = np.einsum("ij,ij->i", pa, pb)
                da, db = np.einsum("ij,ij->i", pa, d), np.einsum("ij,ij->i", pb, d)
                safe = np.where(c2 > 1e-12, c2, 1.0)
                s_ = (da - b * db) / safe
                t_ = (b * da - db) / safe
                inside = (c2 > 1e-12) & (np.abs(s_) < half[ii]) & (np.abs(t_) < half[jj])
                sign = np.sign(sigma)
                if prev_sign is not None:
                    hit = inside & prev_inside & (sign * prev_sign < 0)
                    crossed.update(zip(ii[hit].tolist(), jj[hit].tolist()))
                    sign = np.where(sign == 0, prev_sign, sign)  # through exactly 0: keep the side
                    inside = np.where(sigma == 0, prev_inside & inside, inside)
                prev_sign, prev_inside = sign, inside
        x0, p0 = x1, p1
    return len(crossed)


def jeffery_reference(f, times: np.ndarray) -> tuple[np.ndarray, float]:
    """Exact orientation of a single particle, p(t) = exp(M t) p0 / |exp(M t) p0|, M = W + xi E
    (Jeffery 1922; docs/physics.md), and the amplification bound K: the largest, over record
    pairs t_k <= t_j, of ||exp(M (t_j - t_k))|| / |exp(M (t_j - t_k)) p(t_k)| (how much a
    relative round-off error made at t_k can grow by t_j)."""
    from scipy.linalg import expm

    g = np.asarray(f["setup/resolved/velocity_gradient"][()], dtype=float)
    dim = int(f["setup/resolved/dim"][()])
    g = g[:dim, :dim]
    xi = float(f["initial/xi"][0])
    m = 0.5 * (g - g.T) + xi * 0.5 * (g + g.T)
    p0 = np.asarray(f["initial/p"][0], dtype=float)
    out = []
    for t in times:
        q = expm(m * t) @ p0
        out.append(q / np.linalg.norm(q))
    out = np.array(out)
    amp = 1.0
    for k in range(len(times)):
        for jj in range(k, len(times), max(1, (len(times) - k) // 20)):
            e = expm(m * (times[jj] - times[k]))
            amp = max(amp, np.linalg.norm(e, 2) / np.linalg.norm(e @ out[k]))
    return out, amp


def check_run(path: Path, case: Case, out: Outcome) -> tuple[list[str], str]:
    """Checks of a run file (complete or failed): the list of broken checks and the error text."""
    import h5py

    from pyfold.errors import InputError
    from pyfold.run_checks import check_orientation_records

    broken: list[str] = []
    with h5py.File(path, "r") as f:
        status = f.attrs.get("status", "")
        status = status.decode() if isinstance(status, bytes) else str(status)
        res = f["setup/resolved"]
        out.n_steps = int(res["n_steps"][()])
        out.steps_done = int(f.attrs.get("steps_done", -1))
        dt = float(res["dt"][()])
        alpha = float(res["alpha"][()])
        lengths = np.asarray(res["cell_lengths"][()], dtype=float)
        collisions = res["collisions"][()]
        if isinstance(collisions, bytes):
            collisions = collisions.decode()
        else:  # fold_run's code (fold_contacts: 0 none, 1 naive, 2 strategy)
            collisions = {0: "none", 1: "naive", 2: "strategy"}.get(int(collisions), str(collisions))
        nrec = int(f.attrs.get("records_complete", f["time"].shape[0]))
        times = np.asarray(f["time"][:nrec])
        steps = np.asarray(f["step"][:nrec])
        keep = steps <= out.steps_done
        a2 = np.asarray(f["a2"][:nrec])[keep]
        n_particles = int(f["initial/x"].shape[0])
        # NaN scan of every record of the last good state
        for name in ("a2", "a4", "min_gap", "unit_norm_drift", "length_drift", "stokes_residual", "rigidity_max",
                     "stress"):
            if name in f and not np.all(np.isfinite(np.asarray(f[name][:nrec])[keep])):
                broken.append(f"{name} has NaN/inf")
        try:
            check_orientation_records(a2, times[keep], n_particles, source="a2")
        except InputError as exc:
            broken.append(str(exc).split(": not an orientation")[0])
        # unit norm drift: each step is an exact rotation, so the drift stays within the
        # round-off of the steps made (worst case: linear accumulation)
        drift = float(np.max(np.asarray(f["unit_norm_drift"][:nrec])[keep], initial=0.0))
        out.norm_drift = drift
        drift_bound = ROUNDOFF_PER_STEP * EPS * max(out.steps_done, 1)
        if drift > drift_bound:
            broken.append(f"unit-vector norm drift {drift:.3g} > {drift_bound:.3g} (round-off bound)")
        # Stokes: every solve reached its tolerance
        if "stokes_residual" in f:
            tol = _stokes_tolerance(f)
            resid = np.asarray(f["stokes_residual"][:nrec])[keep]
            if status != "ok" and resid.size:
                # the record written at the failure carries the worst residual since the
                # previous record, the failed solve's: that residual is the diagnostic
                resid = resid[:-1]
            if resid.size and np.nanmax(resid) > tol:
                broken.append(f"Stokes residual {np.nanmax(resid):.3g} > tolerance {tol:.3g} under status {status!r}")
        # the last good state: the last snapshot must be at steps_done
        snap_n = int(f.attrs.get("snapshots_complete", f["snapshot"].shape[0]))
        capped = int(np.sum(np.asarray(f["capped_steps"][:nrec])[keep])) if "capped_steps" in f else 0
        if snap_n == 0:
            broken.append("no snapshot of the last good state")
        else:
            snap_step = int(f["snapshot"][snap_n - 1])
            if snap_step != out.steps_done:
                broken.append(f"last snapshot at step {snap_step}, not at the last good step {out.steps_done}")
            x = np.asarray(f["x"][snap_n - 1], dtype=float)
            p = np.asarray(f["p"][snap_n - 1], dtype=float)
            if not (np.all(np.isfinite(x)) and np.all(np.isfinite(p))):
                broken.append("last good particle state has NaN/inf")
            else:
                from pyfold.scene.shapes import half_segment

                shape_codes = np.asarray(f["initial/shape"][()])
                rad = np.asarray(f["initial/radius"][()], dtype=float)
                length = np.asarray(f["initial/length"][()], dtype=float)
                names = {1: "fibre", 2: "sphere", 3: "spheroid"}
                half = np.array([half_segment(names[int(s)], r, ln) for s, r, ln in zip(shape_codes, rad, length)])
                gap = min_gap_scan(x, p, half, rad, alpha, lattice_vectors(f, snap_step * dt))
                tol = SCAN_ULPS * EPS * float(np.max(lengths))
                out.min_gap_over_alpha = gap / alpha if alpha > 0 else gap
                if collisions != "none" and n_particles > 1:
                    if gap < -tol:
                        broken.append(f"overlap: capsules {-gap:.3g} m inside each other")
                    elif gap < alpha - tol and capped == 0:
                        broken.append(f"gap {gap:.6g} < alpha = {alpha:.6g} without a capped contact step")
                recorded = float(np.asarray(f["min_gap"][:nrec])[keep][-1]) if nrec and keep.any() else np.nan
                if collisions != "none" and n_particles > 1 and np.isfinite(recorded) and recorded - gap > tol + \
                        1e-9 * abs(recorded) and snap_step == steps[keep][-1]:
                    broken.append(f"recorded min_gap {recorded:.6g} exceeds the scanned {gap:.6g}")
        # fibres passing through each other within a step (snapshots every step only)
        if collisions != "none" and n_particles > 1 and snap_n > 2:
            from pyfold.scene.shapes import half_segment

            names = {1: "fibre", 2: "sphere", 3: "spheroid"}
            half_all = np.array([half_segment(names[int(s)], r, ln) for s, r, ln in zip(
                f["initial/shape"][()], f["initial/radius"][()], f["initial/length"][()])])
            out.crossings = count_crossings(f, half_all, np.asarray(f["initial/radius"][()], float), alpha, dt)
            if out.crossings > 0:
                broken.append(f"{out.crossings} fibre pair(s) passed through each other within a step "
                              "(end-of-step gaps all >= alpha)")
        # accuracy against the exact single-particle reference
        if case.reference == "jeffery" and keep.any():
            t = times[keep]
            ref, amp = jeffery_reference(f, t)
            exact = np.einsum("ti,tj->tij", ref, ref)
            err = float(np.max(np.abs(a2 - exact)))
            bound = 2 * ROUNDOFF_PER_STEP * EPS * max(out.steps_done, 1) * amp
            out.error, out.bound, out.error_kind = err, bound, "a2 vs exact Jeffery propagator"
            if err > bound:
                broken.append(f"a2 differs from the exact Jeffery orbit by {err:.3g} > round-off bound {bound:.3g}")
        else:
            trace = float(np.max(np.abs(np.trace(a2, axis1=1, axis2=2) - 1.0), initial=0.0))
            out.error = max(trace, drift)
            out.bound = drift_bound
            out.error_kind = "max(|tr a2 - 1|, unit-norm drift)"
    return broken, status


def _stokes_tolerance(f) -> float:
    import json

    scene = json.loads(f["setup/scene_json"][()])
    return float(scene.get("numerics", {}).get("stokes", {}).get("tolerance", 1e-6))


# Solver: one case through `pyfold run`
KEY_RE = re.compile(r"[a-z_]+(\[\d+\])?\.[a-z_]+")
RANGE_RE = re.compile(r"allowed|must|at most|at least|largest|exceed|between|<=|>=|in \[|in \(|range|limit|budget")


def run_case(case: Case, workdir: Path) -> Outcome:
    import tomli_w

    out = Outcome(case.name, case.extreme, "crash")
    scene_path = workdir / f"{case.name}.toml"
    run_path = workdir / f"{case.name}.h5"
    scene_path.write_text(tomli_w.dumps(case.scene))
    pyfold_cli = Path(sys.executable).with_name("pyfold")
    cmd = ["nice", "-n", "10", str(pyfold_cli), "run", str(scene_path), "-o", str(run_path), "--force"]
    start = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=case.timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the group this case started: pyfold and its fold_run
        proc.communicate()
        out.category, out.seconds = "hang", time.monotonic() - start
        out.diagnostic = f"no answer within {case.timeout:g} s"
        return out
    out.seconds = time.monotonic() - start
    out.exit_status = rc = proc.returncode
    stderr = stderr.replace(f"{workdir}/", "")  # the scene's name is enough in the diagnostics
    last = [ln for ln in stderr.splitlines() if ln.strip() and "━" not in ln]
    if "Traceback (most recent call last)" in stderr:
        out.category, out.diagnostic = "crash", "Python traceback: " + (last[-1] if last else "")
        return out
    if rc not in (0, 1, 2):
        out.category = "crash"
        out.diagnostic = f"exit status {rc}" + (f" (signal {-rc})" if rc < 0 else "") + ": " + " | ".join(last[-3:])
        return out
    if rc == 2:
        message = " | ".join(ln.strip() for ln in last if "error" in ln or ln.startswith("  "))[:400]
        named = KEY_RE.search(message) and RANGE_RE.search(message)
        out.category = "detected failure" if named else "crash"
        out.diagnostic = message if named else "exit 2 without a key and an allowed range: " + message
        return out
    if not run_path.exists():
        out.diagnostic = f"exit {rc} and no run file: " + " | ".join(last[-3:])
        return out
    broken, status = check_run(run_path, case, out)
    if rc == 0:
        if status != "ok":
            broken.append(f"exit 0 but status {status!r}")
        out.category = "silent garbage" if broken else "accurate"
        out.diagnostic = "; ".join(broken) if broken else (
            "; ".join(ln for ln in last if "warning" in ln.lower())[:300])
        return out
    # rc == 1: a failure must be recorded, with its last good state intact
    if not status.startswith("failed"):
        out.category, out.diagnostic = "crash", f"exit 1, status {status!r}: " + " | ".join(last[-3:])
    elif broken:
        out.category, out.diagnostic = "silent garbage", f"{status}; last good state broken: {'; '.join(broken)}"
    else:
        out.category, out.diagnostic = "detected failure", status
    return out


# Run
def table(outcomes: list[Outcome]) -> str:
    head = ("| case | extreme | outcome | error (bound) | norm drift | min gap / alpha | crossed | steps | exit | s | "
            "diagnostic |\n|---|---|---|---|---|---|---|---|---|---|---|\n")
    rows = []
    for o in outcomes:
        err = "" if not np.isfinite(o.error) else f"{o.error:.2e} ({o.bound:.1e})"
        gap = "" if not np.isfinite(o.min_gap_over_alpha) else f"{o.min_gap_over_alpha:.6g}"
        steps = "" if o.steps_done < 0 else f"{o.steps_done}/{o.n_steps}"
        diag = o.diagnostic.replace("|", "/").replace("\n", " ")
        rows.append(f"| {o.name} | {o.extreme} | {o.category} | {err} | {'' if not np.isfinite(o.norm_drift) else f'{o.norm_drift:.1e}'} | {gap} | {'' if o.crossings < 0 else o.crossings} | {steps} | {o.exit_status} | "
                    f"{o.seconds:.1f} | {diag[:300]} |")
    counts = {c: sum(o.category == c for o in outcomes) for c in CATEGORIES}
    tail = "\n\nCounts: " + ", ".join(f"{c} {n}" for c, n in counts.items()) + "\n"
    return head + "\n".join(rows) + tail


def save(outcomes: list[Outcome], path: Path, large: bool) -> None:
    import xarray as xr

    def col(name):
        return [getattr(o, name) for o in outcomes]

    ds = xr.Dataset(
        {"category": ("case", np.array(col("category"), dtype=object)),
         "extreme": ("case", np.array(col("extreme"), dtype=object)),
         "error": ("case", np.array(col("error"), float), {"units": "1", "long_name": "error (see error_kind)"}),
         "error_bound": ("case", np.array(col("bound"), float), {"units": "1", "long_name": "round-off bound"}),
         "error_kind": ("case", np.array(col("error_kind"), dtype=object)),
         "min_gap_over_alpha": ("case", np.array(col("min_gap_over_alpha"), float),
                                {"units": "1", "long_name": "smallest capsule gap of the last good state / alpha "
                                 "(the gap in m when alpha = 0)"}),
         "crossings": ("case", np.array(col("crossings"), np.int64),
                       {"long_name": "fibre pairs that passed through each other within a step (-1: not checked)"}),
         "norm_drift": ("case", np.array(col("norm_drift"), float),
                        {"units": "1", "long_name": "largest |1 - |p|| over the records kept"}),
         "steps_done": ("case", np.array(col("steps_done"), np.int64)),
         "n_steps": ("case", np.array(col("n_steps"), np.int64)),
         "exit_status": ("case", np.array(col("exit_status"), np.int64)),
         "wall_seconds": ("case", np.array(col("seconds"), float), {"units": "s"}),
         "diagnostic": ("case", np.array(col("diagnostic"), dtype=object))},
        coords={"case": np.array(col("name"), dtype=object)},
        attrs={"form": "large" if large else "small", "categories": ", ".join(CATEGORIES)})
    ds.to_netcdf(path, engine="h5netcdf")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--large", action="store_true", help="full sizes (10^6 steps, longer runs)")
    ap.add_argument("--cases", nargs="*", help="run only these cases (names as in the table)")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "extremes")
    args = ap.parse_args(argv)
    cases = build_cases(args.large)
    if args.cases:
        unknown = set(args.cases) - {c.name for c in cases}
        if unknown:
            ap.error(f"--cases: unknown {sorted(unknown)}; allowed: {[c.name for c in cases]}")
        cases = [c for c in cases if c.name in args.cases]
    args.out.mkdir(parents=True, exist_ok=True)
    work = args.out / "runs"
    work.mkdir(exist_ok=True)
    outcomes = []
    for case in cases:
        o = run_case(case, work)
        print(f"{o.name:28s} {o.category:17s} {o.seconds:7.1f} s  {o.diagnostic[:150]}", flush=True)
        outcomes.append(o)
    # Save
    text = table(outcomes)
    (args.out / "extremes.md").write_text(text)
    save(outcomes, args.out / "extremes.nc", args.large)
    print(text)
    bad = sum(o.category in ("silent garbage", "hang", "crash") for o in outcomes)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
