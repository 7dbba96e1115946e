"""`pyfold run`: orchestration (refusal to overwrite, atomic rename, exit codes, failed
status kept) with a stand-in for fold_run, and one real run of the seed's disks."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

import pyfold
from conftest import base_scene, write_scene
from pyfold.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def scene(tmp_path):
    return write_scene(tmp_path / "fibres.toml", base_scene())


def test_run_writes_results_xdmf_and_summary(scene, tmp_path, fake_fold_run, capsys):
    out = tmp_path / "out.h5"
    assert main(["run", str(scene), "-o", str(out)]) == 0
    assert out.is_file() and not out.with_name("out.h5.partial").exists()
    assert out.with_suffix(".xmf").is_file()
    text = capsys.readouterr().out
    assert "status: ok" in text and "regime: semi-dilute" not in text  # 8 fibres in 64: dilute
    assert "regime: dilute" in text and "collisions = none (auto)" in text and "a2 at t = 0.2" in text
    ds = pyfold.open_run(out)
    try:
        assert ds.attrs["command"].startswith("pyfold run ") and ds.sizes["time"] == 5
    finally:
        ds.close()


def test_existing_output_refused_before_any_work(scene, tmp_path, fake_fold_run, capsys):
    out = tmp_path / "out.h5"
    out.write_bytes(b"precious")
    assert main(["run", str(scene), "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert out.read_bytes() == b"precious" and not out.with_name("out.h5.partial").exists()


def test_force_keeps_old_file_until_the_new_one_is_complete(scene, tmp_path, fake_fold_run, monkeypatch, capsys):
    out = tmp_path / "out.h5"
    out.write_bytes(b"precious")
    monkeypatch.setenv("FAKE_FOLD_RUN_EXIT", "2")  # fold_run rejects the file: nothing complete
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 2
    assert out.read_bytes() == b"precious"
    assert "stand-in rejection" in capsys.readouterr().err
    monkeypatch.setenv("FAKE_FOLD_RUN_EXIT", "0")
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 0
    with h5py.File(out) as f:
        assert f.attrs["status"] == "ok"


def test_failure_exit_1_keeps_partial_results_with_failed_status(scene, tmp_path, fake_fold_run, monkeypatch, capsys):
    out = tmp_path / "out.h5"
    monkeypatch.setenv("FAKE_FOLD_RUN_EXIT", "1")
    assert main(["run", str(scene), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "stand-in blow-up" in err and "last good state" in err
    ds = pyfold.open_run(out)
    try:
        assert ds.attrs["status"].startswith("failed: step") and ds.sizes["time"] == 2
    finally:
        ds.close()


def test_invalid_scene_exit_2_before_fold_run(tmp_path, fake_fold_run, capsys):
    scene = base_scene()
    scene["numerics"]["dt"] = 1.0
    out = tmp_path / "out.h5"
    assert main(["run", str(write_scene(tmp_path / "bad.toml", scene)), "-o", str(out)]) == 2
    assert "numerics.dt" in capsys.readouterr().err
    assert not out.exists() and not out.with_name("out.h5.partial").exists()


def test_np_must_be_positive(scene, tmp_path, capsys):
    assert main(["run", str(scene), "-o", str(tmp_path / "o.h5"), "--np", "0"]) == 2
    assert "--np" in capsys.readouterr().err


def test_real_run_of_seed_disks_no_overlap(tmp_path, capsys, monkeypatch):
    """The seed's disks in Couette flow, first 2 time units, through the real fold_run:
    the run file comes back through open_run, and with the strategy no gap is negative."""
    monkeypatch.delenv("PYFOLD_FOLD_RUN", raising=False)
    text = (ROOT / "data" / "scenes" / "couette_disks_seed.toml").read_text()
    text = text.replace("t_end = 30.0", "t_end = 2.0").replace("snapshot_interval = 1.0", "snapshot_interval = 2.0")
    scene = tmp_path / "disks.toml"
    scene.write_text(text)
    out = tmp_path / "disks.h5"
    assert main(["run", str(scene), "-o", str(out)]) == 0, capsys.readouterr().err
    ds = pyfold.open_run(out)
    try:
        assert ds.attrs["status"] == "ok" and int(ds.attrs["steps_done"]) == 40
        assert ds.attrs["scene_toml"] == text
        assert ds["time"].values[-1] == pytest.approx(2.0)
        assert ds["a2"].dims == ("time", "i", "j") and ds["i"].values.tolist() == ["x", "y"]
        assert np.all(ds["min_gap_over_alpha"].values >= 0.0)
        np.testing.assert_allclose(np.trace(ds["a2"].values, axis1=1, axis2=2), 1.0, atol=1e-12)
        assert ds["x"].sizes["snapshot"] == 2 and ds["x"].attrs["units"] == "m"
    finally:
        ds.close()


def test_pyfold_warnings_are_printed_as_one_line_by_the_cli(capsys, monkeypatch):
    import warnings

    from pyfold import cli
    from pyfold.errors import InadmissibleOrientationWarning

    def run(args):
        warnings.warn("a2 leaves the orientation tensors at t = 3 s", InadmissibleOrientationWarning)
        return 0

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    args = parser.parse_args(["demo"])
    monkeypatch.setattr(parser, "parse_args", lambda argv=None: argparse_namespace(args, run))
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert cli.main(["demo"]) == 0
    err = capsys.readouterr().err
    assert "pyfold demo: warning: a2 leaves the orientation tensors at t = 3 s" in err
    assert "InadmissibleOrientationWarning" not in err and ".py:" not in err


def argparse_namespace(args, run):
    import argparse

    ns = argparse.Namespace(**vars(args))
    ns._run = run
    return ns
