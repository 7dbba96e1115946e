"""The local executor: the bundled sweep runs, a second run recomputes nothing, gather marks
incomplete points, and a physical failure is reported with its cause and not retried."""
from __future__ import annotations

import json
import os
import shutil

import numpy as np
import xarray as xr

from _sweep_helpers import EXAMPLE, fake_fold_run, no_traceback, pyfold, write_sweep  # fake_fold_run: a fixture
from pyfold.sweep import store


def _attempts(root) -> dict[str, int]:
    return {p.name: len(store.attempts(p)) for p in (root / "runs").iterdir()}


def test_example_runs_once_and_gathers(tmp_path):
    out = tmp_path / "ex"
    proc = pyfold("sweep", "run", str(EXAMPLE), "--out", str(out))
    no_traceback(proc)
    assert proc.returncode == 0, proc.stderr
    assert "4 done, 0 running, 0 interrupted, 0 queued, 0 failed" in proc.stdout
    # without a terminal: plain progress lines, one per event
    assert sum(" done in " in line for line in proc.stdout.splitlines()) == 4
    runs = json.loads((out / "sweep.json").read_text())["runs"]
    assert len(runs) == 4
    for r in runs:
        assert store.run_state(out / "runs" / r["id"]).state == "done"
    stamps = {p: os.stat(p / "run.h5").st_mtime_ns for p in (out / "runs").iterdir()}
    attempts = _attempts(out)
    assert set(attempts.values()) == {1}

    again = pyfold("sweep", "run", str(EXAMPLE), "--out", str(out))
    assert again.returncode == 0 and "nothing to run" in again.stdout, again.stderr
    assert _attempts(out) == attempts
    assert {p: os.stat(p / "run.h5").st_mtime_ns for p in (out / "runs").iterdir()} == stamps

    # one run lost: gather keeps its point, marked incomplete; the complete point's C_I is there
    lost = out / "runs" / runs[3]["id"]
    (lost / "run.h5").unlink()
    proc = pyfold("sweep", "gather", str(out), "--closures", "exact", "--no-reports")
    no_traceback(proc)
    assert proc.returncode == 0, proc.stderr
    with xr.open_dataset(out / "sweep.nc", engine="h5netcdf") as ds:
        ds = ds.load()
    assert ds["status"].dims == ("particles[0].count", "seed")
    assert ds["status"].sel({"particles[0].count": 48, "seed": 2}).item() == "queued"
    assert list(ds["point_status"].values) == ["complete", "incomplete"]
    assert list(ds["seeds_done"].values) == [2, 1]
    assert np.isnan(ds["a2_mean"].sel({"particles[0].count": 48, "seed": 2})).all()
    assert np.isfinite(ds["a2_mean"].sel({"particles[0].count": 48, "seed": 1})).all()
    # a2 is a unit-trace tensor: the averages keep that to round-off of the records' sums
    trace = ds["a2_mean"].sel(i="x", j="x") + ds["a2_mean"].sel(i="y", j="y") + ds["a2_mean"].sel(i="z", j="z")
    assert np.nanmax(np.abs(trace.values - 1.0)) < 1e-6
    assert np.isfinite(ds["ci"].sel(closure="exact")).all()

    # the sweep completes the lost run again (and only that one)
    proc = pyfold("sweep", "run", str(EXAMPLE), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    now = _attempts(out)
    assert now[runs[3]["id"]] == 2 and all(now[k] == 1 for k in now if k != runs[3]["id"])


def test_physical_failure_reported_not_retried(tmp_path, fake_fold_run, monkeypatch):
    sweep = write_sweep(tmp_path / "one.toml", f'''[sweep]
scene = "{EXAMPLE.parent / 'example_scene.toml'}"
seeds = [1]
''')
    monkeypatch.setenv("FAKE_FOLD_RUN_EXIT", "1")
    out = tmp_path / "out"
    proc = pyfold("sweep", "run", str(sweep), "--out", str(out), env=dict(os.environ))
    no_traceback(proc)
    assert proc.returncode == 1, proc.stderr
    assert "stand-in blow-up" in proc.stderr
    (rid,) = [p.name for p in (out / "runs").iterdir()]
    assert store.run_state(out / "runs" / rid).state == "failed"
    again = pyfold("sweep", "run", str(sweep), "--out", str(out), env=dict(os.environ))
    assert again.returncode == 1 and "stand-in blow-up" in again.stderr
    assert len(store.attempts(out / "runs" / rid)) == 1  # not retried
    status = pyfold("sweep", "status", str(out))
    assert status.returncode == 1 and "failed" in status.stdout and "stand-in blow-up" in status.stdout
    shutil.rmtree(out)
