"""fold_run exit codes: a bad run file exits 2 naming the dataset; a blow-up exits 1
naming step and cause, and the file keeps the last good state."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from test_run_common import random_unit, run_fold, write_run_file, xi_of


def _fibres(rng, n=8, cell=6.0):
    return dict(x=rng.uniform(0, cell, size=(n, 3)), p=random_unit(rng, n, 3), radius=0.05, length=1.0,
                xi=xi_of(10.0), cell_lengths=(cell, cell, cell))


BAD_FILES = [
    ({"drop": ("/initial/xi",)}, "/initial/xi"),
    ({"override": {"/setup/resolved/dt": -1.0}}, "/setup/resolved/dt"),
    ({"override": {"/setup/resolved/t_end": float("nan")}}, "/setup/resolved/t_end"),
    ({"override": {"/setup/resolved/collisions": np.int64(5)}}, "/setup/resolved/collisions"),
    ({"override": {"/setup/resolved/velocity_gradient": np.ones((3, 3))}}, "/setup/resolved/velocity_gradient"),
    ({"override": {"/setup/resolved/shear_rate": 2.0}}, "/setup/resolved/shear_rate"),
    ({"override": {"/setup/resolved/hydrodynamics": np.int64(2)}}, "/setup/resolved/hydrodynamics"),
    # stokes (1) needs its settings: the first one missing is named
    ({"override": {"/setup/resolved/hydrodynamics": np.int64(1)}}, "/setup/resolved/stokes_grid"),
    ({"override": {"/initial/family": np.full(8, 3)}}, "/initial/family"),
    ({"override": {"/initial/p": np.full((8, 3), 1.0)}}, "/initial/p"),
    ({"override": {"/initial/x": np.zeros((8, 2))}}, "/initial/x"),
    ({"override": {"/initial/xi": np.full(8, 1.5)}}, "/initial/xi"),
    ({"drop": ("/initial/radius",)}, "/initial/radius"),
]


@pytest.mark.parametrize("change, dataset", BAD_FILES, ids=[d for _, d in BAD_FILES])
def test_bad_run_file_exits_2_naming_the_dataset(tmp_path, change, dataset):
    rng = np.random.default_rng(1)
    path = tmp_path / "bad.h5"
    write_run_file(path, **_fibres(rng), **change)
    proc = run_fold(path)
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert dataset in proc.stderr, proc.stderr
    assert proc.stderr.startswith("fold_run:")


def test_missing_run_file_and_bad_arguments_exit_2(tmp_path):
    proc = run_fold(tmp_path / "nowhere.h5")
    assert proc.returncode == 2 and "not found" in proc.stderr


def test_nan_blow_up_exits_1_naming_step_and_cause_and_keeps_initial_state(tmp_path):
    """An absurd dt (gamma_dot dt = 1e300) makes the Jeffery propagator overflow:
    NaN in p at step 1. Particles sit on the shear's zero-velocity plane so that the
    NaN (not the displacement check) is what stops the run."""
    rng = np.random.default_rng(2)
    kw = _fibres(rng)
    kw["x"][:, 1] = 3.0  # y = Ly/2: u = 0
    path = tmp_path / "nan.h5"
    write_run_file(path, **kw, dt=1e300, t_end=1e301)
    proc = run_fold(path)
    assert proc.returncode == 1, proc.stderr
    assert "step 1" in proc.stderr and "NaN" in proc.stderr
    with h5py.File(path) as f:
        status = f.attrs["status"]
        assert status.startswith("failed: step 1,") and "NaN" in status
        assert f.attrs["steps_done"] == 0
        assert f["/checkpoint/step"][()] == 0
        np.testing.assert_array_equal(f["/checkpoint/p"][()], kw["p"])
        np.testing.assert_array_equal(f["/checkpoint/x"][()], kw["x"])
        assert list(f["step"][()]) == [0]
        assert np.all(np.isfinite(f["a2"][()]))


def test_huge_displacement_is_a_blow_up(tmp_path):
    rng = np.random.default_rng(3)
    path = tmp_path / "jump.h5"
    write_run_file(path, **_fibres(rng), dt=100.0, t_end=1000.0)
    proc = run_fold(path)
    assert proc.returncode == 1
    assert "step 1" in proc.stderr and "more than half the cell" in proc.stderr


def test_contact_cap_with_on_cap_stop_exits_1_and_keeps_last_good_state(tmp_path):
    """Dense 2-D disks, one contact sweep allowed: the first step that needs more
    stops the run with an overlap status; the file ends at the step before."""
    from test_run_collisions import seed_disks

    path = tmp_path / "cap.h5"
    kw = seed_disks()
    write_run_file(path, **kw, t_end=2.0, collisions=2, contact_max_iter=1, on_contact_cap=0,
                   output_every=1, snapshot_every=5)
    proc = run_fold(path)
    assert proc.returncode == 1, proc.stderr
    assert "security zone" in proc.stderr
    with h5py.File(path) as f:
        status = f.attrs["status"]
        failed = int(status.split("step ")[1].split(",")[0])
        assert status.startswith("failed: step") and "security zone" in status
        assert f.attrs["steps_done"] == failed - 1
        assert f["step"][-1] == failed - 1
        assert f["/checkpoint/step"][()] == failed - 1
        assert f["snapshot"][-1] == failed - 1
        np.testing.assert_array_equal(f["x"][-1], f["/checkpoint/x"][()])
        assert np.all(f["min_gap"][()] >= 0.0)
