"""`pyfold run` never clobbers: -o must not name a file the run writes beside it
(OUT.xmf, OUT.h5.partial), an existing OUT.xmf or OUT.h5.partial is refused before any
work (the latter pointing to --resume / --force), an unwritable -o is a clear exit 2;
and --resume continues an interrupted run to the same final state, bit for bit, as an
uninterrupted one (a dilute Jeffery scene through the real fold_run)."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import base_scene, write_scene
from pyfold.cli import main
from pyfold.integrity import seal
from pyfold.xdmf_files import xdmf_paths


@pytest.fixture
def scene(tmp_path):
    return write_scene(tmp_path / "fibres.toml", base_scene())


@pytest.mark.parametrize("name", ["x.xmf", "x", "x.toml", "x.h5.partial"])
def test_output_must_end_in_h5(scene, tmp_path, fake_fold_run, capsys, name):
    out = tmp_path / name
    assert main(["run", str(scene), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "-o" in err and ".h5" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fibres.toml", "fold_run"]  # nothing written
    for good in ("y.h5", "z.hdf5", "w.nc"):  # the suffixes a run file may have; its XDMF goes beside
        assert main(["run", str(scene), "-o", str(tmp_path / good)]) == 0
        assert (tmp_path / good).is_file() and (tmp_path / good).with_suffix(".xmf").is_file()


def test_existing_xmf_refused_without_force(scene, tmp_path, fake_fold_run, capsys):
    out, xmf = tmp_path / "x.h5", tmp_path / "x.xmf"
    xmf.write_text("<users own XDMF/>")
    assert main(["run", str(scene), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "x.xmf" in err and "--force" in err
    assert xmf.read_text() == "<users own XDMF/>" and not out.exists()
    assert not (tmp_path / "x.h5.partial").exists()
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 0
    assert "<Xdmf" in xmf.read_text()


def test_existing_partial_refused_without_resume_or_force(scene, tmp_path, fake_fold_run, capsys):
    out, partial = tmp_path / "x.h5", tmp_path / "x.h5.partial"
    partial.write_bytes(b"an interrupted run")
    assert main(["run", str(scene), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and "--force" in err and "x.h5.partial" in err
    assert partial.read_bytes() == b"an interrupted run" and not out.exists()
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 0  # start again
    assert out.is_file() and not partial.exists()


def test_unwritable_output_exit_2_naming_o(scene, tmp_path, fake_fold_run, capsys):
    regular = tmp_path / "regular_file"
    regular.write_text("")
    for out in (regular / "x.h5", regular / "sub" / "x.h5"):  # not even root can create these
        assert main(["run", str(scene), "-o", str(out)]) == 2
        err = capsys.readouterr().err
        assert "-o" in err and "not a folder" in err and "Traceback" not in err


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs procfs")
def test_read_only_location_exit_2_before_the_run(scene, fake_fold_run, capsys):
    """/proc takes no new files, not even from root: refused before placement, no traceback."""
    assert main(["run", str(scene), "-o", "/proc/pyfold-test-run.h5"]) == 2
    err = capsys.readouterr().err
    assert "-o" in err and "does not take new files" in err
    assert "fold_run" not in err


def test_resume_without_anything_to_resume(scene, tmp_path, fake_fold_run, capsys):
    out = tmp_path / "x.h5"
    assert main(["run", str(scene), "-o", str(out), "--resume"]) == 2
    assert "nothing to resume" in capsys.readouterr().err
    assert main(["run", str(scene), "-o", str(out)]) == 0
    assert main(["run", str(scene), "-o", str(out), "--resume"]) == 2  # complete: status ok
    assert "status ok" in capsys.readouterr().err


def _jeffery_scene(tmp_path: Path, t_end: float) -> Path:
    """8 fibres in a 4^3 cell: dilute, Jeffery kinematics (deterministic, no contacts)."""
    s = base_scene()
    s["numerics"].update(t_end=t_end, dt=0.01)
    s["output"] = {"interval": 0.05, "snapshot_interval": 0.1, "checkpoint_interval": 0.05}
    return write_scene(tmp_path / f"jeffery_{t_end:g}.toml", s)


@pytest.mark.parametrize("left_as", ["partial", "failed"])
def test_resume_continues_to_the_uninterrupted_result(tmp_path, capsys, monkeypatch, left_as):
    """A run stopped at t = 0.2 (its file left as OUT.h5.partial, or as a failed OUT.h5)
    and continued with --resume to t = 0.4 ends bit for bit like a run of 0.4 in one go;
    the XDMF is rewritten after the resume and shows every snapshot."""
    monkeypatch.delenv("PYFOLD_FOLD_RUN", raising=False)
    long_scene, short_scene = _jeffery_scene(tmp_path, 0.4), _jeffery_scene(tmp_path, 0.2)
    full, out = tmp_path / "full.h5", tmp_path / "out.h5"
    assert main(["run", str(long_scene), "-o", str(full)]) == 0, capsys.readouterr().err
    assert main(["run", str(short_scene), "-o", str(out)]) == 0, capsys.readouterr().err
    # what a run of t_end = 0.4 killed after t = 0.2 leaves: records and a checkpoint up to 0.2
    with h5py.File(out, "a") as f:
        f["/setup/resolved/t_end"][()] = 0.4
        del f["/setup/scene_toml"]
        f["/setup"].create_dataset("scene_toml", data=long_scene.read_text())
        for name in ("/setup/resolved/t_end", "/setup/scene_toml"):  # edited on purpose: checksums renewed
            seal(f[name])
        assert int(f["/checkpoint/step"][()]) == 20
        if left_as == "failed":
            f.attrs["status"] = "failed: step 20, t = 0.2: killed"
    if left_as == "partial":
        out.rename(tmp_path / "out.h5.partial")
        for view in xdmf_paths(out):  # a killed run has written neither
            view.unlink()
    capsys.readouterr()
    assert main(["run", str(long_scene), "-o", str(out), "--resume"]) == 0, capsys.readouterr().err
    assert "resuming" in capsys.readouterr().err
    assert out.is_file() and not (tmp_path / "out.h5.partial").exists()
    with h5py.File(full) as a, h5py.File(out) as b:
        assert b.attrs["status"] == "ok" and int(b.attrs["steps_done"]) == 40
        for name in ("step", "time", "a2", "a4", "x", "p", "snapshot_time"):
            np.testing.assert_array_equal(a[name][()], b[name][()], err_msg=name)
        n_snapshots = b["x"].shape[0]
    assert (tmp_path / "out.xmf").read_text().count("<Grid Name=") >= n_snapshots == 5
