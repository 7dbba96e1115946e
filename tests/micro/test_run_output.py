"""Layout of fold_run results (netCDF-compatible, units, root attributes), resume
from a checkpoint, and np = 1 vs np = 2 equality for a contact-heavy fibre scene."""
from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from test_run_common import random_unit, run_fold, write_run_file, xi_of


def _small(rng, n=30, cell=6.0):
    fam = np.arange(n) % 2
    return dict(x=rng.uniform(0, cell, size=(n, 3)), p=random_unit(rng, n, 3), radius=0.05, length=1.0,
                xi=xi_of(10.0), family=fam, family_names=("a", "b"), cell_lengths=(cell, cell, cell), dt=0.01)


def test_results_open_with_xarray_and_carry_units(tmp_path):
    xr = pytest.importorskip("xarray")
    rng = np.random.default_rng(4)
    path = tmp_path / "r.h5"
    kw = _small(rng)
    write_run_file(path, **kw, t_end=0.25, output_every=10, snapshot_every=10, checkpoint_every=10)
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stderr
    progress = [ln for ln in proc.stdout.splitlines() if ln.startswith("PROGRESS")]
    assert progress and progress[-1].split()[1:3] == ["25", "25"]
    ds = xr.open_dataset(path, engine="h5netcdf")
    # records at 0, 10, 20 and the final step 25
    np.testing.assert_array_equal(ds.step.values, [0, 10, 20, 25])
    np.testing.assert_allclose(ds.time.values, ds.step.values * 0.01, rtol=0, atol=1e-15)
    assert ds.a2.dims == ("time", "i", "j") and ds.a4.dims == ("time", "i", "j", "k", "l")
    assert ds.a2_family.dims == ("time", "family", "i", "j")
    assert ds.x.dims == ("snapshot", "particle", "xyz")
    for name in ("time", "a2", "a4", "min_gap", "snapshot_time", "x", "p", "unit_norm_drift"):
        assert ds[name].attrs["units"] and ds[name].attrs["long_name"], name
    assert ds.attrs["status"] == "ok" and int(ds.attrs["steps_done"]) == 25 and int(ds.attrs["mpi_ranks"]) == 1
    assert ds.attrs["fortran_creator"].startswith("fold_run ")
    # a2 is the number average of the snapshot axes, and the families split it
    p = ds.p.values[-1]
    np.testing.assert_allclose(ds.a2.values[-1], p.T @ p / len(p), atol=1e-14)
    fam = kw["family"]
    pa = p[fam == 0]
    np.testing.assert_allclose(ds.a2_family.values[-1, 0], pa.T @ pa / len(pa), atol=1e-14)
    np.testing.assert_allclose(np.trace(ds.a2.values, axis1=1, axis2=2), 1.0, atol=1e-14)
    # positions are wrapped into the primary cell
    assert np.all((ds.x.values >= 0) & (ds.x.values < 6.0))
    with h5py.File(path) as f:
        assert f["/checkpoint/step"][()] == 25
        np.testing.assert_array_equal(f["/checkpoint/p"][()], f["p"][-1])


def test_resume_from_checkpoint_continues_exactly(tmp_path):
    """Run 0 -> 20 steps in one go, and 0 -> 10 then --resume to 20 (t_end raised):
    records and snapshots must agree bit for bit."""
    rng = np.random.default_rng(5)
    kw = _small(rng)
    full, part = tmp_path / "full.h5", tmp_path / "part.h5"
    write_run_file(full, **kw, t_end=0.2, output_every=5, snapshot_every=5, checkpoint_every=5)
    write_run_file(part, **kw, t_end=0.1, output_every=5, snapshot_every=5, checkpoint_every=5)
    assert run_fold(full).returncode == 0
    assert run_fold(part).returncode == 0
    with h5py.File(part, "a") as f:
        f["/setup/resolved/t_end"][()] = 0.2
    proc = run_fold(part, resume=True)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(full) as a, h5py.File(part) as b:
        for name in ("step", "time", "a2", "a4", "min_gap", "snapshot", "x", "p"):
            np.testing.assert_array_equal(a[name][()], b[name][()], err_msg=name)
        assert b.attrs["steps_done"] == 20 and b.attrs["status"] == "ok"


def test_rerun_without_resume_refuses_a_file_with_results(tmp_path):
    rng = np.random.default_rng(6)
    path = tmp_path / "r.h5"
    write_run_file(path, **_small(rng), t_end=0.02)
    assert run_fold(path).returncode == 0
    proc = run_fold(path)
    assert proc.returncode == 2 and "--resume" in proc.stderr


def test_np1_and_np2_give_the_same_statistics_in_a_contact_heavy_fibre_scene(tmp_path):
    """Replicated state, block-owned kinematics and contact corrections summed over
    ranks: the two runs may differ only by the order of the rank sum (round-off)."""
    pytest.importorskip("pyfold.native.geometry")
    from test_run_collisions import fibre_scene

    scene = fibre_scene()
    out = {}
    for ranks in (1, 2):
        path = tmp_path / f"np{ranks}.h5"
        write_run_file(path, **scene, t_end=0.1, collisions=2, contact_max_iter=100, on_contact_cap=1,
                       output_every=1, snapshot_every=10)
        proc = run_fold(path, np_ranks=ranks)
        assert proc.returncode == 0, proc.stderr
        with h5py.File(path) as f:
            out[ranks] = {k: f[k][()] for k in ("a2", "a4", "min_gap", "n_corrections", "x", "p")}
            assert f.attrs["mpi_ranks"] == ranks
    assert out[1]["n_corrections"].sum() > 100
    np.testing.assert_array_equal(out[1]["n_corrections"], out[2]["n_corrections"])
    for k in ("a2", "a4", "min_gap", "x", "p"):
        assert np.max(np.abs(out[1][k] - out[2][k])) <= 1e-12, k
