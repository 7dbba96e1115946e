"""Why the exact-rigidity solve of slender fibres is slow, and what preconditioners buy.

Question: the exact-rigidity Schur system (fortran/stokes/fold_stokes_rigid.f90,
docs/physics.md#exact-rigidity) needs 2-3x the CG iterations of the penalised solve on
dense fibres. Which eigenmodes make it slow, and which preconditioners remove them at
what cost?

Method: a numpy model of the same operator, (Gamma + C) tau = E on the voxels the
particles touch, Gamma = B A^-1 P B^H with the rotated-difference wavevectors of
fold_stokes_fft (spectral form; the stencil form is the same operator to round-off),
on an unsheared cubic cell, with fold's chi (pyfold.native.stokes.solve_particles). The
model must reproduce fold's own CG count with the point-Jacobi preconditioner of
fold_stokes_rigid; the script prints both. Then, on the same systems:
  * the spectrum of one fibre's block (Jacobi-scaled): null space (self-equilibrated
    stresses), smallest non-zero eigenvalue, number of slow modes, their shape
    (cross-section mean and spread of the axial stress along the fibre) and the part of
    them a per-fibre "beam" coarse space (hat functions along the axis x {1, y, z} across
    it x the 5 stress components) captures;
  * CG iterations to 1e-3 and 1e-6 with: point Jacobi (fold's); blocks of the voxels of
    one fibre grouped into columns along its axis (width 2 voxels); the exact dense block
    of each whole fibre (block Jacobi per body, Balboa Usabiaga et al. 2016); point
    Jacobi plus the beam coarse space (additive two-level, exact per-fibre Galerkin
    coarse matrix);
  * the cost of the whole-fibre blocks: the doubles their factors hold, and the CPU time
    of their factorisation and of one block solve in units of one real FFT of the grid
    (numpy's), both in this run.
Scenes: beta = 10 fibres, 3 voxels per diameter, cell 2.4 L (72^3): one fibre; 55 fibres
(n L^3 = 4) with gaps >= 1, 0.2 and 0.05 R (bench_rigidity_solve.place, seed 1).

Command:  nice -n 5 python benchmarks/bench_rigidity_preconditioners.py [--quick]
          (--quick: the one-fibre spectrum and the 55-fibre 0.2 R scene only)
Cost: --quick ~25 CPU-min, full about 1.5 CPU-hours (the model's numpy transforms are
~5x slower than fold's FFTW ones), ~3 GB of memory for the dense blocks.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
import scipy.linalg as sl

from bench_rigidity_solve import BETA, place
from pyfold.native.stokes import Particles, StokesSettings, solve_particles

CELL, CPD = 2.4, 3
R, LENGTH = 0.5 / BETA, 1.0
#: orthonormal basis of the traceless symmetric tensors: tau = sum_a c_a BASIS[a]
BASIS = np.zeros((5, 3, 3))
BASIS[0] = np.diag([1.0, -1.0, 0.0]) / np.sqrt(2.0)
BASIS[1] = np.diag([1.0, 1.0, -2.0]) / np.sqrt(6.0)
for _a, (_i, _j) in enumerate([(0, 1), (0, 2), (1, 2)]):
    BASIS[2 + _a, _i, _j] = BASIS[2 + _a, _j, _i] = 1.0 / np.sqrt(2.0)
#: simple shear E = sym(G), G = e_x (x) e_y, in the basis
E_RED = np.einsum("ij,aij->a", 0.5 * (np.eye(3)[:, [0]] @ np.eye(3)[[1]] + np.eye(3)[:, [1]] @ np.eye(3)[[0]]), BASIS)
#: fold_stokes_rigid's Jacobi weight: g0 / (g0 + C), g0 = (dim - 1) / (2 eta_f ncg) with eta_f = 1
G0 = 0.2


class GreenOperator:
    """Gamma per Fourier mode (5 x 5) on an n^3 unsheared cube of side CELL, eta_f = 1:
    Gamma_ab = B_a : sym(kv (x) P (B_b kv)) / |kv|^2, kv the rotated-difference
    wavevector of fold_stokes_fft (modes with >= 2 Nyquist indices and k = 0 removed)."""

    def __init__(self, n: int):
        self.n = n
        h = CELL / n
        th = 2 * np.pi * np.arange(n) / n
        thz = th[: n // 2 + 1]
        X, Y, Z = np.meshgrid(np.arange(n), np.arange(n), np.arange(n // 2 + 1), indexing="ij")
        s, c, sz, cz = np.sin(th / 2), np.cos(th / 2), np.sin(thz / 2), np.cos(thz / 2)
        kv = (2 / h) * np.stack([s[X] * c[Y] * cz[Z], c[X] * s[Y] * cz[Z], c[X] * c[Y] * sz[Z]], -1)
        nyq = (2 * X == n).astype(int) + (2 * Y == n) + (2 * Z == n)
        k2 = (kv**2).sum(-1)
        removed = (nyq >= 2) | ((X == 0) & (Y == 0) & (Z == 0)) | (k2 <= 0)
        ik2 = np.where(removed, 0.0, 1.0 / np.where(removed, 1.0, k2))
        kv[removed] = 0.0
        f = np.einsum("bij,...j->...bi", BASIS, kv)
        fp = f - kv[..., None, :] * (np.einsum("...bi,...i->...b", f, kv) * ik2[..., None])[..., None]
        self.hat = np.einsum("aij,...i,...bj->...ab", BASIS, kv, fp * ik2[..., None, None])

    def apply(self, tau: np.ndarray) -> np.ndarray:
        """Strain (5, n, n, n) of the stress field tau (5, n, n, n)."""
        t = np.fft.rfftn(tau, axes=(1, 2, 3))
        return np.fft.irfftn(np.einsum("xyzab,bxyz->axyz", self.hat, t), s=(self.n,) * 3, axes=(1, 2, 3))

    def kernel(self) -> np.ndarray:
        """Gamma in real space, (5, 5, n, n, n): Gamma tau (x) = sum_y kernel(x - y) tau(y)."""
        return np.fft.irfftn(np.moveaxis(self.hat, (3, 4), (0, 1)), s=(self.n,) * 3, axes=(2, 3, 4))


class System:
    """(Gamma + C) tau = E on the touched voxels idx (3, m), compliance comp (m,)."""

    def __init__(self, green: GreenOperator, chi: np.ndarray):
        self.green = green
        self.idx = np.array(np.nonzero(chi > 0))
        c = chi[tuple(self.idx)]
        self.comp = np.where(c >= 0.5, 0.0, (1 - c) / (2 * c))
        self.b = np.tile(E_RED[:, None], (1, self.idx.shape[1]))

    def apply(self, t: np.ndarray) -> np.ndarray:
        f = np.zeros((5,) + (self.green.n,) * 3)
        f[(slice(None),) + tuple(self.idx)] = t
        return self.green.apply(f)[(slice(None),) + tuple(self.idx)] + self.comp * t

    def block(self, kernel: np.ndarray, sel: np.ndarray) -> np.ndarray:
        """The dense block of the voxels sel, ordered (voxel, component)."""
        ids = self.idx[:, sel]
        d = (ids[:, :, None] - ids[:, None, :]) % self.green.n
        m = len(sel)
        M = kernel[:, :, d[0], d[1], d[2]].transpose(2, 0, 3, 1).reshape(5 * m, 5 * m)
        M[np.diag_indices(5 * m)] += np.repeat(self.comp[sel], 5)
        return M


def pcg(system: System, prec, tol: float, maxit: int = 20000) -> int:
    """Iterations of preconditioned CG from zero to ||r|| <= tol ||b|| (fold's rule)."""
    b = system.b
    x, r = np.zeros_like(b), b.copy()
    z = prec(r)
    p, rz, bb = z.copy(), (r * z).sum(), np.sqrt((b * b).sum())
    it = 0
    while np.sqrt((r * r).sum()) > tol * bb and it < maxit:
        it += 1
        q = system.apply(p)
        a = rz / (p * q).sum()
        x += a * p
        r -= a * q
        z = prec(r)
        rz, rz_old = (r * z).sum(), rz
        p = z + (rz / rz_old) * p
    return it


def scene(count: int, gap: float, n: int):
    x, p = place(CELL, count, gap, seed=1)
    P = Particles(x=x, p=p, radius=R, length=LENGTH, shape="fibre")
    sol = solve_particles(P, [CELL] * 3, (n, n, n),
                          settings=StokesSettings(rigidity="exact", tol=1e-3, measure_plans=False, max_iter=20000))
    return x, p, sol.chi, sol.iterations


def body_frames(x, p, idx, n):
    """Per touched voxel: the fibre whose surface is nearest, and the voxel centre's axial
    and transverse coordinates in that fibre's frame."""
    centres = (idx.T + 0.5) * (CELL / n)
    best = np.full(idx.shape[1], np.inf)
    own = np.full(idx.shape[1], -1)
    coords = np.zeros((idx.shape[1], 3))
    for k in range(len(x)):
        d = centres - x[k]
        d -= CELL * np.round(d / CELL)
        s = d @ p[k]
        dist = np.maximum(np.linalg.norm(d - s[:, None] * p[k], axis=1) - R, np.abs(s) - LENGTH / 2)
        a = np.array([1.0, 0, 0]) if abs(p[k][0]) < 0.9 else np.array([0, 1.0, 0])
        e1 = a - (a @ p[k]) * p[k]
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(p[k], e1)
        upd = dist < best
        best[upd], own[upd] = dist[upd], k
        coords[upd] = np.stack([s, d @ e1, d @ e2], 1)[upd]
    return own, coords


def beam_space(coords: np.ndarray, n: int) -> np.ndarray:
    """Orthonormal columns hat_j(s) x {1, y/R, z/R} x unit component, hats every 2 voxels."""
    s, y, z = coords.T
    nodes = np.linspace(-LENGTH / 2, LENGTH / 2, int(round(LENGTH / (2 * CELL / n))) + 1)
    hats = np.clip(1 - np.abs(s[:, None] - nodes[None]) / (nodes[1] - nodes[0]), 0, None)
    cols = []
    for t in (np.ones_like(y), y / R, z / R):
        for j in range(hats.shape[1]):
            for a in range(5):
                col = np.zeros((len(s), 5))
                col[:, a] = hats[:, j] * t
                cols.append(col.reshape(-1))
    q, r = np.linalg.qr(np.array(cols).T)
    return q[:, np.abs(np.diag(r)) > 1e-10 * np.abs(np.diag(r)).max()]


def block_prec(system: System, groups: list[np.ndarray], kernel: np.ndarray):
    facs = []
    for sel in groups:
        M = system.block(kernel, sel)
        M[np.diag_indices(M.shape[0])] += 1e-8 * G0  # the self-equilibrated null space
        facs.append((sel, sl.cho_factor(M)))

    def prec(r):
        z = np.empty_like(r)
        for sel, f in facs:
            z[:, sel] = sl.cho_solve(f, r[:, sel].T.reshape(-1)).reshape(-1, 5).T
        return z

    return prec, facs


def spectrum_of_one_fibre(green: GreenOperator, kernel: np.ndarray, n: int) -> None:
    x, p, chi, fold_its = scene(1, 0.2, n)
    system = System(green, chi)
    print(f"\none fibre: {system.idx.shape[1]} touched voxels ({int((system.comp == 0).sum())} rigid); "
          f"fold CG to 1e-3: {fold_its}, this model: {pcg(system, lambda r: r * (G0 / (G0 + system.comp)), 1e-3)}")
    M = system.block(kernel, np.arange(system.idx.shape[1]))
    w = np.repeat(np.sqrt(G0 / (G0 + system.comp)), 5)
    ev, V = np.linalg.eigh(w[:, None] * M * w[None, :])
    null = int((ev < 1e-10 * ev[-1]).sum())
    rel = ev[null:] / ev[-1]
    print(f"  Jacobi-scaled block: {null} null modes (self-equilibrated stresses), smallest non-zero "
          f"eigenvalue {rel[0]:.2e} of the largest; modes below 1e-3 / 1e-2 / 3e-2 / 0.1 of it: "
          + " / ".join(str(int((rel < t).sum())) for t in (1e-3, 1e-2, 3e-2, 0.1)))
    own, coords = body_frames(x, p, system.idx, n)
    Z = beam_space(coords, n)
    slow = V[:, null:null + 20]
    captured = np.mean(np.linalg.norm(Z.T @ slow, axis=0) ** 2)
    h = CELL / n
    pp = np.einsum("i,aij,j->a", p[0], BASIS, p[0])  # axial-axial component of each basis tensor
    axial = np.einsum("ma,a->m", slow[:, 0].reshape(-1, 5), pp)
    slices = np.floor((coords[:, 0] + LENGTH / 2) / h).astype(int)
    means = np.array([axial[slices == j].mean() for j in np.unique(slices)])
    spreads = np.array([axial[slices == j].std() for j in np.unique(slices)])
    print(f"  the 20 slowest modes: {captured:.0%} of their norm in the beam coarse space ({Z.shape[1]} columns); "
          f"slowest mode's axial stress per voxel slice along the fibre: |mean| <= {np.abs(means).max():.3f}, "
          f"spread up to {spreads.max():.3f} (norm 1): tension varying across the section, smooth along the axis")


def preconditioners(green: GreenOperator, kernel: np.ndarray, n: int, count: int, gap: float) -> None:
    x, p, chi, fold_its = scene(count, gap, n)
    system = System(green, chi)
    own, coords = body_frames(x, p, system.idx, n)
    jacobi = lambda r: r * (G0 / (G0 + system.comp))  # noqa: E731
    model_its = pcg(system, jacobi, 1e-3)
    print(f"\n{count} fibre(s), gap >= {gap} R: {system.idx.shape[1]} touched voxels; fold CG to 1e-3: {fold_its}, "
          f"this model: {model_its}")
    h = CELL / n
    rows = [("point Jacobi (fold_stokes_rigid)", jacobi, None)]
    columns = []
    for k in range(count):
        sel = np.nonzero(own == k)[0]
        key = np.round(coords[sel, 1] / (2 * h)).astype(int) * 1000 + np.round(coords[sel, 2] / (2 * h)).astype(int)
        columns += [sel[key == c] for c in np.unique(key)]
    rows.append(("columns along each fibre, 2 voxels wide", *block_prec(system, columns, kernel)))
    t0 = time.process_time()
    bodies = [np.nonzero(own == k)[0] for k in range(count)]
    body_prec, facs = block_prec(system, bodies, kernel)
    t_fac = time.process_time() - t0
    rows.append(("whole-fibre dense blocks (block Jacobi per body)", body_prec, facs))
    coarse = []
    for sel in bodies:
        Z = beam_space(coords[sel], n)
        ew, U = np.linalg.eigh(Z.T @ system.block(kernel, sel) @ Z)
        keep = ew > 1e-9 * ew.max()
        coarse.append((sel, Z @ U[:, keep], 1.0 / ew[keep]))

    def two_level(r):
        z = jacobi(r)
        for sel, Zc, iw in coarse:
            z[:, sel] += (Zc @ (iw * (Zc.T @ r[:, sel].T.reshape(-1)))).reshape(-1, 5).T
        return z

    rows.append(("point Jacobi + beam coarse space (additive)", two_level, None))
    for name, prec, _ in rows:
        print(f"  {name:<52} CG to 1e-3 / 1e-6: {pcg(system, prec, 1e-3):>5d} / {pcg(system, prec, 1e-6):>5d}",
              flush=True)
    r = system.b.copy()
    field = np.random.default_rng(0).normal(size=(n,) * 3)
    t0 = time.process_time()
    for _ in range(5):
        np.fft.irfftn(np.fft.rfftn(field), s=field.shape)
    t_op = (time.process_time() - t0) / 10  # one real FFT of the grid (numpy's)
    t0 = time.process_time()
    for _ in range(3):
        body_prec(r)
    t_blk = (time.process_time() - t0) / 3
    doubles = sum((5 * len(s)) ** 2 for s in bodies)
    print(f"  whole-fibre blocks: {doubles / 1e6:.0f} M doubles ({8 * doubles / 2**30:.2f} GiB) of factors, "
          f"factorised in {t_fac:.1f} CPU-s = {t_fac / t_op:.0f} FFT-equivalents; one block solve "
          f"{t_blk / t_op:.1f} FFT-equivalents (one real FFT of the grid with numpy's FFT, which is slower than "
          f"FFTW: against fold's unit these are lower bounds; a CG iteration of fold is 11-14)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one-fibre spectrum and the 0.2 R scene only")
    args = ap.parse_args()
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    n = int(round(CELL * BETA * CPD))
    green = GreenOperator(n)
    kernel = green.kernel()
    spectrum_of_one_fibre(green, kernel, n)
    for count, gap in [(55, 0.2)] if args.quick else [(1, 0.2), (55, 1.0), (55, 0.2), (55, 0.05)]:
        preconditioners(green, kernel, n, count, gap)
    print(f"\nload average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
