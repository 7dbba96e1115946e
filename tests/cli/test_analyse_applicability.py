"""`pyfold analyse` and `pyfold report` refuse runs the C_I estimators do not fit, unless
--force: a strain shorter than one Jeffery period of the particles' aspect ratio, and
particles without orientation (spheres; disks in 2-D). In 2-D the default closures are
those defined there, instead of a failure on IBOF/ORW3.

The runs are run files as `pyfold run` writes them, with records appended in fold_run's
layout (tests/cli/_fake_results.py); the fit is replaced by a stand-in that records what
it was given, so only the checks run.
"""
from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from _fake_results import append_results
from conftest import base_scene, write_scene

from pyfold import report as report_module
from pyfold import run_checks, trajectory_fit
from pyfold.cli import main
from pyfold.closures import available
from pyfold.run_checks import DEFAULT_CLOSURES
from pyfold.run_input import write_run_file
from pyfold.scene import load_scene
from pyfold.scene.initial import initial_state

TIMES = [0.0, 0.05, 0.1, 0.15, 0.2]  # base scene: dt = 0.01, records every 0.05: strain 0.2


class FitStarted(Exception):
    """Raised by the stand-in fit: the checks let the run through."""


@pytest.fixture
def no_fit(monkeypatch):
    seen = {}

    def fit(ds, L, closures, xi):
        seen["closures"] = tuple(closures)
        raise FitStarted()

    def analyse_run(path, ds, seed, closures, L, xi):
        seen["closures"] = tuple(closures)
        raise FitStarted()

    monkeypatch.setattr(trajectory_fit, "fit_ci_per_closure", fit)
    monkeypatch.setattr(report_module, "analyse_run", analyse_run)
    return seen


def _fake_run(folder: Path, scene: dict, name: str = "run") -> Path:
    resolved = load_scene(write_scene(folder / f"{name}.toml", scene))
    initial = initial_state(resolved)
    path = folder / f"{name}.h5"
    write_run_file(path, resolved, initial, f"pyfold run {name}.toml")
    p, x = initial.p, initial.x
    dim = p.shape[1]
    a2 = np.repeat((np.einsum("ni,nj->ij", p, p) / len(p))[None], len(TIMES), axis=0)
    append_results(path, dim, len(p), 1, TIMES, [0, 10], [0.0, 0.1], a2, np.stack([x, x]), np.stack([p, p]),
                   [2.0] * len(TIMES), status="ok")
    with h5py.File(path, "a") as f:
        f.attrs["steps_done"] = np.int64(20)
    return path


def _period_of(path: Path) -> float:
    """Jeffery's period in strain, 2 pi (beta_e + 1/beta_e), from the run's recorded xi."""
    with h5py.File(path) as f:
        xi = float(f["setup/resolved/family_xi"][0])
    beta_e = math.sqrt((1.0 + xi) / (1.0 - xi))
    return 2.0 * math.pi * (beta_e + 1.0 / beta_e)


@pytest.mark.parametrize("command", ["analyse", "report"])
def test_a_run_shorter_than_one_jeffery_period_is_refused_naming_the_period(tmp_path, no_fit, capsys, command):
    run = _fake_run(tmp_path, base_scene())
    out = tmp_path / "out"
    assert main([command, str(run), "--closures", "exact,ibof", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    period = _period_of(run)
    assert f"strain 0.2 is {0.2 / period:.2g} Jeffery periods" in err, err
    assert f"= {period:.3g} strain" in err and "--force" in err, err
    assert not no_fit and (not out.exists() or not any(out.iterdir()))


@pytest.mark.parametrize("command", ["analyse", "report"])
def test_force_goes_ahead_with_a_warning(tmp_path, no_fit, capsys, command):
    run = _fake_run(tmp_path, base_scene())
    with pytest.raises(FitStarted):
        main([command, str(run), "--closures", "exact,ibof", "--out", str(tmp_path / "out"), "--force"])
    assert "WARNING (--force)" in capsys.readouterr().err and no_fit["closures"] == ("exact", "ibof")


@pytest.mark.parametrize("command", ["analyse", "report"])
@pytest.mark.parametrize("dim", [3, 2])
def test_spheres_and_disks_have_no_orientation_to_fit(tmp_path, no_fit, capsys, command, dim):
    scene = base_scene()
    scene["particles"] = [{"name": "spheres", "shape": "sphere", "radius": 0.1, "count": 8}]
    if dim == 2:
        scene["cell"] = {"dim": 2, "size": [4.0, 4.0]}
    run = _fake_run(tmp_path, scene)
    assert main([command, str(run), "--closures", "exact", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "no orientation" in err and "C_I is undefined" in err and "--force" in err, err
    assert not no_fit


def test_in_2d_the_default_closures_are_those_defined_there(tmp_path, no_fit, capsys):
    scene = base_scene()
    scene["cell"] = {"dim": 2, "size": [4.0, 4.0]}
    run = _fake_run(tmp_path, scene)
    with pytest.raises(FitStarted):
        main(["analyse", str(run), "--out", str(tmp_path / "out"), "--force"])
    chosen = no_fit["closures"]
    assert chosen == tuple(c for c in DEFAULT_CLOSURES if c == "exact" or c in available(2))
    assert "ibof" not in chosen and "orw3" not in chosen and len(chosen) >= 3
    assert run_checks.default_closures(3) == DEFAULT_CLOSURES
    # named explicitly, a closure not defined in 2-D is still refused, naming the allowed ones
    assert main(["analyse", str(run), "--closures", "ibof", "--out", str(tmp_path / "o2"), "--force"]) == 2
    err = capsys.readouterr().err
    assert "closure not defined 'ibof' in 2-D" in err and "allowed in 2-D" in err, err
