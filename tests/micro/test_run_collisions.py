"""Collision invariants of full fold_run runs
(docs/physics.md#no-overlap-with-the-collision-strategy):
strategy -> every gap >= 0 at every step; none -> overlaps appear, and are recorded.

* the seed's 2-D Couette disks: cell 1.5 x 1, R = 0.075, phi ~ 50 % (42 disks),
  gamma_dot = 1, dt = 0.05, alpha = 0.005 (the seed runs to t = 30; 5 here);
* 3-D fibres in the semi-concentrated regime n L^3 = 15 > L/d = 10, Lees-Edwards shear.
Records are written at every step and are minima over their interval anyway.
"""
from __future__ import annotations

import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from test_run_common import run_fold, write_run_file, xi_of

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "fortran" / "app"))
from check_fold_run import place_disks  # noqa: E402  (the meson check's placement of the same disks)


def seed_disks():
    """The seed's scene: 42 disks of R = 0.075 in 1.5 x 1 (phi = 49.5 %), Couette walls."""
    R, n = 0.075, 42
    rng = np.random.default_rng(0)  # places all 42 disks in ~2e4 trials
    x = place_disks(n, R, 1.5, 1.0, rng)
    theta = rng.uniform(0, 2 * np.pi, n)
    return dict(x=x, p=np.column_stack([np.cos(theta), np.sin(theta)]), shape=np.full(n, 2), radius=R,
                length=2 * R, xi=0.0, dim=2, cell_lengths=(1.5, 1.0, 1.0), walls=1, shear_rate=1.0, dt=0.05,
                alpha=0.005, family_names=("disks",))


def fibre_scene(n_l3=15.0, cell=2.5, beta=10.0, seed=3):
    from pyfold.native.geometry import FIBRE, Cell, place_particles

    n = int(round(n_l3 * cell**3))
    R = 0.5 / beta
    c = Cell(lengths=(cell, cell, cell), shear_rate=1.0)
    pl = place_particles(c, np.full(n, FIBRE), np.full(n, R), np.full(n, 1.0), alpha=0.01, seed=seed)
    return dict(x=pl.x, p=pl.p, radius=R, length=1.0, xi=xi_of(beta), cell_lengths=(cell, cell, cell),
                shear_rate=1.0, dt=0.01, alpha=0.01)


@pytest.fixture(scope="module")
def disk_runs(tmp_path_factory):
    out = {}
    for mode in (0, 2):
        path = tmp_path_factory.mktemp("disks") / f"disks{mode}.h5"
        write_run_file(path, **seed_disks(), t_end=5.0, collisions=mode, contact_max_iter=200,
                       on_contact_cap=1, output_every=1)
        proc = run_fold(path)
        assert proc.returncode == 0, proc.stderr
        with h5py.File(path) as f:
            out[mode] = {k: f[k][()] for k in ("min_gap", "min_gap_over_alpha", "n_corrections", "step",
                                                "capped_steps", "contact_iterations", "pairs_left")}
    return out


def test_seed_disks_with_strategy_never_overlap(disk_runs):
    r = disk_runs[2]
    assert len(r["step"]) == 101  # every step recorded (t = 0 ... 5, dt = 0.05)
    assert r["n_corrections"].sum() > 0
    assert np.all(r["min_gap"] >= 0.0), r["min_gap"].min()


def test_seed_disks_without_collisions_overlap_and_it_is_recorded(disk_runs):
    r = disk_runs[0]
    assert r["n_corrections"].sum() == 0
    assert r["min_gap"].min() < 0.0
    assert r["min_gap_over_alpha"].min() < 0.0
    assert r["pairs_left"].max() > 0


@pytest.fixture(scope="module")
def fibre_runs(tmp_path_factory):
    pytest.importorskip("pyfold.native.geometry")
    scene = fibre_scene()
    out = {}
    for mode in (0, 2):
        path = tmp_path_factory.mktemp("fibres") / f"fibres{mode}.h5"
        write_run_file(path, **scene, t_end=0.2, collisions=mode, contact_max_iter=100, on_contact_cap=1,
                       output_every=1)
        proc = run_fold(path)
        assert proc.returncode == 0, proc.stderr
        with h5py.File(path) as f:
            out[mode] = {k: f[k][()] for k in ("min_gap", "n_corrections", "capped_steps", "unit_norm_drift")}
    return out


def test_semiconcentrated_fibres_with_strategy_never_overlap(fibre_runs):
    r = fibre_runs[2]
    assert r["n_corrections"].sum() > 0
    assert np.all(r["min_gap"] >= 0.0), r["min_gap"].min()
    assert r["unit_norm_drift"].max() < 1e-13


def test_semiconcentrated_fibres_without_collisions_overlap(fibre_runs):
    assert fibre_runs[0]["min_gap"].min() < 0.0
