"""`pyfold analyse` checks its input before fitting anything: a failed run (unless
--allow-failed), a run without records or without /setup, records of a2 that are not
orientation tensors, unknown closures and an --out that cannot be written are refused
with exit 2 and a message naming the cause."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from _fake_results import append_results
from conftest import base_scene, write_scene
from pyfold import run_checks, trajectory_fit
from pyfold.cli import main
from pyfold.errors import InputError
from pyfold.run_input import write_run_file
from pyfold.scene import load_scene
from pyfold.scene.initial import initial_state

TIMES = [0.0, 0.05, 0.1, 0.15, 0.2]  # base scene: dt = 0.01, records every 0.05


class FitStarted(Exception):
    """Raised by the stand-in fit: the checks let the run through."""


@pytest.fixture(scope="module")
def setup_only(tmp_path_factory):
    """A run file as `pyfold run` writes it before fold_run: /setup and /initial, no records."""
    folder = tmp_path_factory.mktemp("runs")
    resolved = load_scene(write_scene(folder / "scene.toml", base_scene()))
    initial = initial_state(resolved)
    path = folder / "setup_only.h5"
    write_run_file(path, resolved, initial, "pyfold run scene.toml")
    return path, initial


def _run(tmp_path, setup_only, status="ok", steps_done=20, a2=None) -> Path:
    src, initial = setup_only
    path = tmp_path / "run.h5"
    path.write_bytes(src.read_bytes())
    p, x = initial.p, initial.x
    if a2 is None:
        a2 = np.repeat((np.einsum("ni,nj->ij", p, p) / len(p))[None], len(TIMES), axis=0)
    append_results(path, 3, len(p), 1, TIMES, [0, 10], [0.0, 0.1], a2, np.stack([x, x]), np.stack([p, p]),
                   [2.0] * len(TIMES), status=status)
    with h5py.File(path, "a") as f:
        f.attrs["steps_done"] = np.int64(steps_done)
    return path


@pytest.fixture(autouse=True, scope="module")
def short_runs_allowed():
    """These runs (strain 0.2) are shorter than the one Jeffery period a C_I estimate needs;
    that refusal is tested in test_analyse_applicability.py, here the other checks are."""
    from pyfold import provenance

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(provenance, "MIN_FIT_PERIODS", 0.0)
        yield


@pytest.fixture
def no_fit(monkeypatch):
    """Any fit that starts raises FitStarted, recording the dataset it was given."""
    seen = {}

    def fit(ds, L, closures, xi):
        seen["time"] = np.asarray(ds["time"].values)
        raise FitStarted()

    monkeypatch.setattr(trajectory_fit, "fit_ci_per_closure", fit)
    return seen


def _analyse(path, tmp_path, *extra):
    return main(["analyse", str(path), "--closures", "exact,ibof", "--out", str(tmp_path / "analysis"), *extra])


def test_failed_run_refused_without_allow_failed(tmp_path, setup_only, no_fit, capsys):
    path = _run(tmp_path, setup_only, status="failed: step 11, t = 0.11: NaN in the particle velocities", steps_done=10)
    assert _analyse(path, tmp_path) == 2
    err = capsys.readouterr().err
    assert "pyfold analyse: error:" in err and "did not finish" in err and "failed: step 11" in err
    assert "--allow-failed" in err
    assert not no_fit


def test_allow_failed_warns_and_fits_only_up_to_the_last_good_state(tmp_path, setup_only, no_fit, capsys):
    path = _run(tmp_path, setup_only, status="failed: step 11, t = 0.11: NaN in the particle velocities", steps_done=10)
    with pytest.raises(FitStarted):
        _analyse(path, tmp_path, "--allow-failed")
    assert no_fit["time"].tolist() == [0.0, 0.05, 0.1]  # steps_done = 10, dt = 0.01
    err = capsys.readouterr().err
    assert "WARNING" in err and "did not finish" in err and "3 records up to the last good state" in err


def test_run_still_running_or_killed_is_refused(tmp_path, setup_only, no_fit, capsys):
    path = _run(tmp_path, setup_only, status="running")
    assert _analyse(path, tmp_path) == 2
    assert "status 'running'" in capsys.readouterr().err


def test_run_without_records_refused(tmp_path, setup_only, no_fit, capsys):
    path = tmp_path / "empty.h5"
    path.write_bytes(setup_only[0].read_bytes())
    assert _analyse(path, tmp_path) == 2
    err = capsys.readouterr().err
    assert "no records" in err and "Traceback" not in err


def test_run_with_a_single_record_refused(tmp_path, setup_only, no_fit, capsys):
    src, initial = setup_only
    path = tmp_path / "one.h5"
    path.write_bytes(src.read_bytes())
    p, x = initial.p, initial.x
    append_results(path, 3, len(p), 1, [0.0], [0], [0.0], (np.einsum("ni,nj->ij", p, p) / len(p))[None],
                   x[None], p[None], [2.0])
    assert _analyse(path, tmp_path) == 2
    assert "only one record" in capsys.readouterr().err


def test_run_without_setup_refused(tmp_path, setup_only, no_fit, capsys):
    path = _run(tmp_path, setup_only)
    with h5py.File(path, "a") as f:
        del f["setup"]
    assert _analyse(path, tmp_path) == 2
    err = capsys.readouterr().err
    assert "no /setup/resolved" in err and "Traceback" not in err


def _bad(k, matrix):
    def edit(a2):
        a2 = a2.copy()
        a2[k] = matrix(a2[k])
        return a2
    return edit


BAD_A2 = [
    ("trace 2.2", _bad(2, lambda a: 2.2 * a), "record 2 (t = 0.1) has trace 2.2"),
    ("negative eigenvalue", _bad(3, lambda a: np.diag([1.2, -0.1, -0.1])), "record 3 (t = 0.15) is not positive semi-definite"),
    ("asymmetric", _bad(1, lambda a: a + np.array([[0, 1e-3, 0], [0, 0, 0], [0, 0, 0]])), "record 1 (t = 0.05) is not symmetric"),
    ("NaN", _bad(4, lambda a: np.full((3, 3), np.nan)), "record 4 (t = 0.2) contains NaN"),
    ("trace off by 1e-8", _bad(1, lambda a: a + np.diag([1e-8, 0, 0])), "record 1 (t = 0.05) has trace 1.00000001"),
]


@pytest.mark.parametrize("case, edit, expected", BAD_A2, ids=[c[0] for c in BAD_A2])
def test_inadmissible_a2_refused_naming_the_first_bad_record(case, edit, expected, tmp_path, setup_only, no_fit, capsys):
    path = _run(tmp_path, setup_only)
    with h5py.File(path, "a") as f:
        f["a2"][...] = edit(f["a2"][()])
    assert _analyse(path, tmp_path) == 2
    err = capsys.readouterr().err
    assert expected in err and "not an orientation tensor" in err, err
    assert not no_fit


def test_orientation_tolerance_follows_precision_and_particle_count():
    assert run_checks.orientation_tolerance(np.float64, 8) == 1e-10
    assert run_checks.orientation_tolerance(np.float64, 10**7) == pytest.approx(10 * 10**7 * 2.220446049250313e-16)
    assert run_checks.orientation_tolerance(np.float32, 8) == pytest.approx(80 * 1.1920929e-07)
    # round-off of a real mean of unit dyads passes
    rng = np.random.default_rng(1)
    p = rng.normal(size=(100_000, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    a2 = np.einsum("ni,nj->ij", p, p) / len(p)
    run_checks.check_orientation_records(a2[None], np.zeros(1), len(p))


def test_unwritable_out_refused_before_any_fit(tmp_path, setup_only, no_fit, capsys):
    path = _run(tmp_path, setup_only)
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    # a path under a regular file cannot be created, not even by root
    assert main(["analyse", str(path), "--closures", "exact", "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err
    assert "--out: cannot create the folder" in err and str(blocker / "sub") in err
    assert not no_fit
    assert main(["analyse", str(path), "--closures", "exact", "--out", str(blocker)]) == 2
    assert "--out: must be a folder" in capsys.readouterr().err
    # the same run with a writable --out passes every check and reaches the fit, all records
    with pytest.raises(FitStarted):
        _analyse(path, tmp_path)
    assert no_fit["time"].tolist() == TIMES
    assert (tmp_path / "analysis").is_dir()


def test_unknown_closure_refused_before_opening_the_run(tmp_path, capsys):
    assert main(["analyse", str(tmp_path / "no_run_needed.h5"), "--closures", "ibof,bogus"]) == 2  # no such file first
    capsys.readouterr()
    path = tmp_path / "not_even_hdf5.h5"
    path.write_text("x")
    assert main(["analyse", str(path), "--closures", "ibof,bogus"]) == 2
    err = capsys.readouterr().err
    assert "--closures: unknown closure 'bogus'; allowed: exact, " in err and "ibof" in err


def test_check_closures_is_the_one_rule_for_names():
    """`pyfold main` should call this before simulating (pyfold/commands/main_job.py)."""
    assert run_checks.check_closures("exact, IBOF ,orw3,ibof") == ("exact", "ibof", "orw3")
    assert run_checks.check_closures(["exact", "fec"], dim=2) == ("exact", "fec")
    for text, expected in [("bogus", "unknown closure 'bogus'; allowed: exact, "), (",", "give at least one closure name"),
                           ("ibof,nope,bad", "unknown closures 'nope', 'bad'"), ("nat1", "NAT1")]:
        with pytest.raises(InputError, match="--closures: ") as info:
            run_checks.check_closures(text)
        assert expected in str(info.value)
    with pytest.raises(InputError, match="closure not defined 'ibof' in 2-D"):
        run_checks.check_closures("exact,ibof", dim=2)
