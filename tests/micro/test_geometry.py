"""Fortran cell, segment distance, cell lists and Jeffery kinematics against brute force and exact results."""
import itertools

import numpy as np
import pytest
from scipy.linalg import expm

from pyfold.errors import InputError, checked
from pyfold.native import geometry as geo


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# --------------------------------------------------------------------------- cell
def brute_min_image(dx, cell):
    """Shortest image: every row n_y (and layer n_z) of the sheared lattice within reach,
    each with its nearest x image (for fixed n_y, n_z the x shift is a plain rounding)."""
    lx, ly = cell.lengths[0], cell.lengths[1]
    reach_y = int(np.abs(dx[:, 1]).max() / ly) + 2
    rows = [0] if cell.walls else range(-reach_y, reach_y + 1)
    if cell.dim == 3:
        reach_z = int(np.abs(dx[:, 2]).max() / cell.lengths[2]) + 2
        layers = range(-reach_z, reach_z + 1)
    else:
        layers = [0]
    best = None
    for ny, nz in itertools.product(rows, layers):
        trial = dx.copy()
        trial[:, 0] -= ny * cell.shear_offset
        trial[:, 1] -= ny * ly
        if cell.dim == 3:
            trial[:, 2] -= nz * cell.lengths[2]
        trial[:, 0] -= lx * np.round(trial[:, 0] / lx)
        if best is None:
            best = trial
        else:
            closer = np.linalg.norm(trial, axis=1) < np.linalg.norm(best, axis=1)
            best[closer] = trial[closer]
    return best


@pytest.mark.parametrize("dim,walls,offset", [(2, False, 0.0), (2, False, -0.75), (2, False, 0.41),
                                               (3, False, 0.33), (3, True, 0.0), (2, True, 0.0)])
def test_min_image_is_the_shortest_lattice_image(dim, walls, offset):
    cell = geo.Cell((1.5, 1.0, 1.2)[:dim], walls=walls, shear_rate=1.0, shear_offset=offset)
    dx = np.random.default_rng(1).uniform(-3, 3, size=(2000, dim))
    if walls:
        dx[:, 1] = np.clip(dx[:, 1], -0.99, 0.99)
    got = geo.min_image(dx, cell)
    ref = brute_min_image(dx, cell)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), np.linalg.norm(ref, axis=1), rtol=0, atol=1e-12)


def test_wrap_applies_the_lees_edwards_velocity_jump():
    # a particle leaving through the top face re-enters at the bottom shifted by -s and
    # slowed by gamma_dot*Ly: its velocity relative to the local mean flow is unchanged
    cell = geo.Cell((1.5, 1.0), shear_rate=2.0, shear_offset=0.3)
    x = np.array([[0.2, 1.1], [1.4, -0.05], [3.2, 0.5], [0.5, 2.3]])
    v = np.array([[0.5, 0.1], [0.0, -0.2], [0.1, 0.0], [0.3, 0.0]])
    xw, vw = geo.wrap(x, v, cell)
    assert np.all((xw >= 0) & (xw < np.array(cell.lengths)))
    ny = np.floor(x[:, 1] / 1.0)
    np.testing.assert_allclose(vw[:, 0], v[:, 0] - ny * 2.0 * 1.0, atol=1e-14)
    # wrapped and original positions are the same point of the sheared lattice
    np.testing.assert_allclose(geo.min_image(xw - x, cell), 0.0, atol=1e-13)
    u = lambda pos: np.stack([cell.shear_rate * (pos[:, 1] - 0.5), np.zeros(len(pos))], axis=1)
    np.testing.assert_allclose(vw - u(xw), v - u(x), atol=1e-13)


def test_cell_rejects_a_non_shear_gradient():
    # a non-deforming periodic cell cannot host an elongational mean flow
    v, om, stat, msg = geo._ext().fold_geo_jeffery(np.ones(3), 0, np.diag([1.0, -1.0, 0.0]),
                                                   np.asfortranarray([[0.5], [0.5]]),
                                                   np.asfortranarray([[1.0], [0.0]]), np.array([0.5]))
    with pytest.raises(InputError, match="simple shear"):
        checked(stat, msg)


# ------------------------------------------------------------------ segment distance
def brute_segment_distance(r, p1, h1, p2, h2, m=41):
    """Two-stage grid search of min |r + s p1 - t p2| over the rectangle (vectorised over pairs)."""
    n = len(r)

    def search(s_lo, s_hi, t_lo, t_hi):
        s = s_lo[:, None] + (s_hi - s_lo)[:, None] * np.linspace(0, 1, m)[None, :]
        t = t_lo[:, None] + (t_hi - t_lo)[:, None] * np.linspace(0, 1, m)[None, :]
        d = (r[:, None, None, :] + s[:, :, None, None] * p1[:, None, None, :]
             - t[:, None, :, None] * p2[:, None, None, :])
        dist = np.linalg.norm(d, axis=-1).reshape(n, -1)
        k = np.argmin(dist, axis=1)
        return dist[np.arange(n), k], s[np.arange(n), k // m], t[np.arange(n), k % m]

    d1, s1, t1 = search(-h1, h1, -h2, h2)
    ds, dt = 2 * h1 / (m - 1), 2 * h2 / (m - 1)
    d2, _, _ = search(np.maximum(s1 - ds, -h1), np.minimum(s1 + ds, h1),
                      np.maximum(t1 - dt, -h2), np.minimum(t1 + dt, h2))
    return np.minimum(d1, d2)


def segment_cases(rng, n, dim):
    r = rng.uniform(-1.5, 1.5, size=(n, dim))
    p1 = unit(rng.normal(size=(n, dim)))
    p2 = unit(rng.normal(size=(n, dim)))
    h1 = rng.uniform(0.0, 1.0, n)
    h2 = rng.uniform(0.0, 1.0, n)
    h1[: n // 10] = 0.0  # point-segment (sphere-fibre) and point-point
    h2[n // 20: n // 10] = 0.0
    k = n // 10
    # exactly parallel / antiparallel, overlapping or not
    p2[k: 2 * k] = p1[k: 2 * k] * np.where(rng.uniform(size=(k, 1)) < 0.5, 1.0, -1.0)
    # nearly parallel (angles 1e-9 .. 1e-4 rad)
    ang = 10.0 ** rng.uniform(-9, -4, k)
    q = unit(rng.normal(size=(k, dim)))
    q = unit(q - np.sum(q * p1[2 * k: 3 * k], axis=1, keepdims=True) * p1[2 * k: 3 * k])
    p2[2 * k: 3 * k] = np.cos(ang)[:, None] * p1[2 * k: 3 * k] + np.sin(ang)[:, None] * q
    # collinear segments apart along their axis: the closest points are two ends
    gap = rng.uniform(0.01, 0.5, k)
    sgn = np.where(rng.uniform(size=k) < 0.5, 1.0, -1.0)
    p2[3 * k: 4 * k] = p1[3 * k: 4 * k] * sgn[:, None]
    r[3 * k: 4 * k] = p1[3 * k: 4 * k] * (h1[3 * k: 4 * k] + h2[3 * k: 4 * k] + gap)[:, None]
    # ends facing each other off-axis (end-end with a lateral offset)
    r[4 * k: 5 * k] = (p1[4 * k: 5 * k] * (h1[4 * k: 5 * k] + 0.3)[:, None]
                       + 0.05 * unit(rng.normal(size=(k, dim))))
    p2[4 * k: 5 * k] = unit(p1[4 * k: 5 * k] + 0.3 * rng.normal(size=(k, dim)))
    r[4 * k: 5 * k] += p2[4 * k: 5 * k] * h2[4 * k: 5 * k, None]
    return r, p1, h1, p2, h2


@pytest.mark.parametrize("dim,n", [(3, 2000), (2, 2000)])
def test_segment_distance_matches_brute_force_sampling(dim, n):
    m = 41
    r, p1, h1, p2, h2 = segment_cases(np.random.default_rng(7 + dim), n, dim)
    out = geo.capsule_contact(r, p1, h1, 0.0, p2, h2, 0.0)
    s, t, dist = out["s"], out["t"], out["dist"]
    d_ref = brute_segment_distance(r, p1, h1, p2, h2, m)
    # the kernel never loses to any of the ~3400 sampled point pairs ...
    assert np.all(dist <= d_ref + 1e-12)
    # ... and the samples come within the certified grid error: |r + s p1 - t p2| is
    # 1-Lipschitz in s and t, and the first grid has spacings 2h/(m-1)
    assert np.all(d_ref - dist <= (h1 + h2) / (m - 1) + 1e-12)
    # the returned closest points lie on the segments and realise the distance
    assert np.all(np.abs(s) <= h1 + 1e-15) and np.all(np.abs(t) <= h2 + 1e-15)
    dvec = r + s[:, None] * p1 - t[:, None] * p2
    np.testing.assert_allclose(np.linalg.norm(dvec, axis=1), dist, atol=1e-13)
    # optimality certificate of the convex problem (KKT): the gradient of |dvec|^2/2 in
    # s is p1.dvec, in t it is -p2.dvec; zero inside, pointing outwards at a bound
    tol = 1e-9
    gs, gt = np.sum(p1 * dvec, axis=1), -np.sum(p2 * dvec, axis=1)
    for g, u, h in ((gs, s, h1), (gt, t, h2)):
        inside = np.abs(u) < h - 1e-12
        assert np.all(np.abs(g[inside]) <= tol)
        assert np.all(g[(~inside) & (u > 0)] <= tol) and np.all(g[(~inside) & (u < 0)] >= -tol)


def test_parallel_segments_take_the_middle_of_the_overlap():
    # two parallel unit-half-length segments, side by side, shifted by 0.4 along x:
    # every s in [-0.6, 1] is optimal on 1 ... the middle is s = 0.2 and t = -0.2
    r = np.array([[0.4, 0.3, 0.0]])
    p = np.array([[1.0, 0.0, 0.0]])
    out = geo.capsule_contact(r, p, 1.0, 0.05, p, 1.0, 0.05)
    np.testing.assert_allclose(out["dist"], 0.3 - 0.1, atol=1e-15)
    np.testing.assert_allclose(out["s"], -0.2, atol=1e-15)
    np.testing.assert_allclose(out["t"], 0.2, atol=1e-15)
    np.testing.assert_allclose(out["normal"], [[0.0, 1.0, 0.0]], atol=1e-15)


def test_crossing_axes_get_the_normal_along_p1_cross_p2():
    r = np.array([[0.0, 0.0, 1e-18]])
    out = geo.capsule_contact(r, [[1.0, 0, 0]], 1.0, 0.1, [[0.0, 1.0, 0]], 1.0, 0.1)
    np.testing.assert_allclose(out["dist"], -0.2, atol=1e-15)
    np.testing.assert_allclose(np.abs(out["normal"]), [[0.0, 0.0, 1.0]], atol=1e-15)


def test_sphere_sphere_and_sphere_fibre_gaps_are_exact():
    # spheres: |r| - R1 - R2; sphere beside a fibre's middle: lateral distance - R1 - R2;
    # sphere beyond a fibre end: distance to the end point - R1 - R2
    r = np.array([[0.3, 0.4, 0.0], [0.0, 0.5, 0.0], [1.3, 0.0, 0.4]])
    p1 = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    p2 = np.array([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    out = geo.capsule_contact(r, p1, [0.0, 0.0, 0.0], [0.1, 0.1, 0.1], p2, [0.0, 1.0, 1.0], [0.05, 0.02, 0.02])
    np.testing.assert_allclose(out["dist"], [0.5 - 0.15, 0.5 - 0.12, np.hypot(0.3, 0.4) - 0.12], atol=1e-15)


# ------------------------------------------------------------------------ cell lists
@pytest.mark.parametrize("dim,walls,offset,n", [(2, False, 0.0, 400), (2, False, 0.6234, 400),
                                                 (2, False, -0.75, 300), (2, True, 0.0, 300),
                                                 (3, False, 0.377, 600), (3, False, -1.1, 500),
                                                 (3, True, 0.0, 400)])
def test_cell_list_finds_exactly_the_pairs_of_the_n2_scan(dim, walls, offset, n):
    lengths = (2.3, 1.7, 1.9)[:dim]
    cell = geo.Cell(lengths, walls=walls, shear_rate=1.0, shear_offset=offset)
    rng = np.random.default_rng(n + dim)
    # positions anywhere (unwrapped), so the images matter
    x = rng.uniform(-1.0, 3.0, size=(n, dim)) if not walls else rng.uniform(0.0, 1.0, (n, dim)) * lengths
    for rc in (0.21, 0.5):
        cells = geo.neighbour_pairs(x, cell, rc, method="cells")
        naive = geo.neighbour_pairs(x, cell, rc, method="naive")
        assert len(naive) > 0
        np.testing.assert_array_equal(cells, naive)
        # and the n2 scan agrees with an independent numpy brute force over images
        i, j = np.triu_indices(n, 1)
        d = np.linalg.norm(brute_min_image(x[i] - x[j], cell), axis=1)
        np.testing.assert_array_equal(naive, np.stack([i[d < rc], j[d < rc]], axis=1))


def test_cell_list_refuses_a_cell_smaller_than_twice_the_range():
    with pytest.raises(InputError, match="twice the interaction range"):
        geo.neighbour_pairs(np.zeros((3, 2)) + 0.1, geo.Cell((1.0, 1.0)), 0.6)


# ------------------------------------------------------------------------ kinematics
def jeffery_xi(beta):
    return (beta**2 - 1) / (beta**2 + 1)


def test_sphere_spins_at_half_the_vorticity_and_drifts_with_the_flow():
    cell = geo.Cell((2.0, 1.0, 1.0), shear_rate=3.0)
    x = np.array([[0.3, 0.8, 0.1], [1.0, 0.2, 0.9]])
    v, om = geo.jeffery_velocities(cell, x, unit([[1, 2, 3], [0, 0, 1]]), [0.0, 0.0])
    np.testing.assert_allclose(om, [[0, 0, -1.5]] * 2, atol=1e-15)  # u = gd y e_x: omega_z = -gd/2
    np.testing.assert_allclose(v[:, 0], 3.0 * (x[:, 1] - 0.5), atol=1e-15)
    np.testing.assert_allclose(v[:, 1:], 0.0, atol=1e-15)
    v2, om2 = geo.jeffery_velocities(geo.Cell((2.0, 1.0), shear_rate=3.0), x[:, :2], [[1.0, 0.0]] * 2, [0.0, 0.0])
    np.testing.assert_allclose(om2[:, 2], -1.5, atol=1e-15)


def test_rigid_update_keeps_unit_axes_and_lengths_over_1e4_steps():
    rng = np.random.default_rng(3)
    n, length = 50, 0.7
    cell = geo.Cell((3.0, 3.0, 3.0), shear_rate=1.0)
    x = rng.uniform(0, 3, (n, 3))
    p = unit(rng.normal(size=(n, 3)))
    xh, ph = geo.jeffery_advance(cell, x, p, np.full(n, jeffery_xi(15.0)), dt=0.01, nsteps=10_000, every=10_000)
    norm_drift = np.abs(np.linalg.norm(ph, axis=2) - 1.0).max()
    ends = (xh[-1] + 0.5 * length * ph[-1]) - (xh[-1] - 0.5 * length * ph[-1])
    length_drift = np.abs(np.linalg.norm(ends, axis=1) - length).max() / length
    assert norm_drift <= 1e-12 and length_drift <= 1e-12
    # and the particles did rotate a lot (the test is not vacuous)
    assert np.min(np.sum(ph[0] * ph[-1], axis=1)) < 0.999


def jeffery_period_measured(beta, dt, dim):
    """Time for the unwrapped in-plane angle of a single fibre to turn by 2 pi."""
    gd = 1.0
    period = 2 * np.pi / gd * (beta + 1 / beta)
    cell = geo.Cell((4.0, 4.0, 4.0)[:dim], shear_rate=gd)
    p0 = np.zeros((1, dim))
    p0[0, 1] = 1.0  # start along the gradient direction, where the rotation is fastest
    nsteps = int(1.05 * period / dt)
    _, ph = geo.jeffery_advance(cell, np.full((1, dim), 2.0), p0, [jeffery_xi(beta)], dt, nsteps)
    theta = np.unwrap(np.arctan2(ph[:, 0, 1], ph[:, 0, 0]))
    turned = theta[0] - theta  # shear turns the axis clockwise
    k = np.argmax(turned >= 2 * np.pi)
    frac = (2 * np.pi - turned[k - 1]) / (turned[k] - turned[k - 1])
    return (k - 1 + frac) * dt, period


@pytest.mark.parametrize("dim", [2, 3])
def test_discrete_jeffery_period_converges_to_the_exact_period_at_second_order(dim):
    # The step (velocities frozen, exact rotation) is first order pointwise (next test),
    # but the O(dt) term of the orbit period cancels: Euler's modified equation is
    # theta' = f - (dt/2) f f' + O(dt^2), so T_dt = T + (dt/2) \oint f'/f dtheta + O(dt^2)
    # and \oint f'/f dtheta = [ln f] over a period = 0. Measured order: 2.00.
    beta = 5.0
    dts = np.array([0.08, 0.04, 0.02, 0.01])
    errs = []
    for dt in dts:
        measured, exact = jeffery_period_measured(beta, dt, dim)
        errs.append(abs(measured - exact) / exact)
    order = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert errs[-1] < 1e-4
    assert abs(order - 2.0) < 0.2


def test_3d_jeffery_orbit_matches_the_exact_solution():
    # p(t) = B p0 / |B p0|, B = exp(t (W + xi D))  (Jeffery 1922; exact for any start)
    beta, gd, t_end = 8.0, 1.0, 6.0
    xi = jeffery_xi(beta)
    G = np.zeros((3, 3))
    G[0, 1] = gd
    D, W = (G + G.T) / 2, (G - G.T) / 2
    p0 = unit(np.array([[0.3, 0.5, 0.8], [-0.2, 0.9, 0.1]]))
    B = expm(t_end * (W + xi * D))
    exact = unit(p0 @ B.T)
    cell = geo.Cell((4.0, 4.0, 4.0), shear_rate=gd)
    errs = []
    for dt in (0.02, 0.01, 0.005):
        nsteps = int(round(t_end / dt))
        _, ph = geo.jeffery_advance(cell, np.full((2, 3), 2.0), p0, [xi, xi], dt, nsteps, every=nsteps)
        errs.append(np.abs(ph[-1] - exact).max())
    assert errs[-1] < 5e-3
    assert 1.7 < errs[0] / errs[1] < 2.3 and 1.7 < errs[1] / errs[2] < 2.3  # first order
