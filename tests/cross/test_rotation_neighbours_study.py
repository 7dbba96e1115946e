"""The seed's hydrodynamic-interaction study (studies/seed_examples/rotation_neighbours.py) in
its smallest form: its placement meets every constraint, its quadrature is exact on a Jeffery
orbit, a sphere alone in a cubic cell spins at gamma_dot/2, and a tiny run writes a dataset
that xarray reads back.

Tolerances: the placement constraints are checked to round-off of the cell coordinates
(16 eps * cell); the quadrature to n eps of the sum of n positive terms; the spin to
kappa * tol relative (tests/micro/test_cylinder_period.py: with the Green-operator
preconditioner each CG rate carries a relative error of at most kappa * tol). The spin is
exactly gamma_dot/2 in the discrete problem: the voxelised sphere at a voxel corner and its
images keep the cubic point group with inversion, whose only invariant third-rank
pseudo-tensor is epsilon_ijk, so the symmetric rate of strain drives no rotation.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from study_import import import_study  # helper module next to this file

EPS = np.finfo(float).eps


@pytest.fixture(scope="module")
def study():
    return import_study("seed_examples", "rotation_neighbours")


@pytest.mark.parametrize("phi, cell, fibre", [(0.3, 5.0, False), (0.2, 8.0, True)])
def test_placement_keeps_every_gap(study, phi, cell, fibre):
    n = study.n_spheres(phi, cell)
    centre = np.full(3, cell / 2)
    x = study.place_spheres(np.random.default_rng(7), n, cell, fibre_centre=centre if fibre else None,
                            clearance=study.FIBRE_CLEARANCE)
    assert x.shape == (n, 3) and np.all((x >= 0) & (x < cell))
    tol = 16 * EPS * cell
    dx = study._min_image(x[:, None] - x[None], cell)
    dist = np.linalg.norm(dx, axis=-1)[np.triu_indices(n, 1)]
    assert dist.min() >= 1 + study.GAP - tol
    if fibre:
        _, bad = study.swept_disc_push(x, centre, cell, 0.5 + study.FIBRE_CLEARANCE - tol)
        assert not bad


@pytest.mark.parametrize("nphi", [8, 16])
def test_half_orbit_rule_is_exact_on_a_jeffery_orbit(study, nphi):
    b = float(study.equivalent_aspect_ratio(study.BETA, "harris_pittman"))
    theta, w = study.jeffery_half_nodes(nphi, b)
    omega = -study.SHEAR_RATE * (b**2 * np.sin(theta) ** 2 + np.cos(theta) ** 2) / (b**2 + 1)
    exact = 2 * math.pi / study.SHEAR_RATE * (b + 1 / b)
    assert abs(study.period(omega, w) - exact) <= 4 * nphi * EPS * exact
    assert float(study.beta_from_period(exact)) == pytest.approx(b, rel=16 * EPS * b**2 / (b**2 - 1))


def test_tiny_run_writes_a_dataset_and_a_lone_sphere_spins_at_half_the_shear_rate(study, tmp_path):
    import xarray as xr

    form = study.Form(vpd=(4, 6), seeds=2, nphi=8, single_cells=(2.0,), sphere_phis=(0.2,), fibre_phis=(0.1,))
    raw = study.run(form, log=lambda *a, **k: None)
    corner = raw.single_spin.sel(position=0).values
    assert np.all(np.abs(corner - 1) <= study.KAPPA * study.TOL)
    ds, table = study.analyse(raw)
    path = tmp_path / "rotation_neighbours.nc"
    ds.to_netcdf(path, engine="h5netcdf")
    with xr.open_dataset(path, engine="h5netcdf") as back:
        assert back.sphere_omega.sizes == {"phi": 1, "seed": 2, "vpd": 2, "sphere": study.n_spheres(0.2, 5.0), "xyz": 3}
        f = back.fibre_frequency.values
        assert np.all(f >= 0) and np.all((f == 0) == (back.fibre_stalled.values == 1))
        T1 = back.fibre_single_period.values
        assert np.all(np.isfinite(T1) & (T1 > 0))
    assert "Fibre among frozen neighbour spheres" in table
