"""The Slurm executor against a real single-node Slurm (scripts/slurm_local).

A sweep of 4 runs is submitted as a job array; once two runs are running and have
written a checkpoint, one is cancelled with ``scancel`` and the other loses its
fold_run to ``kill -9``. ``pyfold sweep run`` again resubmits both, which resume from
their checkpoints (their second attempt starts from ``interrupted`` and pyfold run
says it resumes), and the gathered dataset equals, value for value, the same sweep run
by the local executor: resuming is exact (the run files resume bit for bit), so no
tolerance applies. A run with np = 2 under Slurm (mpirun inside the allocation) equals
the local np = 2 run record for record.
"""
from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import h5py
import numpy as np
import xarray as xr

from _sweep_helpers import (EXAMPLE_SCENE, example_sweep, no_traceback, pyfold, slurm,  # slurm: a fixture
                            wait_for, write_sweep)
from pyfold.sweep import slurm as slurm_executor
from pyfold.sweep import store
from pyfold.sweep.gather import COST_VARIABLES

#: Strain of the runs: 1.2 x 10^4 steps of 48 and 56 fibres, long enough to be caught mid-run
#: after a checkpoint (one every tenth of the run), seconds of fold_run each.
T_END = 120.0


def _fold_run_pids(folder: Path) -> list[int]:
    """Pids of fold_run processes writing the run in ``folder``."""
    pids = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if argv and argv[0].endswith(b"fold_run") and any(str(folder).encode() in a for a in argv):
            pids.append(int(proc.name))
    return pids


def _checkpointed(folder: Path) -> bool:
    """The run's partial file holds a checkpoint past step 0 (read while fold_run writes it)."""
    try:
        with h5py.File(folder / store.PARTIAL, "r", locking=False) as f:
            return "checkpoint" in f and int(f["checkpoint/step"][()]) > 0
    except (OSError, KeyError, ValueError, RuntimeError):
        return False


def _running_with_checkpoint(root: Path, ids: list[str]) -> list[str]:
    return [rid for rid in ids if _fold_run_pids(store.run_folder(root, rid))
            and _checkpointed(store.run_folder(root, rid))]


def _dataset(root: Path) -> xr.Dataset:
    with xr.open_dataset(root / "sweep.nc", engine="h5netcdf") as ds:
        return ds.load().drop_vars(list(COST_VARIABLES))


def test_cancelled_and_killed_jobs_resume(tmp_path, slurm):
    sweep = example_sweep(tmp_path, t_end=T_END, counts=(48, 56))
    out = tmp_path / "slurm"
    proc = pyfold("sweep", "run", str(sweep), "--out", str(out), "--executor", "slurm", "--no-wait", env=slurm)
    no_traceback(proc)
    assert proc.returncode == 0 and "submitted as job array" in proc.stdout, proc.stderr
    ids = store.unique_runs(store.read_manifest(out))
    assert len(ids) == 4
    caught = wait_for(lambda: (lambda r: r if len(r) >= 2 else None)(_running_with_checkpoint(out, ids)),
                      600, "two runs running under Slurm with a checkpoint")
    cancelled, killed = caught[:2]
    tasks = slurm_executor.task_of(slurm_executor.read_jobs(out))
    job, index = tasks[cancelled]
    subprocess.run(["scancel", f"{job}_{index}"], check=True, env=slurm, timeout=60)
    for pid in _fold_run_pids(store.run_folder(out, killed)):
        os.kill(pid, signal.SIGKILL)

    def array_ended():
        env_before = os.environ.get("SLURM_CONF")
        os.environ["SLURM_CONF"] = slurm["SLURM_CONF"]
        try:
            return not slurm_executor.queue([job])
        finally:
            if env_before is None:
                os.environ.pop("SLURM_CONF")
            else:
                os.environ["SLURM_CONF"] = env_before

    wait_for(array_ended, 900, "the job array to end", step=1.0)
    for rid in (cancelled, killed):
        assert store.run_state(store.run_folder(out, rid)).state == "interrupted", rid
    status = pyfold("sweep", "status", str(out), env=slurm)
    assert status.stdout.count("interrupted") >= 2, status.stdout

    again = pyfold("sweep", "run", str(sweep), "--out", str(out), "--executor", "slurm", env=slurm)
    no_traceback(again)
    assert again.returncode == 0, again.stderr
    assert "2 run(s) submitted" in again.stdout, again.stdout
    for rid in ids:
        assert store.run_state(store.run_folder(out, rid)).state == "done"
    for rid in (cancelled, killed):
        attempts = store.attempts(store.run_folder(out, rid))
        assert [a["from"] for a in attempts][-1] == "interrupted", attempts
        assert all(a["job"] for a in attempts)  # every attempt ran as a Slurm task
        new_job, new_index = slurm_executor.task_of(slurm_executor.read_jobs(out))[rid]
        log = (out / "slurm" / f"{new_job}_{new_index}.out").read_text()
        assert "from its last checkpoint" in log, log

    local = tmp_path / "local"
    proc = pyfold("sweep", "run", str(sweep), "--out", str(local), env=slurm)
    assert proc.returncode == 0, proc.stderr
    for root in (out, local):
        proc = pyfold("sweep", "gather", str(root), "--closures", "exact", "--no-reports", env=slurm)
        assert proc.returncode == 0, proc.stderr
    xr.testing.assert_identical(_dataset(out), _dataset(local))


def test_two_ranks_under_slurm_equal_local(tmp_path, slurm):
    sweep = write_sweep(tmp_path / "np2.toml", f'''[sweep]
scene = "{EXAMPLE_SCENE}"
seeds = [3]
[arguments]
"particles[0].count" = 48
[resources]
np = 2
''')
    out = tmp_path / "slurm"
    proc = pyfold("sweep", "run", str(sweep), "--out", str(out), "--executor", "slurm", env=slurm)
    no_traceback(proc)
    assert proc.returncode == 0, proc.stderr
    (rid,) = store.unique_runs(store.read_manifest(out))
    folder = store.run_folder(out, rid)
    assert store.attempts(folder)[-1]["np"] == 2
    local = tmp_path / "local.h5"
    proc = pyfold("run", str(folder / store.SCENE), "-o", str(local), "--np", "2", env=slurm)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(folder / store.RUN_FILE, "r") as a, h5py.File(local, "r") as b:
        assert int(a["setup/resolved/n_steps"][()]) > 0
        for name in ("a2", "a4", "time"):
            np.testing.assert_array_equal(a[name][()], b[name][()], err_msg=name)
