"""The voxeliser's χ against a brute-force evaluation of its definition.

fortran/grid/fold_voxelise.f90 defines the coverage of a voxel by a particle as the mean over
S³ sub-points of the smooth step H(1/2 − φ/w) of the signed distance φ (w = h/S), and for a
fibre voxelised at s R with its added shell kept the security zone g apart from the other
particles, as the mean of H(1/2 − φ_g/w) + own (H(1/2 − φ_s/w) − H(1/2 − φ_g/w)) with
own = H(1/2 + (min_j φ_j − φ_g − g)/w) (φ_g, φ_s the signed distances at the geometric and
the scaled radius, φ_j the other particles' geometric ones); χ is the sum over the particles,
clipped at 1. The voxeliser evaluates this only where it can differ from 0 or 1 (a particle's
box, the rows and voxels near its surface, the sub-points in its shell, the neighbours that
can be the nearest): every such skip must leave χ unchanged. Here the definition is evaluated
at every sub-point of every voxel for every particle, in numpy, on a dense set of fibres with
near pairs whose shells would overlap, and compared with the χ the solver voxelises.

Tolerance: the two evaluations differ only by round-off in the sub-point positions and the
distances, |Δφ| ≤ c u ℓ with u the unit round-off, ℓ the cell length and c a small count of
operations (16 here, generous for a handful of products and sums); H has slope ≤ 15/8, and
a sub-point's coverage carries three such terms, so each voxel's χ differs by at most
3 (15/8) c u ℓ / w.
"""
from __future__ import annotations

import numpy as np
import pytest

CELL, N, S = 2.7, 36, 3  # cubic cell [m], voxels per side, sub-points per voxel edge
R, L = 0.1, 1.0  # β = 5 fibres
SCALE, GAP = 1.3, 0.02  # a shell of 0.3 R: two fibres nearer than 0.06 overlap with "overlap"


def _fibres():
    """Eight fibres: two parallel pairs and a crossing pair at surface gaps below 2 (s − 1) R
    (their shells meet), and two fibres alone, one across the periodic boundary."""
    x = np.array([[0.9, 0.9, 0.9], [0.9, 0.9 + 2 * R + 0.03, 0.9],             # pair along x, gap 0.03 in y
                  [1.9, 0.6, 1.7], [1.9, 0.6, 1.7 + 2 * R + 0.045],             # pair along y, gap 0.045 in z
                  [1.0, 2.0, 2.1], [1.0, 2.0 + 2 * R + 0.035, 2.1],             # crossing: x against z
                  [2.2, 1.6, 0.4], [2.6, 2.3, 2.5]])                            # alone; across the boundary
    p = np.array([[1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1],
                  [1, 1, 1], [1, -2, 0.5]], dtype=float)
    return x, p / np.linalg.norm(p, axis=1)[:, None]


def _h(t):
    c = np.clip(t, 0.0, 1.0)
    return c ** 3 * (10.0 + c * (-15.0 + 6.0 * c))


def _flat_cylinder_distance(d, p, radius):
    """Exact signed distance of the points d (..., 3) from a flat-ended cylinder of axis p,
    centred at the origin."""
    z = d @ p
    a = np.abs(z) - 0.5 * L
    b = np.sqrt(np.maximum(0.0, np.einsum("...i,...i", d, d) - z * z)) - radius
    return np.minimum(np.maximum(a, b), 0.0) + np.hypot(np.maximum(a, 0.0), np.maximum(b, 0.0))


def _reference_chi(x, p, shells):
    h, w = CELL / N, CELL / (N * S)
    s1 = (np.arange(N * S) + 0.5) * w  # sub-point coordinates along an axis
    pts = np.stack(np.meshgrid(s1, s1, s1, indexing="ij"), axis=-1)
    geo, scaled = [], []
    for xk, pk in zip(x, p):
        d = pts - xk
        d -= CELL * np.round(d / CELL)  # minimum image: the cell is over 2 (L + 2 R) wide
        geo.append(_flat_cylinder_distance(d, pk, R))
        scaled.append(_flat_cylinder_distance(d, pk, SCALE * R))
    total = np.zeros((N * S,) * 3)
    for k in range(len(x)):
        hg, hs = _h(0.5 - geo[k] / w), _h(0.5 - scaled[k] / w)
        if shells == "apart":
            nearest = np.min([geo[j] for j in range(len(x)) if j != k], axis=0)
            own = _h(0.5 + (nearest - geo[k] - GAP) / w)
            total += hg + own * (hs - hg)
        else:
            total += hs
    return np.minimum(total.reshape(N, S, N, S, N, S).mean(axis=(1, 3, 5)), 1.0), h, w


@pytest.mark.parametrize("shells", ["overlap", "apart"])
def test_the_voxelised_chi_is_its_definition_at_every_sub_point(shells):
    from pyfold.native.stokes import Particles, StokesSettings, solve_particles

    x, p = _fibres()
    part = Particles(x=x, p=p, radius=np.full(len(x), R), length=np.full(len(x), L), shape=["fibre"] * len(x))
    sol = solve_particles(part, [CELL] * 3, [N] * 3, alpha=GAP,
                          settings=StokesSettings(tol=1e-2, subsamples=S, fibre_ends="flat", fibre_radius_scale=SCALE,
                                                  fibre_shells=shells, measure_plans=False))
    ref, h, w = _reference_chi(x, p, shells)
    bound = 3 * (15 / 8) * 16 * np.finfo(float).eps / 2 * CELL / w
    assert np.max(np.abs(sol.chi - ref)) <= bound
    # the configuration exercises what it is meant to: shells that meet, voxels partly covered
    assert np.count_nonzero((ref > 0) & (ref < 1)) > 1000
    if shells == "apart":
        overlap, _, _ = _reference_chi(x, p, "overlap")
        assert overlap.sum() - ref.sum() > 1.0  # the near pairs' shells yielded, by voxels' worth
