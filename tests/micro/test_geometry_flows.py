"""Elongational flows through fold_run on the deforming lattice of fold_cell.

* dilute fibres, Jeffery kinematics, planar (Kraynik-Reinelt, across three remaps)
  and uniaxial elongation: every fibre on the exact Jeffery solution, and the run's
  a2(t) = Folgar-Tucker with C_I = 0 and the run's own a4 (cubic interpolation in
  time), as for shear in tests/cross/test_dilute_jeffery.py;
* a contact scene in planar elongation over more than two Kraynik-Reinelt periods:
  every gap >= 0 (>= alpha) with the strategy, overlaps without it;
* uniaxial elongation past the admissible time: the run stops cleanly at the step
  the cell gets too thin, keeping the last good state.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy.linalg import expm

from pyfold.native import geometry as geo
from test_run_common import random_unit, run_fold, write_run_file, xi_of

BETA = 10.0
N = 100
L = 6.0
DT = 0.01
FLOWS = {
    # Kraynik-Reinelt period at rate 1: ln((3 + sqrt 5)/2) = 0.962 -> three remaps
    "planar": (np.diag([1.0, -1.0, 0.0]), 3.0),
    # thickness 6 e^{-t/2} must stay > 2 x 1.15: admissible until t = 1.91
    "uniaxial": (np.diag([1.0, -0.5, -0.5]), 1.5),
}


def resolved_override(G):
    return {"/setup/resolved/velocity_gradient": G,
            "/setup/resolved/shear_rate": float(np.sqrt(0.5 * np.sum((G + G.T) ** 2)))}


@pytest.fixture(scope="module", params=sorted(FLOWS))
def dilute_run(request, tmp_path_factory):
    xr = pytest.importorskip("xarray")
    G, t_end = FLOWS[request.param]
    rng = np.random.default_rng(17)
    path = tmp_path_factory.mktemp("elong") / f"{request.param}.h5"
    p0 = random_unit(rng, N, 3)
    nsteps = int(round(t_end / DT))
    write_run_file(path, x=rng.uniform(0, L, size=(N, 3)), p=p0, radius=0.05, length=1.0, xi=xi_of(BETA),
                   cell_lengths=(L, L, L), dt=DT, t_end=t_end, collisions=0, output_every=1, snapshot_every=nsteps,
                   override=resolved_override(G))
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    return request.param, G, xr.open_dataset(path, engine="h5netcdf"), p0


def test_dilute_fibres_in_elongation_follow_the_exact_jeffery_solution(dilute_run):
    name, G, ds, p0 = dilute_run
    D, W = 0.5 * (G + G.T), 0.5 * (G - G.T)
    t = float(ds.snapshot_time.values[-1])
    q = p0 @ expm(t * (W + xi_of(BETA) * D)).T
    np.testing.assert_allclose(ds.p.values[-1], q / np.linalg.norm(q, axis=1, keepdims=True), rtol=0, atol=1e-12)
    # the centres were kept in the primary cell of the deformed lattice at t_end
    cell = geo.Cell((L, L, L), velocity_gradient=G, time=t)
    lat = cell.lattice()
    assert lat.flow == ("planar_kraynik_reinelt" if name == "planar" else "general")
    f = np.linalg.solve(lat.vectors.T, (ds.x.values[-1] - lat.origin).T)
    assert np.all(f > -1e-12) and np.all(f < 1 + 1e-12)


def test_dilute_a2_in_elongation_equals_folgar_tucker_ci0_with_its_own_a4(dilute_run):
    from pyfold.closures import TabulatedA4
    from pyfold.models import FolgarTucker, solve_orientation

    _, G, ds, _ = dilute_run
    t = ds.time.values
    a2 = ds.a2.values
    model = FolgarTucker(ci=0.0, xi=xi_of(BETA), closure=TabulatedA4(t, ds.a4.values, method="cubic"))
    sol = solve_orientation(model, a2[0], G, t, rtol=1e-10, atol=1e-12)
    err = np.max(np.abs(np.asarray(sol.a2) - a2))
    assert np.max(np.abs(a2[-1] - a2[0])) > 0.2  # the fibres did align
    assert err <= 1e-6, err


def pair_gaps_2d(x, radius, cell):
    i, j = np.triu_indices(len(x), 1)
    return np.linalg.norm(geo.min_image(x[i] - x[j], cell), axis=1) - radius[i] - radius[j]


@pytest.fixture(scope="module")
def disk_runs(tmp_path_factory):
    """2-D disks, phi = 0.35, planar elongation in a 3 x 3 Kraynik-Reinelt cell, with
    and without the collision strategy, over 2.6 periods."""
    rate, Lc, R, n, alpha, dt, t_end = 1.0, 3.0, 0.1, 100, 0.005, 0.01, 2.5
    G = np.diag([rate, -rate, 0.0])
    cell = geo.Cell((Lc, Lc), velocity_gradient=G[:2, :2])
    placed = geo.place_particles(cell, np.full(n, geo.SPHERE), np.full(n, R), np.full(n, 2 * R), alpha=alpha, seed=3)
    out = {}
    for mode in (0, 2):
        path = tmp_path_factory.mktemp("disks") / f"m{mode}.h5"
        write_run_file(path, x=placed.x, p=placed.p, shape=np.full(n, 2), radius=R, length=2 * R, xi=0.0, dim=2,
                       cell_lengths=(Lc, Lc, 0.0), dt=dt, t_end=t_end, collisions=mode, alpha=alpha,
                       contact_max_iter=200, output_every=1, snapshot_every=5, override=resolved_override(G))
        proc = run_fold(path)
        assert proc.returncode == 0, proc.stderr + proc.stdout
        with h5py.File(path) as f:
            out[mode] = (f["snapshot_time"][()], f["x"][()], f["min_gap_over_alpha"][()])
    return cell, np.full(n, R), alpha, out


def test_contacts_in_planar_elongation_keep_every_gap_positive(disk_runs):
    cell, radius, alpha, out = disk_runs
    t_snap, xs, mgoa = out[2]
    assert t_snap[-1] > 2.5 * cell.lattice().period * 0.99
    # independent check from the snapshots: all pairs, minimum image of the lattice of that time
    worst = min(pair_gaps_2d(x, radius, cell.at_time(t)).min() for t, x in zip(t_snap, xs))
    assert worst >= alpha * (1 - 1e-6), worst
    assert mgoa.min() >= 1 - 1e-6
    # without the strategy the same scene overlaps: the check is not vacuous
    t0, x0, _ = out[0]
    assert min(pair_gaps_2d(x, radius, cell.at_time(t)).min() for t, x in zip(t0, x0)) < 0


def test_uniaxial_run_past_the_admissible_time_stops_cleanly(tmp_path):
    G, _ = FLOWS["uniaxial"]
    rng = np.random.default_rng(2)
    n, R, length, t_end = 20, 0.05, 1.0, 3.0
    path = tmp_path / "u.h5"
    write_run_file(path, x=rng.uniform(0, L, size=(n, 3)), p=random_unit(rng, n, 3), radius=R, length=length,
                   xi=xi_of(BETA), cell_lengths=(L, L, L), dt=DT, t_end=t_end, collisions=2, alpha=0.005,
                   output_every=10, override=resolved_override(G))
    proc = run_fold(path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    rc = geo.contact_search_range(np.full(n, geo.FIBRE), np.full(n, R), np.full(n, length), alpha=0.005)
    t_ok = geo.admissible_t_end(geo.Cell((L, L, L), velocity_gradient=G), rc, DT, t_end)
    assert 1.0 < t_ok < t_end
    with h5py.File(path) as f:
        status = f.attrs["status"]
        status = status.decode() if isinstance(status, bytes) else str(status)
        assert "deformed periodic cell is only" in status and "cannot go on" in status
        steps = int(np.asarray(f.attrs["steps_done"]).ravel()[0])
        assert steps * DT == pytest.approx(t_ok, abs=1e-9)
        assert f["time"][-1] == pytest.approx(t_ok, abs=1e-9)  # the last good state is kept
