"""Exact-rigidity Stokes solve (numerics.stokes.rigidity = "exact") against results it
must reproduce: the penalised solve's kappa -> infinity extrapolation, Einstein's
viscosity and the dilute simple-cubic array (docs/rheology.md).

* Random spheres at phi = 0.1 on a binary chi (every voxel empty or full): there the
  penalised solve is the Tikhonov regularisation of the exact one
  (tests/micro/test_stokes_exact.py), eta_kappa = eta_exact - g(e), e = 1/(kappa - 1),
  g(e) = sum_i a_i e / (s_i + e) with a_i, s_i > 0: increasing and concave in e, g(0) = 0.
  The Richardson extrapolation in 1/kappa through kappa = 1e4 and 1e5 is the chord of g
  extended to e = 0, which a concave g lies below: the extrapolation never exceeds the
  exact value, and in the first-order regime (g = a e - b e^2 + ...) it misses it by
  b e4 e5, a fraction ~ e5 of the observed difference eta_1e5 - eta_1e4: the observed
  difference bounds the error.
* Einstein and the simple-cubic array: one sphere per periodic cube; the reference is
  the point-stresslet lattice sum of studies/rheology/sphere_viscosity.py,
  (eta - 1)/phi = 2.5 - 12.5 q phi + O(phi^(5/3)). The exact solve makes the voxels
  covered at least half rigid, so its voxelised sphere has a surface error O(h) and its
  intrinsic viscosity approaches the limit at first order in the voxel size h, from
  above. The test extrapolates linearly in h from the two pairs of three grids
  (32/48/64^3) and bounds the error of the finer pair's extrapolation by the difference
  of the two (the higher-order remainder, larger at the coarser pair). At 4-12 voxels per
  radius the voxel set jumps with the grid and the two extrapolations differ by 8-14 % of
  the value: a loose bound, and what the data support.
"""
from __future__ import annotations

import numpy as np
import pytest

from pyfold.native.stokes import Particles, solve_chi, solve_particles
from test_rheology_sc_array import _study
from test_run_common import stokes_settings

SHEAR = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
GRIDS = (32, 48, 64)


@pytest.fixture(scope="module")
def lattice_sums():
    return _study().sc_lattice_sums()


def _random_spheres_chi(n: int, count: int, phi: float, seed: int) -> np.ndarray:
    """Binary chi of ``count`` equal spheres of total volume fraction ``phi`` at random in
    the unit periodic cube (voxel centres inside a sphere are solid), at least two voxels
    apart so the bodies stay separate on the grid."""
    R = (3 * phi / (4 * np.pi * count)) ** (1 / 3)
    rng = np.random.default_rng(seed)
    centres: list[np.ndarray] = []
    while len(centres) < count:
        c = rng.uniform(0.0, 1.0, 3)
        if all(np.linalg.norm((c - x) - np.round(c - x)) >= 2 * R + 2.0 / n for x in centres):
            centres.append(c)
    g = (np.arange(n) + 0.5) / n
    X = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1)
    chi = np.zeros((n, n, n))
    for c in centres:
        d = X - c
        d -= np.round(d)
        chi[(d**2).sum(axis=-1) <= R * R] = 1.0
    return chi


def test_random_spheres_exact_viscosity_is_the_penalised_kappa_to_infinity_extrapolation():
    # 8 spheres of radius 0.134 (4.3 voxels) on 32^3, the grid of tests/micro/test_stokes.py
    chi = _random_spheres_chi(32, 8, 0.1, seed=3)
    assert chi.mean() == pytest.approx(0.1, rel=0.15)
    exact = solve_chi(chi, np.eye(3), SHEAR, stokes_settings(rigidity="exact", tol=1e-12)).eta_eff
    eta = {k: solve_chi(chi, np.eye(3), SHEAR, stokes_settings(kappa=k, tol=1e-12, max_iter=100000)).eta_eff
           for k in (1e3, 1e4, 1e5)}
    # solver error of a penalised eta: <= (kappa - 1)(tol + eps_op) of the particles' part
    # (fold_stokes_trust), ~1e-7 of it at kappa 1e5: the margin of the one-sided checks
    slack = 1e-6 * (exact - 1.0)
    assert eta[1e3] < eta[1e4] < eta[1e5] < exact + slack
    e4, e5 = 1 / (1e4 - 1), 1 / (1e5 - 1)
    observed = eta[1e5] - eta[1e4]
    extrapolated = eta[1e5] + observed * e5 / (e4 - e5)
    assert extrapolated <= exact + slack  # the chord of a concave gap lies above it
    assert exact - extrapolated <= observed  # first-order regime: the difference bounds the error
    # and the gap of kappa = 1e3 (the default) is at most (1e4 - 1)/(1e3 - 1) times the 1e4 one
    assert exact - eta[1e3] <= (1e4 - 1) / (1e3 - 1) * (exact - eta[1e4]) + slack


def _richardson_first_order(values: list[float], grids=GRIDS) -> tuple[float, float]:
    """Extrapolations to h = 0 (value linear in h = 1/n) from the coarser and the finer
    pair of grids."""
    (a, b, c), (n1, n2, n3) = values, grids
    return (n2 * b - n1 * a) / (n2 - n1), (n3 * c - n2 * b) / (n3 - n2)


def _sphere_cell(phi: float, centre) -> list[tuple[float, float]]:
    """(eta_face, eta_diag) of one sphere per unit cube, exact rigidity, on each grid."""
    R = (3 * phi / (4 * np.pi)) ** (1 / 3)
    P = Particles(x=[centre], p=[[1.0, 0.0, 0.0]], radius=R, length=2 * R, shape="sphere")
    s = stokes_settings(rigidity="exact", tol=1e-8)
    out = []
    for n in GRIDS:
        face = solve_particles(P, [1, 1, 1], (n, n, n), settings=s)
        diag = solve_chi(face.chi, np.eye(3), np.diag([0.5, -0.5, 0.0]), s)
        out.append((face.eta_eff, diag.eta_eff))
    return out


@pytest.fixture(scope="module")
def dilute_sphere():
    # radius 1/8 (4, 6, 8 voxels), off-centre as in tests/micro/test_stokes.py: phi = 0.82 %
    phi = 4 / 3 * np.pi * 0.125**3
    return phi, _sphere_cell(phi, [0.5, 0.3, 0.45])


@pytest.fixture(scope="module")
def sc_array():
    # phi = 0.03 as in tests/micro/test_rheology_sc_array.py (R = 0.193: 6.2, 9.3, 12.3 voxels)
    return 0.03, _sphere_cell(0.03, [0.5, 0.5, 0.5])


def _check_against_lattice_sum(phi, etas, q, column):
    intrinsic = [(e[column] - 1.0) / phi for e in etas]
    reference = 2.5 - 12.5 * q * phi
    coarse, fine = _richardson_first_order(intrinsic)
    # truncation of the lattice sum: the next terms, taken as relative O(phi^(2/3)) of the
    # phi^2 one (tests/micro/test_rheology_sc_array.py)
    truncation = phi ** (2 / 3) * 12.5 * abs(q) * phi
    assert abs(fine - reference) <= abs(fine - coarse) + truncation, (intrinsic, coarse, fine, reference)
    return intrinsic, fine


def test_dilute_sphere_intrinsic_viscosity_extrapolates_to_einstein(dilute_sphere, lattice_sums):
    phi, etas = dilute_sphere
    intrinsic, fine = _check_against_lattice_sum(phi, etas, lattice_sums[0], column=0)
    # from above and falling: the voxels covered at least half make the rigid body larger
    assert intrinsic[0] > intrinsic[1] > intrinsic[2] > fine


def test_sc_array_exact_viscosities_extrapolate_to_the_point_stresslet_lattice_sum(sc_array, lattice_sums):
    phi, etas = sc_array
    for column, q in enumerate(lattice_sums):
        _check_against_lattice_sum(phi, etas, q, column)


def test_sc_array_exact_anisotropy_is_the_lattice_sums(sc_array, lattice_sums):
    # The anisotropy is the phi^2 interaction of each sphere's stresslet with its images'
    # strain, both proportional to the stresslet: a grid whose single-sphere stresslet is
    # too large by delta (the face viscosity's relative excess over the lattice sum on the
    # same grid) makes it too large by (1 + delta)^2 - 1, plus the truncation bound of
    # tests/micro/test_rheology_sc_array.py (0.10).
    phi, etas = sc_array
    q_face, q_diag = lattice_sums
    for face, diag in etas:
        delta = abs((face - 1) / phi / (2.5 - 12.5 * q_face * phi) - 1)
        bound = (1 + delta) ** 2 - 1 + 0.10
        assert (diag - face) / phi**2 == pytest.approx(12.5 * (q_face - q_diag), rel=bound), (face, diag, bound)
