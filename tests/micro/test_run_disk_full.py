"""fold_run on a full disk: the first failed write stops the run.

A run whose output does not fit on its file system must stop at the first failed
HDF5 call (often a dataset close or a flush: HDF5's caches write the data there)
with exit status 1, within seconds, naming the I/O failure, the dataset and the
step; no signal (an older fold_run ignored the failed closes, ran on and crashed
with SIGSEGV in HDF5's termination). The file keeps its last good state: whole
records and snapshots only (``records_complete`` / ``snapshots_complete``) that are
those of an uninterrupted run bit for bit, the checkpoint written before the failure,
from which ``--resume`` finishes the run like an uninterrupted one once there is
space; the root attribute ``status`` says ``failed: ... I/O ...`` (best effort: when
even that cannot be written, stderr says so).

The full disk is real: a 2 MiB tmpfs mounted for the test (we run as root). Where
mount is not permitted, a 2 MiB file-size limit (RLIMIT_FSIZE, soft) stands in for
it: fold_run ignores SIGXFSZ, so a write past the limit fails with EFBIG like a write
to a full disk.
"""
from __future__ import annotations

import os
import re
import resource
import shutil
import signal
import subprocess
import time

import h5py
import numpy as np
import pytest

from test_run_common import random_unit, require_fold_run, run_fold, write_run_file, xi_of

#: Size of the full disk (tmpfs) or the file-size limit [bytes]
DISK = 2 << 20
#: Datasets the file keeps bit for bit like an uninterrupted run (up to the last whole entry)
COMPARED = ("step", "time", "a2", "a4", "a2_family", "min_gap", "n_corrections", "snapshot", "snapshot_time",
            "x", "p")


def _scene(path, t_end=2.0):
    """1000 fibres, a record and a snapshot (48 kB) every step, a checkpoint every 5:
    about 15 MB over 200 steps, 2 MiB fill after some 25 steps."""
    n = 1000
    rng = np.random.default_rng(1)
    write_run_file(path, x=rng.uniform(0, 10, size=(n, 3)), p=random_unit(rng, n, 3), radius=0.01, length=0.5,
                   xi=xi_of(10.0), cell_lengths=(10.0, 10.0, 10.0), dt=0.01, t_end=t_end, output_every=1,
                   snapshot_every=1, checkpoint_every=5)
    with h5py.File(path, "a") as f:  # what pyfold.open_run needs of the scene layer
        f["setup"].create_dataset("scene_toml", data=np.array(b"# test", dtype=h5py.string_dtype("utf-8", 6)))
        f["setup"].create_dataset("scene_json", data=np.array(b"{}", dtype=h5py.string_dtype("utf-8", 2)))


@pytest.fixture
def full_disk(tmp_path):
    """(directory, how): a 2 MiB tmpfs mounted at `directory` ("tmpfs"), or a plain
    directory whose files fold_run may grow to 2 MiB only ("fsize")."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK}", "tmpfs", str(disk)],
                             capture_output=True).returncode == 0
    try:
        yield disk, ("tmpfs" if mounted else "fsize")
    finally:
        if mounted and subprocess.run(["umount", str(disk)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def _limited():
    """preexec_fn of the "fsize" fallback: soft file-size limit, SIGXFSZ ignored."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (DISK, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))


def _run_on(path, how, timeout=60.0):
    if how == "tmpfs":
        return run_fold(path, timeout=timeout)
    # run_fold takes no preexec_fn: the same command and environment, with the limit
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               PMIX_MCA_gds="hash")  # PMIx's shared-memory store would itself exceed the limit
    return subprocess.run([str(require_fold_run()), str(path)], capture_output=True, text=True, timeout=timeout,
                          env=env, preexec_fn=_limited)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The same run, uninterrupted, on a disk with space."""
    require_fold_run()
    path = tmp_path_factory.mktemp("disk_full_ref") / "ref.h5"
    _scene(path)
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stderr
    return path


def test_a_full_disk_stops_the_run_at_once_keeping_the_last_good_state(full_disk, reference, tmp_path):
    import pyfold

    disk, how = full_disk
    path = disk / "run.h5"
    _scene(path)
    start = time.monotonic()
    proc = _run_on(path, how)
    elapsed = time.monotonic() - start

    # exit 1 (not a signal: the old fold_run ran on and crashed with SIGSEGV), at once
    assert proc.returncode == 1, (proc.returncode, proc.stderr[-3000:])
    assert elapsed < 30.0, elapsed
    err = proc.stderr
    assert "Program received signal" not in err and "Backtrace" not in err, err
    cause = "No space left on device" if how == "tmpfs" else "File too large"
    failure = [line for line in err.splitlines() if line.startswith("fold_run: failed: step ")]
    assert len(failure) == 1, err
    line = failure[0]
    assert ": I/O: writing the outputs of step " in line and cause in line, line
    assert re.search(r" failed: /[a-z0-9_]+(/[a-z0-9_]+)?: ", line), line  # names the dataset
    failed_step = int(line.split("failed: step ")[1].split(",")[0])
    assert 0 < failed_step < 200  # it did not run on to the end
    # stdout: no progress beyond the failing step
    progress = [int(l.split()[1]) for l in proc.stdout.splitlines() if l.startswith("PROGRESS")]
    assert not progress or max(progress) < failed_step

    # the file reads up to its last whole record and snapshot, equal to the uninterrupted run
    with h5py.File(path) as f:
        status = f.attrs["status"]
        status = status.decode() if isinstance(status, bytes) else str(status)
        records = int(f.attrs["records_complete"])
        snapshots = int(f.attrs["snapshots_complete"])
        ckpt = int(f["checkpoint/step"][()])
        assert 0 < records <= failed_step + 1 and 0 < snapshots <= failed_step + 1
        with h5py.File(reference) as r:
            for name in COMPARED:
                n = snapshots if name in ("snapshot", "snapshot_time", "x", "p") else records
                np.testing.assert_array_equal(f[name][:n], r[name][:n], err_msg=name)
    if "could not be recorded" in err:  # best effort: the status write itself failed
        assert status == "running", status
    else:
        assert status.startswith(f"failed: step {failed_step}, t = ") and ": I/O: " in status and cause in status
    ds = pyfold.open_run(path)
    try:
        assert ds.sizes["time"] == records and ds.sizes["snapshot"] == snapshots
        assert int(ds.step.values[-1]) == records - 1 and np.isfinite(ds.a2.values).all()
        assert np.isfinite(ds.x.values).all()
    finally:
        ds.close()

    # once there is space, --resume finishes it like the uninterrupted run, bit for bit
    moved = tmp_path / "moved.h5"
    shutil.copyfile(path, moved)
    assert 0 < ckpt <= failed_step
    proc = run_fold(moved, resume=True)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(moved) as f, h5py.File(reference) as r:
        assert f.attrs["status"] == "ok" and f.attrs["steps_done"] == 200
        for name in COMPARED:
            np.testing.assert_array_equal(f[name][()], r[name][()], err_msg=name)


def test_write_xdmf_of_an_unreadable_file_is_an_error_not_a_traceback(tmp_path):
    """``pyfold run`` writes the XDMF after a failed run too: a file HDF5 cannot open
    (as a full disk can leave it) gives a PyfoldError with the cause."""
    from pyfold.errors import PyfoldError
    from pyfold.run_results import write_xdmf

    path = tmp_path / "broken.h5"
    path.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    with pytest.raises(PyfoldError, match="cannot be opened as an HDF5 file"):
        write_xdmf(path)
    assert not path.with_suffix(".xmf").exists()
