"""`pyfold run SCENE -o OUT.h5 --resume` with a larger t_end extends a run (pyfold.extend).

With the real fold_run: a dilute Jeffery scene (8 fibres, no contacts), deterministic
step by step, so an extension equals a run made in one go bit for bit (every dataset
and its attributes compared with ==, no tolerance); every refusal is exit 2 naming the
key and leaves the run file byte for byte as it was.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import base_scene, write_scene

from pyfold.cli import main
from pyfold.run_input import fixed_string

#: Explicit intervals (steps of dt = 0.01: records every 5, snapshots every 10, checkpoints every 5).
INTERVALS = {"interval": 0.05, "snapshot_interval": 0.1, "checkpoint_interval": 0.05}


def _scene(tmp_path: Path, t_end: float, output: dict | None = INTERVALS, seed: int = 3, name: str = "") -> Path:
    s = base_scene()
    s["numerics"].update(t_end=t_end, dt=0.01, seed=seed)
    if output is None:
        s.pop("output", None)
    else:
        s["output"] = dict(output)
    return write_scene(tmp_path / f"jeffery_{name}{t_end:g}_{seed}.toml", s)


def _datasets(path: Path) -> dict[str, tuple[np.ndarray, dict]]:
    """Every dataset of a run file: its value and its attributes (dimension-scale
    bookkeeping left out: HDF5 object references differ between files)."""
    out: dict[str, tuple[np.ndarray, dict]] = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            attrs = {k: v for k, v in obj.attrs.items() if k not in ("DIMENSION_LIST", "REFERENCE_LIST")}
            out[name] = (obj[()], attrs)

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return out


def _assert_bitwise_equal(a: Path, b: Path) -> None:
    da, db = _datasets(a), _datasets(b)
    assert sorted(da) == sorted(db)
    for name in da:
        (va, aa), (vb, ab) = da[name], db[name]
        va, vb = np.asarray(va), np.asarray(vb)
        assert va.dtype == vb.dtype and va.shape == vb.shape, name
        assert va.tobytes() == vb.tobytes(), f"{name} differs"
        assert sorted(aa) == sorted(ab), name
        for key in aa:
            assert np.asarray(aa[key]).tobytes() == np.asarray(ab[key]).tobytes(), f"{name}@{key} differs"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def real_fold_run(monkeypatch):
    monkeypatch.delenv("PYFOLD_FOLD_RUN", raising=False)


def test_extending_a_complete_run_equals_a_run_made_in_one_go(tmp_path, capsys, real_fold_run):
    short, long = _scene(tmp_path, 0.2), _scene(tmp_path, 0.4)
    full, out = tmp_path / "full.h5", tmp_path / "out.h5"
    assert main(["run", str(long), "-o", str(full)]) == 0, capsys.readouterr().err
    assert main(["run", str(short), "-o", str(out)]) == 0, capsys.readouterr().err
    assert main(["run", str(long), "-o", str(out), "--resume"]) == 0, capsys.readouterr().err
    assert "extending" in capsys.readouterr().err
    assert out.is_file() and not (tmp_path / "out.h5.partial").exists()
    with h5py.File(out) as f:
        assert f.attrs["status"] == "ok" and int(f.attrs["steps_done"]) == 40
    _assert_bitwise_equal(full, out)
    # the XDMF beside it shows every snapshot of the extended run (t = 0, 0.1, ..., 0.4)
    assert (tmp_path / "out.xmf").read_text().count("<Grid Name=") >= 5


def test_extending_a_killed_run_equals_a_run_made_in_one_go(tmp_path, capsys, real_fold_run):
    """A run of t_end = 0.3 killed after its checkpoint at t = 0.2 (OUT.h5.partial, status
    running), resumed with t_end = 0.4."""
    short, mid, long = _scene(tmp_path, 0.2), _scene(tmp_path, 0.3), _scene(tmp_path, 0.4)
    full, out = tmp_path / "full.h5", tmp_path / "out.h5"
    assert main(["run", str(long), "-o", str(full)]) == 0, capsys.readouterr().err
    assert main(["run", str(short), "-o", str(out)]) == 0, capsys.readouterr().err
    from pyfold.scene import load_scene
    from pyfold.run_input import write_setup

    with h5py.File(out, "a") as f:  # what the run of 0.3 left when killed at step 25: a checkpoint at 20
        assert int(f["/checkpoint/step"][()]) == 20
        del f["setup"]
        write_setup(f, load_scene(mid))
        f.attrs["status"] = fixed_string("running")
    out.rename(tmp_path / "out.h5.partial")
    (tmp_path / "out.xmf").unlink()  # a killed run has written no XDMF yet
    (tmp_path / "out.xmf.h5").unlink()
    assert main(["run", str(long), "-o", str(out), "--resume"]) == 0, capsys.readouterr().err
    assert "extending" in capsys.readouterr().err
    _assert_bitwise_equal(full, out)


def test_extension_keeps_the_recorded_default_intervals(tmp_path, capsys, real_fold_run):
    """Intervals left to their defaults scale with t_end (t_end/100, /10, /20): the
    extension keeps the recorded ones, and equals a run made in one go with them set."""
    short, long = _scene(tmp_path, 0.2, output=None), _scene(tmp_path, 0.4, output=None)
    pinned = _scene(tmp_path, 0.4, output={"interval": 0.01, "snapshot_interval": 0.02,
                                           "checkpoint_interval": 0.01}, name="pinned")
    full, out = tmp_path / "full.h5", tmp_path / "out.h5"
    assert main(["run", str(pinned), "-o", str(full)]) == 0, capsys.readouterr().err
    assert main(["run", str(short), "-o", str(out)]) == 0, capsys.readouterr().err
    assert main(["run", str(long), "-o", str(out), "--resume"]) == 0, capsys.readouterr().err
    with h5py.File(out) as f:
        assert [int(f[f"/setup/resolved/{k}"][()]) for k in ("output_every", "snapshot_every",
                                                             "checkpoint_every")] == [1, 2, 1]
    a, b = _datasets(full), _datasets(out)
    for name in a:
        if name in ("setup/scene_toml", "setup/scene_json"):  # the two scene texts differ (intervals written out)
            continue
        assert np.asarray(a[name][0]).tobytes() == np.asarray(b[name][0]).tobytes(), name


@pytest.mark.parametrize("change, key", [
    (lambda s: s["numerics"].update(seed=4), "numerics.seed"),
    (lambda s: s["particles"][0].update(count=9), "particles[0].count"),
    (lambda s: s["output"].update(interval=0.1), "output.interval"),
])
def test_any_other_difference_is_refused_naming_the_key(tmp_path, capsys, real_fold_run, change, key):
    short = _scene(tmp_path, 0.2)
    out = tmp_path / "out.h5"
    assert main(["run", str(short), "-o", str(out)]) == 0, capsys.readouterr().err
    before = _digest(out)
    s = base_scene()
    s["numerics"].update(t_end=0.4, dt=0.01, seed=3)
    s["output"] = dict(INTERVALS)
    change(s)
    other = write_scene(tmp_path / "other.toml", s)
    assert main(["run", str(other), "-o", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err
    assert _digest(out) == before and not (tmp_path / "out.h5.partial").exists()


@pytest.mark.parametrize("t_end", [0.2, 0.1])
def test_a_t_end_not_beyond_the_recorded_one_is_refused(tmp_path, capsys, real_fold_run, t_end):
    out = tmp_path / "out.h5"
    assert main(["run", str(_scene(tmp_path, 0.2)), "-o", str(out)]) == 0, capsys.readouterr().err
    before = _digest(out)
    assert main(["run", str(_scene(tmp_path, t_end, name="x")), "-o", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "t_end" in err and "0.2" in err and "Traceback" not in err
    assert _digest(out) == before and not (tmp_path / "out.h5.partial").exists()


def test_an_end_off_the_record_interval_is_refused(tmp_path, capsys, real_fold_run):
    """A run ending at step 23 with records every 5 steps has a last record a run made in
    one go would not have: refused naming output.interval."""
    out = tmp_path / "out.h5"
    assert main(["run", str(_scene(tmp_path, 0.23, output={"interval": 0.05, "snapshot_interval": 0.0,
                                                           "checkpoint_interval": 0.05})),
                 "-o", str(out)]) == 0, capsys.readouterr().err
    before = _digest(out)
    longer = _scene(tmp_path, 0.4, output={"interval": 0.05, "snapshot_interval": 0.0, "checkpoint_interval": 0.05})
    assert main(["run", str(longer), "-o", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "output.interval" in err and "step 23" in err
    assert _digest(out) == before


def test_setup_checksums_hold_after_an_extension(tmp_path, capsys, real_fold_run):
    """The rewritten /setup is sealed: the extended file verifies, and a change to it is detected."""
    from pyfold.integrity import verify_path

    out = tmp_path / "out.h5"
    assert main(["run", str(_scene(tmp_path, 0.2)), "-o", str(out)]) == 0, capsys.readouterr().err
    assert main(["run", str(_scene(tmp_path, 0.3)), "-o", str(out), "--resume"]) == 0, capsys.readouterr().err
    assert not verify_path(out).damage
    with h5py.File(out, "a") as f:
        assert float(f["/setup/resolved/t_end"][()]) == 0.3
        f["/setup/resolved/t_end"][()] = 0.5  # not sealed again: damage
    assert verify_path(out).damage


def test_extending_a_run_killed_by_a_signal_equals_a_run_made_in_one_go(tmp_path, capsys, real_fold_run):
    """`pyfold run` of t_end = 400 stopped by SIGTERM part-way (exit 143, OUT.h5.partial kept
    with status running), then `--resume` with t_end = 420: the file equals a run of 420
    made in one go. Checkpoints every 50 steps, records every 5: a checkpoint is always on
    a record, so no record sums a partial interval."""
    import os
    import re
    import signal
    import subprocess
    import sys

    from pyfold.progress import MIN_INTERVAL

    output = {"interval": 0.05, "snapshot_interval": 10.0, "checkpoint_interval": 0.5}
    mid, long = _scene(tmp_path, 400.0, output=output), _scene(tmp_path, 420.0, output=output)
    full, out = tmp_path / "full.h5", tmp_path / "out.h5"
    partial = tmp_path / "out.h5.partial"
    # signal once the progress lines (plain: stderr is no terminal) show a step past the
    # first checkpoints and far from the end; a machine that finishes first skips
    proc = subprocess.Popen([sys.executable, "-m", "pyfold.cli", "run", str(mid), "-o", str(out),
                             "--progress-every", str(MIN_INTERVAL)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines = []
    try:
        for line in proc.stderr:
            lines.append(line)
            step = re.search(r"progress step (\d+)/", line)
            if step and 100 <= int(step.group(1)) < 36000:
                os.kill(proc.pid, signal.SIGTERM)
                break
        _, err = proc.communicate(timeout=120)
        err = "".join(lines) + err
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    if proc.returncode == 0 or (out.exists() and not partial.exists()):
        pytest.skip("the run finished before the signal (a very fast machine): nothing was killed")
    assert proc.returncode == 143, err
    with h5py.File(partial) as f:
        assert f.attrs["status"] == "running"
        assert 0 < int(f["/checkpoint/step"][()]) < 40000
    assert main(["run", str(long), "-o", str(out), "--resume"]) == 0, capsys.readouterr().err
    assert "extending" in capsys.readouterr().err
    assert main(["run", str(long), "-o", str(full)]) == 0, capsys.readouterr().err
    _assert_bitwise_equal(full, out)
