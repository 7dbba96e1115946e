"""Integrity of run files after a kill: checkpoints are atomic and verified, records
are whole or absent.

A kill of ``fold_run`` can stop it anywhere, also inside a checkpoint or a record
write. The states such a kill leaves are made here with h5py (and, in a bounded
loop, with real SIGKILLs): ``fold_run --resume`` must either continue bit for bit
like an uninterrupted run (from the last complete checkpoint) or refuse with exit 2
naming the cause, never finish "ok" with a different state; ``pyfold.open_run``
must return whole records only.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time

import h5py
import numpy as np
import pytest
import tomli_w

from test_run_common import random_unit, require_fold_run, run_fold, write_run_file, xi_of

#: Datasets an uninterrupted and a resumed run must agree on bit for bit
COMPARED = ("step", "time", "a2", "a4", "a2_family", "min_gap", "n_corrections", "snapshot", "snapshot_time",
            "x", "p")


def _small(seed=5, n=30, cell=6.0):
    rng = np.random.default_rng(seed)
    return dict(x=rng.uniform(0, cell, size=(n, 3)), p=random_unit(rng, n, 3), radius=0.05, length=1.0,
                xi=xi_of(10.0), family=np.arange(n) % 2, family_names=("a", "b"), cell_lengths=(cell, cell, cell),
                dt=0.01, collisions=1, alpha=0.005)


def _assert_same_run(reference, resumed, steps):
    with h5py.File(reference) as a, h5py.File(resumed) as b:
        for name in COMPARED:
            np.testing.assert_array_equal(a[name][()], b[name][()], err_msg=name)
        for name in ("step", "time", "x", "p", "v", "omega"):
            np.testing.assert_array_equal(a["checkpoint"][name][()], b["checkpoint"][name][()], err_msg=name)
        assert b.attrs["status"] == "ok" and b.attrs["steps_done"] == steps
        assert b.attrs["records_complete"] == a["step"].shape[0] == b["step"].shape[0]
        for name in ("step", "x", "p", "v", "omega", "checksum"):
            np.testing.assert_array_equal(b["checkpoint"][name][()], b["checkpoint_shadow"][name][()], err_msg=name)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """An uninterrupted run 0 -> 20 steps, and runs 0 -> 10 and 0 -> 15 (checkpoints
    every 5 steps) whose t_end is raised to the full run's, so that --resume continues
    them to 20."""
    require_fold_run()
    tmp = tmp_path_factory.mktemp("integrity")
    paths = {name: tmp / f"{name}.h5" for name in ("full", "part", "mid")}
    kw = _small()
    for name, t_end in (("full", 0.2), ("part", 0.1), ("mid", 0.15)):
        write_run_file(paths[name], **kw, t_end=t_end, output_every=5, snapshot_every=5, checkpoint_every=5)
        proc = run_fold(paths[name])
        assert proc.returncode == 0, proc.stderr
    for name, step in (("part", 10), ("mid", 15)):
        with h5py.File(paths[name], "a") as f:
            f["/setup/resolved/t_end"][()] = 0.2
            assert f["/checkpoint/step"][()] == step
    with h5py.File(paths["full"]) as f:
        # the run moves: arrays of another step are a different state
        assert np.abs(f["x"][3] - f["x"][2]).max() > 1e-3
    return paths


def _torn(f, copy, ref):
    """Overwrite the copy `copy` (a group) partly with the state of step 10 (snapshot 2
    of the reference run), as a kill in the middle of writing it leaves it."""
    f[copy]["x"][()] = ref["x"][2]


# Kill states of a run checkpointing at step 15 after a complete checkpoint at step 10,
# made from the run 0 -> 15 (both copies of step 15, records up to 15). A checkpoint
# is written into /checkpoint_shadow first, then into /checkpoint.
def _killed_writing_the_shadow(f, ref):
    """The shadow (written first) is torn; /checkpoint still holds step 10 (set by the test)."""
    _torn(f, "checkpoint_shadow", ref)


def _killed_writing_the_checkpoint(f, ref):
    """The shadow of step 15 is complete, /checkpoint torn between steps 10 and 15."""
    _torn(f, "checkpoint", ref)


def _killed_writing_the_first_shadow(f, ref):
    """Killed while the first checkpoint ever is written: a torn shadow, no /checkpoint."""
    del f["checkpoint"]
    _torn(f, "checkpoint_shadow", ref)


@pytest.mark.parametrize("tear", [_killed_writing_the_shadow, _killed_writing_the_checkpoint])
def test_resume_uses_the_last_complete_checkpoint_copy(runs, tmp_path, tear):
    path = tmp_path / "torn.h5"
    shutil.copy(runs["mid"], path)
    with h5py.File(path, "a") as f, h5py.File(runs["full"]) as ref, h5py.File(runs["part"]) as part:
        if tear is _killed_writing_the_shadow:
            # /checkpoint: the complete checkpoint of step 10
            for name in part["checkpoint"]:
                f["checkpoint"][name][()] = part["checkpoint"][name][()]
        tear(f, ref)
    proc = run_fold(path, resume=True)
    assert proc.returncode == 0, proc.stderr
    _assert_same_run(runs["full"], path, 20)


@pytest.mark.parametrize("what", ["x", "p", "omega", "step"])
def test_resume_refuses_when_no_complete_checkpoint_is_left(runs, tmp_path, what):
    """The reported defect: /checkpoint/step of one step, positions (or axes, or
    velocities) of another; here in both copies. Exit 2, naming the cause."""
    path = tmp_path / "torn.h5"
    shutil.copy(runs["mid"], path)
    with h5py.File(path, "a") as f, h5py.File(runs["full"]) as ref:
        for copy in ("checkpoint", "checkpoint_shadow"):
            if copy not in f:
                continue
            g = f[copy]
            if what == "step":
                g["step"][()] = 10
            elif what == "omega":
                g["omega"][()] = 2.0 * g["omega"][()] + 1.0
            else:
                g[what][()] = ref[what][2]
    proc = run_fold(path, resume=True)
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "no complete checkpoint" in proc.stderr, proc.stderr
    assert "/checkpoint: checksum mismatch" in proc.stderr and "/checkpoint_shadow: checksum mismatch" in proc.stderr
    with h5py.File(path) as f:
        assert f.attrs["status"] == "ok" and f.attrs["steps_done"] == 15  # the file is left as it was


def test_resume_refuses_a_torn_first_checkpoint(runs, tmp_path):
    path = tmp_path / "torn.h5"
    shutil.copy(runs["mid"], path)
    with h5py.File(path, "a") as f, h5py.File(runs["full"]) as ref:
        _killed_writing_the_first_shadow(f, ref)
    proc = run_fold(path, resume=True)
    assert proc.returncode == 2 and "/checkpoint_shadow: checksum mismatch" in proc.stderr, proc.stderr


def test_a_checkpoint_of_an_older_fold_run_without_checksum_still_resumes(runs, tmp_path):
    """Old layout: /checkpoint without checksum, no shadow, no record counts."""
    path = tmp_path / "old.h5"
    shutil.copy(runs["part"], path)
    with h5py.File(path, "a") as f:
        del f["checkpoint/checksum"]
        del f["checkpoint_shadow"]
        for name in ("records_complete", "snapshots_complete"):
            del f.attrs[name]
    proc = run_fold(path, resume=True)
    assert proc.returncode == 0, proc.stderr
    assert "no checksum" in proc.stderr
    _assert_same_run(runs["full"], path, 20)


def test_checkpoint_copies_are_overwritten_in_place(runs):
    """After the first checkpoint no link or dataset is created or removed (the
    file's metadata, which a kill could leave half-written, stays as it is): each
    copy's datasets keep their addresses, and both copies hold the same state."""
    with h5py.File(runs["mid"]) as f:
        for name in ("x", "p", "v", "omega", "step", "time", "checksum"):
            np.testing.assert_array_equal(f["checkpoint"][name][()], f["checkpoint_shadow"][name][()])
        offsets = {name: f["checkpoint"][name].id.get_offset() for name in ("x", "p", "v", "omega")}
    path = runs["mid"].parent / "mid_resumed.h5"
    shutil.copy(runs["mid"], path)
    assert run_fold(path, resume=True).returncode == 0
    with h5py.File(path) as f:
        assert f["/checkpoint/step"][()] == 20
        assert {name: f["checkpoint"][name].id.get_offset() for name in offsets} == offsets


def test_random_sigkills_resume_bitwise_or_refuse(tmp_path):
    """Real kills at random times of a run that checkpoints every step: each resume
    either reproduces the uninterrupted run bit for bit or is refused with exit 2."""
    exe = require_fold_run()
    kw = _small(seed=11, n=40)
    steps = 400
    setup = dict(**kw, t_end=steps * 0.01, output_every=1, snapshot_every=7, checkpoint_every=1)
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")

    def start(path):
        """Start fold_run; return it and the time its first PROGRESS line (step loop) came."""
        proc = subprocess.Popen([str(exe), str(path)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                env=env, text=True)
        for line in proc.stdout:
            if line.startswith("PROGRESS"):
                break
        return proc, time.monotonic()

    ref = tmp_path / "ref.h5"
    write_run_file(ref, **setup)
    proc, t0 = start(ref)
    proc.stdout.read()
    assert proc.wait() == 0
    stepping = time.monotonic() - t0
    rng = np.random.default_rng(2024)
    outcomes = []
    deadline = time.monotonic() + 40.0
    for trial in range(6):
        if time.monotonic() > deadline:
            break
        path = tmp_path / f"kill{trial}.h5"
        write_run_file(path, **setup)
        proc, t0 = start(path)
        time.sleep(max(0.0, t0 + rng.uniform(0.05, 0.95) * stepping - time.monotonic()))
        proc.send_signal(signal.SIGKILL)
        proc.stdout.close()
        proc.wait()
        res = run_fold(path, resume=True)
        if res.returncode == 0:
            _assert_same_run(ref, path, steps)
            outcomes.append("bitwise")
        else:
            assert res.returncode == 2 and res.stderr.startswith("fold_run:"), (res.returncode, res.stderr)
            outcomes.append("refused: " + res.stderr.strip()[:300])
    assert outcomes and "bitwise" in outcomes, outcomes


# ------------------------------------------------------------------ records


def _scene_run_file(tmp, name, t_end):
    """A run file made by the scene layer (open_run needs /setup/scene_*)."""
    from pyfold.run_input import write_run_file as write_scene_run_file
    from pyfold.scene import load_scene
    from pyfold.scene.initial import initial_state

    scene = {
        "cell": {"dim": 3, "size": [4.0, 4.0, 4.0]},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [{"name": "fibres", "shape": "fibre", "radius": 0.05, "length": 1.0, "count": 24,
                       "orientation": "isotropic"}],
        "model": {"hydrodynamics": "jeffery", "collisions": "auto"},
        "numerics": {"dt": 0.01, "t_end": t_end, "seed": 3},
        "output": {"interval": 0.02, "snapshot_interval": 0.1, "checkpoint_interval": 0.1},
    }
    toml = tmp / f"{name}.toml"
    toml.write_text(tomli_w.dumps(scene), encoding="utf-8")
    resolved = load_scene(toml)
    path = tmp / f"{name}.h5"
    write_scene_run_file(path, resolved, initial_state(resolved), "test_run_integrity")
    return path


def test_a_torn_last_record_is_dropped_by_open_run_and_by_resume(tmp_path):
    """Killed while appending the record of step 14 (checkpoint at step 10): some
    record datasets are one longer than others, records_complete says 7."""
    import pyfold
    from pyfold.run_results import write_xdmf

    require_fold_run()
    full = _scene_run_file(tmp_path, "full", 0.2)
    part = _scene_run_file(tmp_path, "part", 0.1)
    for path in (full, part):
        proc = run_fold(path)
        assert proc.returncode == 0, proc.stderr
    torn = tmp_path / "torn.h5"
    shutil.copy(full, torn)
    with h5py.File(torn, "a") as f, h5py.File(part) as p:
        assert p["/checkpoint/step"][()] == 10
        for copy in ("checkpoint", "checkpoint_shadow"):  # the newest complete checkpoint: step 10
            if copy in f:
                del f[copy]
            if copy in p:
                p.copy(copy, f)
        steps = f["step"][()]
        keep = int(np.count_nonzero(steps <= 14))  # records 0, 2, ..., 14
        assert keep == 8
        for name, d in f.items():
            if isinstance(d, h5py.Dataset) and d.ndim >= 1 and d.dims[0] and d.dims[0][0].name == "/time":
                d.resize(keep, axis=0)
        f["time"].resize(keep, axis=0)
        f["a2"].resize(keep - 1, axis=0)  # the torn record: a2 not appended yet
        f["min_gap"][keep - 1] = 0.0       # ... min_gap extended, its value not written
        f.attrs["records_complete"] = np.int64(keep - 1)
        snaps = int(np.count_nonzero(f["snapshot"][()] <= 10))
        for name in ("snapshot", "snapshot_time", "x", "p"):
            f[name].resize(snaps, axis=0)
        f.attrs["snapshots_complete"] = np.int64(snaps)
        f.attrs["status"] = "running"
        f.attrs["steps_done"] = np.int64(0)
    with h5py.File(full) as f:
        want_steps = f["step"][: keep - 1]
        want_a2 = f["a2"][: keep - 1]
        want_gap = f["min_gap"][: keep - 1]

    ds = pyfold.open_run(torn)
    try:
        assert ds.sizes["time"] == keep - 1
        np.testing.assert_array_equal(ds.step.values, want_steps)
        np.testing.assert_array_equal(ds.a2.values, want_a2)
        np.testing.assert_array_equal(ds.min_gap.values, want_gap)
    finally:
        ds.close()

    # a file of a fold_run before the counts: the shortest dataset counts (here also a
    # snapshot torn after its x); ParaView gets the whole snapshots only
    old = tmp_path / "old.h5"
    shutil.copy(torn, old)
    with h5py.File(old, "a") as f:
        del f.attrs["records_complete"]
        del f.attrs["snapshots_complete"]
        f["p"].resize(snaps - 1, axis=0)
    ds = pyfold.open_run(old)
    try:
        assert ds.sizes["time"] == keep - 1 and ds.sizes["snapshot"] == snaps - 1
        np.testing.assert_array_equal(ds.a2.values, want_a2)
    finally:
        ds.close()
    xmf = write_xdmf(old).read_text(encoding="utf-8")
    assert xmf.count('<Grid Name="snapshot ') == snaps - 1

    proc = run_fold(torn, resume=True)
    assert proc.returncode == 0, proc.stderr
    _assert_same_run(full, torn, 20)
    ds = pyfold.open_run(torn)
    try:
        assert ds.sizes["time"] == 11 and not np.any(np.all(ds.a2.values == 0.0, axis=(1, 2)))
    finally:
        ds.close()
