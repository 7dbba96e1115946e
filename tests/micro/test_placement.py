"""Seeded random placement (fold_placement): no overlap beyond alpha, target fractions reached, orientations honoured."""
import numpy as np
import pytest

from pyfold.errors import InputError
from pyfold.native import geometry as geo


def all_gaps(cell, pl, shape, radius, length):
    """Surface gaps of every pair (capsule model, minimum image), by the validated segment kernel."""
    n = len(shape)
    i, j = np.triu_indices(n, 1)
    h = np.where(shape == geo.FIBRE, 0.5 * length, np.where(shape == geo.SPHEROID, 0.5 * length - radius, 0.0))
    r = geo.min_image(pl.x[i] - pl.x[j], cell)
    return geo.capsule_contact(r, pl.p[i], h[i], radius[i], pl.p[j], h[j], radius[j])["dist"]


def seed_disks(walls):
    # the seed's sphere example: cell 1.5 x 1, R = 0.075, phi = 50 %, alpha = 0.005
    cell = geo.Cell((1.5, 1.0), walls=walls, shear_rate=1.0)
    n = int(round(0.5 * 1.5 / (np.pi * 0.075**2)))
    return cell, np.full(n, geo.SPHERE), np.full(n, 0.075), np.full(n, 0.15)


@pytest.mark.parametrize("walls", [True, False])
def test_seed_disks_at_50_percent_are_placed_without_overlap(walls):
    cell, shape, radius, length = seed_disks(walls)
    pl = geo.place_particles(cell, shape, radius, length, alpha=0.005, seed=11)
    phi = len(shape) * np.pi * 0.075**2 / 1.5
    assert phi == pytest.approx(0.5, abs=0.01)
    assert np.all(all_gaps(cell, pl, shape, radius, length) >= 0.005 - 1e-12)
    if walls:
        assert np.all(pl.x[:, 1] - 0.075 >= 0.0025 - 1e-12) and np.all(1.0 - pl.x[:, 1] - 0.075 >= 0.0025 - 1e-12)
    # random sequential addition alone cannot get there (jams near 0.547, slowly):
    # the relaxation sweeps did the rest
    assert pl.n_rsa < len(shape) and pl.relax_sweeps > 0


def test_pure_rsa_reports_the_fraction_it_reached():
    cell, shape, radius, length = seed_disks(True)
    with pytest.raises(InputError, match=r"could not reach volume fraction 0\.4948: random sequential addition reached 0\.4"):
        geo.place_particles(cell, shape, radius, length, alpha=0.005, seed=11, relax_sweeps=0)


def test_impossible_fraction_is_an_input_error():
    cell = geo.Cell((1.0, 1.0))
    n = 60  # phi = 0.94 of disks: above hexagonal close packing (0.907)
    with pytest.raises(InputError, match=r"could not reach volume fraction 0\.94"):
        geo.place_particles(cell, np.full(n, geo.SPHERE), np.full(n, 0.0707), np.full(n, 0.1414),
                            alpha=0.0, seed=1, max_attempts=50, relax_sweeps=50)


def test_placement_is_reproducible_from_the_seed():
    cell, shape, radius, length = seed_disks(False)
    a = geo.place_particles(cell, shape, radius, length, alpha=0.005, seed=5)
    b = geo.place_particles(cell, shape, radius, length, alpha=0.005, seed=5)
    c = geo.place_particles(cell, shape, radius, length, alpha=0.005, seed=6)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.p, b.p)
    assert not np.allclose(a.x, c.x)


def test_3d_spheres_at_38_percent():
    cell = geo.Cell((1.0, 1.0, 1.0), shear_rate=1.0)
    radius = 0.08
    n = int(0.38 / (4 / 3 * np.pi * radius**3))
    shape, rad, length = np.full(n, geo.SPHERE), np.full(n, radius), np.full(n, 2 * radius)
    pl = geo.place_particles(cell, shape, rad, length, alpha=0.004, seed=3)
    assert n * 4 / 3 * np.pi * radius**3 >= 0.375
    assert np.all(all_gaps(cell, pl, shape, rad, length) >= 0.004 - 1e-12)


@pytest.mark.parametrize("orientation", ["isotropic", "planar", "aligned"])
def test_concentrated_fibres_honour_the_orientation_distribution(orientation):
    # beta = L/d = 10, n L^3 = 15 > L/d (concentrated regime): phi = n pi R^2 L = 0.118
    L, R = 0.5, 0.025
    cell = geo.Cell((1.5, 1.5, 1.5), shear_rate=1.0)
    n = int(15 * 1.5**3 / L**3)
    shape, rad, length = np.full(n, geo.FIBRE), np.full(n, R), np.full(n, L)
    axis = [1.0, 0.0, 0.0] if orientation == "aligned" else None
    pl = geo.place_particles(cell, shape, rad, length, alpha=0.002, seed=2, orientation=orientation, axis=axis)
    assert np.all(all_gaps(cell, pl, shape, rad, length) >= 0.002 - 1e-12)
    np.testing.assert_allclose(np.linalg.norm(pl.p, axis=1), 1.0, atol=1e-14)
    a2 = pl.p.T @ pl.p / n
    if orientation == "isotropic":
        np.testing.assert_allclose(a2, np.eye(3) / 3, atol=0.06)
    elif orientation == "planar":  # uniform in the x-y plane (default normal e_z)
        np.testing.assert_allclose(pl.p[:, 2], 0.0, atol=1e-15)
        np.testing.assert_allclose(a2, np.diag([0.5, 0.5, 0.0]), atol=0.06)
    else:
        np.testing.assert_array_equal(pl.p, np.tile([1.0, 0.0, 0.0], (n, 1)))


def test_mixed_families_of_fibres_spheroids_and_spheres_in_2d():
    cell = geo.Cell((2.0, 2.0), walls=True, shear_rate=1.0)
    shape = np.array([geo.FIBRE] * 40 + [geo.SPHEROID] * 30 + [geo.SPHERE] * 60)
    radius = np.array([0.02] * 40 + [0.04] * 30 + [0.05] * 60)
    length = np.array([0.4] * 40 + [0.24] * 30 + [0.1] * 60)
    pl = geo.place_particles(cell, shape, radius, length, alpha=0.003, seed=9)
    assert np.all(all_gaps(cell, pl, shape, radius, length) >= 0.003 - 1e-12)
