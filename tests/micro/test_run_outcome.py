"""fold_run writes the outcome attributes beside the status: a completed run, a run
stopped by its contact cap and a NaN blow-up each say what happened, at which step
and time, with the same cause as the human-readable status."""
from __future__ import annotations

import math

import h5py
import numpy as np

from pyfold.outcome import read_outcome
from test_run_common import random_unit, run_fold, write_run_file, xi_of


def _fibres(rng, n=8, cell=6.0):
    return dict(x=rng.uniform(0, cell, size=(n, 3)), p=random_unit(rng, n, 3), radius=0.05, length=1.0,
                xi=xi_of(10.0), cell_lengths=(cell, cell, cell))


def test_completed_run_has_outcome_completed_at_its_last_step(tmp_path):
    path = tmp_path / "ok.h5"
    write_run_file(path, **_fibres(np.random.default_rng(1)), dt=0.1, t_end=0.5)
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(path) as f:
        assert f.attrs["status"] == "ok"
        assert f.attrs["outcome"] == "completed"
        assert f.attrs["outcome_step"] == 5 == f.attrs["steps_done"]
        assert math.isclose(f.attrs["outcome_time"], 0.5)
        assert f.attrs["outcome_cause"] == ""
        assert math.isnan(f.attrs["outcome_residual"])  # no Stokes solver
    assert read_outcome(path).completed


def test_contact_cap_outcome_names_the_failing_step_and_cause(tmp_path):
    from test_run_collisions import seed_disks

    path = tmp_path / "cap.h5"
    write_run_file(path, **seed_disks(), t_end=2.0, collisions=2, contact_max_iter=1, on_contact_cap=0,
                   output_every=1, snapshot_every=5)
    proc = run_fold(path)
    assert proc.returncode == 1, proc.stderr
    with h5py.File(path) as f:
        status = f.attrs["status"]
        failed = int(status.split("step ")[1].split(",")[0])
        assert f.attrs["outcome"] == "contact_cap"
        assert f.attrs["outcome_step"] == failed == f.attrs["steps_done"] + 1
        assert math.isclose(f.attrs["outcome_time"], failed * f["/setup/resolved/dt"][()])
        assert status.endswith(": " + f.attrs["outcome_cause"])
        assert "security zone" in f.attrs["outcome_cause"]
    o = read_outcome(path)
    assert (o.code, o.step) == ("contact_cap", failed) and not o.completed


def test_nan_blow_up_outcome(tmp_path):
    rng = np.random.default_rng(2)
    kw = _fibres(rng)
    kw["x"][:, 1] = 3.0  # y = Ly/2: u = 0, so the NaN (not the displacement check) stops the run
    path = tmp_path / "nan.h5"
    write_run_file(path, **kw, dt=1e300, t_end=1e301)
    proc = run_fold(path)
    assert proc.returncode == 1, proc.stderr
    o = read_outcome(path)
    assert (o.code, o.step, o.time) == ("blow_up", 1, 1e300)
    assert "NaN" in o.cause and o.status.startswith("failed: step 1,") and o.status.endswith(": " + o.cause)


def test_stokes_non_convergence_outcome_carries_the_residual_reached(tmp_path):
    """A Stokes solve capped at 4 CG iterations fails at step 1: outcome not_converged,
    with the residual the record holds."""
    path = tmp_path / "nc.h5"
    x = np.array([[0.3, 0.3, 0.3], [0.7, 0.6, 0.6]])
    write_run_file(path, x=x, p=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], radius=0.1, length=[0.2, 0.3],
                   xi=[0.0, xi_of(1.5)], shape=[2, 3], dt=0.02, t_end=0.1,
                   stokes={"stokes_grid": (24, 24, 24), "stokes_max_iterations": 4})
    proc = run_fold(path)
    assert proc.returncode == 1, proc.stderr
    with h5py.File(path) as f:
        residual = f["stokes_residual"][-1]
    o = read_outcome(path)
    assert (o.code, o.step) == ("not_converged", 1)
    assert o.residual == residual > 1e-6
    assert "not converged" in o.cause and o.status.endswith(": " + o.cause)
