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


def test_cell_rejects_walls_with_elongation_and_a_compressible_gradient():
    x, p = np.asfortranarray([[0.5], [0.5]]), np.asfortranarray([[1.0], [0.0]])
    # Couette walls drive a simple shear only
    *_, stat, msg = geo._ext().fold_geo_jeffery(np.ones(3), 1, np.diag([1.0, -1.0, 0.0]), x, p, np.array([0.5]))
    with pytest.raises(InputError, match="walls .* simple shear only"):
        checked(stat, msg)
    # a periodic lattice carried by the flow keeps its volume only if tr G = 0
    *_, stat, msg = geo._ext().fold_geo_jeffery(np.ones(3), 0, np.diag([1.0, -0.5, 0.0]), x, p, np.array([0.5]))
    with pytest.raises(InputError, match="traceless"):
        checked(stat, msg)


# ------------------------------------------------------------ deforming lattices
KR_TAN = (np.sqrt(5.0) - 1.0) / 2.0
KR_PERIOD_STRAIN = np.log((3.0 + np.sqrt(5.0)) / 2.0)


def kr_lattice0(L, dim, Lz=2.5):
    """Kraynik & Reinelt (1992): the square rotated by the magic angle, z neutral (rows = vectors)."""
    c = 1.0 / np.sqrt(1.0 + KR_TAN**2)
    s = KR_TAN * c
    a = np.eye(dim) * Lz
    a[0, :2] = L * np.array([c, -s])
    a[1, :2] = L * np.array([s, c])
    return a


GENERAL_G = np.array([[0.3, 0.8, 0.1], [-0.5, -0.1, 0.4], [0.2, -0.3, -0.2]])


def deformed_cases():
    """(cell, unreduced lattice rows exp(G t) A0 computed here with SciPy)."""
    out = []
    for dim in (2, 3):
        lengths = (3.0, 3.0, 2.5)[:dim]
        G = np.diag([1.0, -1.0, 0.0])[:dim, :dim]
        for t in (0.37, 0.9, 2.3):  # 2.3: past two Kraynik-Reinelt periods
            out.append((geo.Cell(lengths, velocity_gradient=G, time=t), (expm(G * t) @ kr_lattice0(3.0, dim).T).T))
        G = GENERAL_G[:dim, :dim] - np.trace(GENERAL_G[:dim, :dim]) / dim * np.eye(dim)
        lengths = (3.0, 2.0, 2.5)[:dim]
        for t in (0.8, 1.7):
            out.append((geo.Cell(lengths, velocity_gradient=G, time=t), (expm(G * t) @ np.diag(lengths)).T))
    G = np.diag([1.0, -0.5, -0.5])
    out.append((geo.Cell((3.0, 2.0, 2.5), velocity_gradient=G, time=0.6), (expm(G * 0.6) @ np.diag([3.0, 2.0, 2.5])).T))
    return out


DEFORMED = deformed_cases()
DEFORMED_IDS = [f"{c.dim}d-{c.lattice().flow}-t{c.time}" for c, _ in DEFORMED]
# brute-force enumeration over the unreduced exp(G t) A0 is affordable while it is not
# too skewed (t = 2.3 of Kraynik-Reinelt is checked through the lattice identity above)
BRUTE = [c for c in DEFORMED if c[0].time < 2.0]
BRUTE_IDS = [i for c, i in zip(DEFORMED, DEFORMED_IDS) if c[0].time < 2.0]


def brute_lattice_min_image(dx, rows):
    """Shortest image of each dx over an integer box of images of the UNREDUCED lattice
    that provably contains it: |n_k - f_k| <= |r|/h_k for any image r at least as short."""
    A = rows.T
    f = np.linalg.solve(A, dx.T).T
    base = dx - np.round(f) @ rows
    h = 1.0 / np.linalg.norm(np.linalg.inv(A), axis=1)
    K = np.ceil(np.linalg.norm(base, axis=1).max() / h).astype(int) + 1
    grids = np.meshgrid(*[np.arange(-k, k + 1) for k in K], indexing="ij")
    shifts = np.stack([g.ravel() for g in grids], axis=1) @ rows
    best = base.copy()
    for chunk in np.array_split(np.arange(len(shifts)), max(1, len(shifts) // 256)):
        cand = base[:, None, :] - shifts[None, chunk, :]
        d = np.linalg.norm(cand, axis=2)
        k = d.argmin(axis=1)
        pick = cand[np.arange(len(dx)), k]
        closer = np.linalg.norm(pick, axis=1) < np.linalg.norm(best, axis=1)
        best[closer] = pick[closer]
    return best


def integer_relation(rows_a, rows_b):
    """M with rows_b = M rows_a (must be an integer matrix of determinant +-1 for the same lattice)."""
    return np.linalg.solve(rows_a.T, rows_b.T).T


@pytest.mark.parametrize("case", DEFORMED, ids=DEFORMED_IDS)
def test_deformed_lattice_is_exp_gt_a0_reduced(case):
    cell, rows = case
    lat = cell.lattice()
    # the reduced basis spans exactly the lattice exp(G t) A0 (unimodular integer change)
    m = integer_relation(rows, lat.vectors)
    np.testing.assert_allclose(m, np.round(m), atol=1e-9)
    assert abs(abs(np.linalg.det(np.round(m))) - 1.0) < 1e-12
    # reduced: no vector shortened by adding or subtracting another
    v = lat.vectors
    for i, j in itertools.permutations(range(cell.dim), 2):
        for sgn in (-1, 1):
            assert np.linalg.norm(v[i] + sgn * v[j]) >= np.linalg.norm(v[i]) * (1 - 1e-12)
    # thickness = 1/|dual vector| and the volume is conserved (tr G = 0)
    np.testing.assert_allclose(lat.thickness, 1.0 / np.linalg.norm(np.linalg.inv(v.T), axis=1), rtol=1e-12)
    np.testing.assert_allclose(abs(np.linalg.det(v)), np.prod(cell.lengths), rtol=1e-12)


@pytest.mark.parametrize("case", BRUTE, ids=BRUTE_IDS)
def test_min_image_on_deformed_lattices_matches_brute_force_enumeration(case):
    cell, rows = case
    rng = np.random.default_rng(11 + cell.dim)
    dx = rng.uniform(-8.0, 8.0, size=(1500, cell.dim))
    dx[:300] *= 0.05  # short displacements: the fast path
    got = geo.min_image(dx, cell)
    ref = brute_lattice_min_image(dx, rows)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), np.linalg.norm(ref, axis=1), rtol=0, atol=1e-11)
    # and the result is dx moved by a lattice vector
    n = np.linalg.solve(rows.T, (dx - got).T).T
    np.testing.assert_allclose(n, np.round(n), atol=1e-9)


def test_kraynik_reinelt_lattice_repeats_after_the_hencky_strain_period():
    # lambda = (3 + sqrt 5)/2: after e t = ln lambda the lattice is the initial one
    rate = 0.7
    G = np.diag([rate, -rate, 0.0])
    cell = geo.Cell((2.0, 2.0, 1.5), velocity_gradient=G)
    lat = cell.lattice()
    assert lat.flow == "planar_kraynik_reinelt"
    assert lat.period == pytest.approx(KR_PERIOD_STRAIN / rate, rel=1e-15)
    for t in (0.0, 0.3, 1.1):
        a, b = cell.at_time(t).lattice(), cell.at_time(t + lat.period).lattice()
        m = integer_relation(a.vectors, b.vectors)
        np.testing.assert_allclose(m, np.round(m), atol=1e-9)
        assert abs(abs(np.linalg.det(np.round(m))) - 1.0) < 1e-12
        # the thickness never degrades: the cell list works at any time
        assert b.thickness.min() > 0.5 * 1.5
    # the underlying map over one period is Arnold's cat map [[2,1],[1,1]] (or its inverse)
    A0 = kr_lattice0(2.0, 2)
    cat = np.linalg.solve(A0.T, expm(np.diag([rate, -rate]) * lat.period) @ A0.T)
    np.testing.assert_allclose(cat, [[2, 1], [1, 1]], atol=1e-12)


@pytest.mark.parametrize("case", BRUTE[::2], ids=BRUTE_IDS[::2])
def test_wrap_on_a_deformed_lattice_keeps_the_velocity_relative_to_the_mean_flow(case):
    cell, rows = case
    lat = cell.lattice()
    rng = np.random.default_rng(5)
    x = rng.uniform(-10, 10, size=(400, cell.dim))
    v = rng.normal(size=(400, cell.dim))
    xw, vw = geo.wrap(x, v, cell)
    f = np.linalg.solve(lat.vectors.T, (xw - lat.origin).T).T
    assert np.all(f >= -1e-12) and np.all(f < 1 + 1e-12)
    n = np.linalg.solve(rows.T, (x - xw).T).T
    np.testing.assert_allclose(n, np.round(n), atol=1e-9)
    G = cell.gradient()[: cell.dim, : cell.dim]
    u = lambda pos: (pos - 0.5 * np.array(cell.lengths)) @ G.T
    np.testing.assert_allclose(vw - u(xw), v - u(x), atol=1e-11)


@pytest.mark.parametrize("case", BRUTE[1::2], ids=BRUTE_IDS[1::2])
def test_cell_list_on_a_deformed_lattice_finds_exactly_the_n2_pairs(case):
    cell, rows = case
    rc = 0.45 * cell.lattice().thickness.min()
    rng = np.random.default_rng(3)
    x = rng.uniform(-4, 7, size=(160 if cell.dim == 3 else 200, cell.dim))
    cells = geo.neighbour_pairs(x, cell, rc, method="cells")
    naive = geo.neighbour_pairs(x, cell, rc, method="naive")
    i, j = np.triu_indices(len(x), 1)
    d = np.linalg.norm(brute_lattice_min_image(x[i] - x[j], rows), axis=1)
    assert (d < rc).sum() > 20
    np.testing.assert_array_equal(cells, naive)
    np.testing.assert_array_equal(naive, np.stack([i[d < rc], j[d < rc]], axis=1))
    with pytest.raises(InputError, match="deformed periodic cell is only"):
        geo.neighbour_pairs(x, cell, 0.51 * cell.lattice().thickness.min())


def test_admissible_end_time_of_elongations_without_remap():
    # uniaxial elongation of a cube: the lattice stays orthogonal (already reduced),
    # thickness L e^{-e t/2} along y and z, so 2 rc < L e^{-e t/2} until t = 2 ln(L/2rc)/e
    L, rc, rate, dt = 6.0, 1.0, 1.0, 0.01
    cell = geo.Cell((L, L, L), velocity_gradient=np.diag([rate, -rate / 2, -rate / 2]))
    t_ok = geo.admissible_t_end(cell, rc, dt, 10.0)
    assert t_ok == pytest.approx(np.floor(2 * np.log(L / (2 * rc)) / rate / dt) * dt, abs=1e-12)
    assert geo.admissible_t_end(cell, rc, dt, 1.0) == 1.0
    # planar elongation with Lx != Ly: no Kraynik-Reinelt lattice, thickness Ly e^{-e t}
    cell = geo.Cell((8.0, 5.0), velocity_gradient=np.diag([rate, -rate]))
    assert cell.lattice().flow == "general"
    assert geo.admissible_t_end(cell, rc, dt, 10.0) == pytest.approx(np.floor(np.log(5.0 / 2) / dt) * dt, abs=1e-12)
    # with Lx = Ly the remapped lattice never thins: any t_end is admissible
    cell = geo.Cell((5.0, 5.0), velocity_gradient=np.diag([rate, -rate]))
    assert geo.admissible_t_end(cell, rc, dt, 50.0) == 50.0
    assert geo.admissible_t_end(cell, 3.0, dt, 50.0) == -1.0  # too thin from the start


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
