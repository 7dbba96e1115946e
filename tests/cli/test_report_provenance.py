"""What a report states beside its numbers, on a real run: the physics model, resolution
and strain range (summary and results.nc), the Jeffery periods actually spanned (from the
particles' xi, not a constant), no steady-state onset before the first flip, and a
results.nc whose variables are all described, whose recommended C_I is named, and whose
`runs` point to files that exist.

One contacts-only run of 44 fibres, beta = 5 (Jeffery period 32 strain), to strain 40:
long enough for the estimators (one period), short enough for seconds of simulation.
"""
from __future__ import annotations

import json
import math
import shutil

import h5py
import numpy as np
import pytest
import xarray as xr

from pyfold import provenance
from pyfold.cli import main
from pyfold.run_input import write_run_file
from pyfold.scene import load_scene
from pyfold.scene.initial import initial_state
from pyfold.scene.sheared_fibres import sheared_fibres

BETA, N_L3, T_END = 5.0, 2.25, 40.0


def _period(path) -> float:
    with h5py.File(path) as f:
        xi = float(f["setup/resolved/family_xi"][0])
    beta_e = math.sqrt((1.0 + xi) / (1.0 - xi))
    return 2.0 * math.pi * (beta_e + 1.0 / beta_e)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder holding the run, and a report written into it (as the main job does)."""
    folder = tmp_path_factory.mktemp("provenance") / "job"
    folder.mkdir()
    scene = folder / "scene.toml"
    scene.write_text(sheared_fibres(BETA, N_L3, 7, T_END).toml, encoding="utf-8")
    assert main(["run", str(scene), "-o", str(folder / "run.h5")]) == 0
    assert main(["report", str(folder / "run.h5"), "--out", str(folder), "--closures", "exact,ibof,quadratic"]) == 0
    return folder


def test_the_summary_names_the_model_the_resolution_and_the_strain(folder):
    period = _period(folder / "run.h5")
    assert T_END / 2 < period < T_END  # the scene is what this test needs: one period, not two
    for name in ("summary.txt", "summary.md"):
        text = (folder / name).read_text(encoding="utf-8")
        assert "Jeffery kinematics + contacts (collision strategy), no hydrodynamic interactions" in text, name
        assert "resolution: 44 particles, time step" in text and "strain 0-40" in text, name
        # the trajectory fit spans the run (less than the two periods it would take): said as such
        assert f"({T_END / period:.2g} Jeffery periods" in text, name
        assert "(2 Jeffery periods" not in text, name


def test_no_steady_state_onset_inside_the_first_flip(folder):
    with xr.open_dataset(folder / "results.nc") as ds:
        onset = float(ds["onset_time"].values[0])
        gamma_dot = 1.0  # sheared_fibres: shear rate 1
        assert onset * gamma_dot >= _period(folder / "run.h5") - 1e-9
        assert float(ds["window_start"].values[0]) >= onset - 1e-12 or not int(ds["stationary"].values[0])


def test_results_are_described_named_and_point_to_existing_runs(folder, tmp_path):
    with xr.open_dataset(folder / "results.nc") as ds:
        undescribed = [n for n, v in ds.variables.items() if "long_name" not in v.attrs or "units" not in v.attrs]
        assert not undescribed
        assert "rank" not in ds.variables and "closure_rank" in ds
        assert ds.attrs["recommended_ci"] == "ci_recommended" and ds["ci_recommended"].attrs["recommended"] == "yes"
        assert "ci_rate_regression" in ds and "ci" not in ds.variables
        assert ds.attrs["physics_model"].startswith("Jeffery kinematics + contacts")
        assert ds.attrs["hydrodynamics"] == "jeffery" and "hydrodynamics = jeffery" in ds.attrs["hydrodynamics_reason"]
        assert ds.attrs["strain_end"] == pytest.approx(T_END)
        runs = json.loads(ds.attrs["runs"])
    assert runs == ["run.h5"]  # inside the results folder: named relative to it
    moved = tmp_path / "moved"
    shutil.copytree(folder, moved)  # the main job renames its folder when complete
    assert all((moved / r).is_file() for r in runs)


def test_the_wording_follows_the_measurements(folder):
    text = (folder / "summary.txt").read_text(encoding="utf-8")
    assert "narrow the orientation spread" not in text
    assert "|a2 - I/3|" in text or "not distinguishable from 0" in text


def test_a_stokes_run_is_named_with_its_grid(tmp_path):
    """The provenance of a fluid-coupled run states the model and the grid resolution
    (voxels per diameter = 2 r / (cell / grid))."""
    scene = sheared_fibres(5.0, 2.0, 1, 4.0, hydrodynamics="stokes")
    path = tmp_path / "stokes.toml"
    path.write_text(scene.toml, encoding="utf-8")
    resolved = load_scene(path)
    run = tmp_path / "stokes.h5"
    write_run_file(run, resolved, initial_state(resolved), "pyfold run stokes.toml")
    with h5py.File(run) as f:
        grid = f["setup/resolved/stokes_grid"][()]
        cell = f["setup/resolved/cell_lengths"][()]
        radius = float(f["setup/resolved/family_radius"][0])
        xi = float(f["setup/resolved/family_xi"][0])
    L = np.zeros((3, 3))
    L[0, 1] = 1.0
    p = provenance.provenance_of(run, np.array([0.0, 4.0]), L, xi)
    assert p.hydrodynamics == "stokes" and p.model.startswith("fluid-coupled Stokes")
    assert f"Stokes grid {' x '.join(str(int(g)) for g in grid)}" in p.resolution
    assert f"{2 * radius / float(np.max(cell / grid)):.3g} grid cells per diameter" in p.resolution


def test_analyse_results_are_described_and_name_the_model(folder, tmp_path):
    out = tmp_path / "analysis"
    assert main(["analyse", str(folder / "run.h5"), "--closures", "exact,ibof", "--out", str(out)]) == 0
    with xr.open_dataset(out / "results.nc") as ds:
        undescribed = [n for n, v in ds.variables.items() if "long_name" not in v.attrs or "units" not in v.attrs]
        assert not undescribed
        assert ds.attrs["recommended_ci"] == "ci_recommended" and "ci" not in ds.variables
        assert ds.attrs["physics_model"].startswith("Jeffery kinematics + contacts")
        assert ds.attrs["strain_end"] == pytest.approx(T_END)


def test_a_run_ending_inside_the_first_period_has_no_onset(folder):
    """The first 25 strain of the run (period 32): no steady state can be judged, so no
    onset is reported (NaN), whatever MSER-5 finds in the record."""
    from pyfold import run_analysis, run_checks

    run = folder / "run.h5"
    ds = run_checks.open_checked_run(run)
    L = run_checks.velocity_gradient_of(run)
    xi = run_checks.shape_factor_of(ds)
    short = ds.isel(time=np.flatnonzero(ds["time"].values <= 25.0))
    r = run_analysis.analyse_run(run, short, 7, ("exact", "ibof"), L, xi)
    assert math.isnan(r.onset_time) and not r.stationary
    assert "ends inside the first Jeffery period" in r.steady_message
    whole = run_analysis.analyse_run(run, ds, 7, ("exact", "ibof"), L, xi)
    assert whole.onset_time >= _period(run) - 1e-9
