"""Stability at the extremes, fast subset of studies/extremes/extremes.py (docs/extremes.md):
each extreme scene most likely to regress gives an accurate run or a detected failure --
never silent garbage, a hang (every case runs under a time limit in its own process group)
or a crash. The checks that tell them apart are themselves tested on doctored inputs, so
that a broken check cannot let garbage through as "accurate".
"""
from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("extremes", ROOT / "studies" / "extremes" / "extremes.py")
extremes = importlib.util.module_from_spec(_spec)
sys.modules["extremes"] = extremes  # dataclasses look their module up while the class is built
_spec.loader.exec_module(extremes)

#: about a minute on 2 cores: one case per kind of extreme that has failed or nearly failed
SUBSET = ("beta100_single_orbit", "beta100_stokes", "spheres_phi0.60", "dt_tip_10radius", "dt_spheres_2radius",
          "stokes_cpd1", "stokes_kappa1e+06", "planar_single", "uniaxial_single_strain20")
BAD = ("silent garbage", "hang", "crash")
CASES = {c.name: c for c in extremes.build_cases(large=False)}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Each case run once (lazily), shared by the tests that doctor its run file."""
    work = tmp_path_factory.mktemp("extremes")
    done = {}

    def get(name):
        if name not in done:
            done[name] = extremes.run_case(CASES[name], work)
        return done[name], work / f"{name}.h5"
    return get


@pytest.mark.parametrize("name", SUBSET)
def test_extreme_scene_is_accurate_or_a_detected_failure(name, runs):
    out, _ = runs(name)
    assert out.category not in BAD, f"{name}: {out.category}: {out.diagnostic}"
    if out.category == "accurate" and np.isfinite(out.error):
        assert out.error <= out.bound, (name, out.error, out.bound)
    if out.category == "detected failure":
        assert out.diagnostic.strip(), name


def _pair(y1: float):
    """Two fibres (half length 0.5): one along x at the cell centre, one along z whose
    centre moves in y from y1 to 1.6 in one step of dt = 0.01, as two snapshots."""
    f = h5py.File("pair.h5", "w", driver="core", backing_store=False)
    f.attrs["snapshots_complete"] = 2
    f["snapshot"] = np.array([0, 1])
    res = f.create_group("setup/resolved")
    res["velocity_gradient"] = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    res["cell_lengths"] = np.array([3.0, 3.0, 3.0])
    res["dim"] = 3
    f["x"] = np.array([[[1.5, 1.5, 1.5], [1.5, y1, 1.5]], [[1.5, 1.5, 1.5], [1.5, 1.6, 1.5]]])
    f["p"] = np.array([[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]] * 2)
    return f


@pytest.mark.parametrize("y1", [1.4, 1.45])  # 1.4: the axes meet exactly at a sub-step
def test_crossing_check_sees_a_fibre_passing_through_another(y1):
    with _pair(y1) as f:
        assert extremes.count_crossings(f, np.array([0.5, 0.5]), np.array([0.01, 0.01]), 0.001, 0.01) == 1


def test_crossing_check_ignores_a_fibre_passing_beyond_the_end():
    with _pair(1.4) as f:
        x = f["x"][()]
        x[:, 1, 0] = 2.2  # fibre 1 passes 0.2 beyond the end of fibre 0 (x = 2.0)
        f["x"][...] = x
        assert extremes.count_crossings(f, np.array([0.5, 0.5]), np.array([0.01, 0.01]), 0.001, 0.01) == 0


def test_gap_scan_matches_the_capsule_distance_of_crossed_and_parallel_fibres():
    # crossed at right angles, axes 0.3 apart: gap 0.3 - 2 R; parallel, side by side 0.25 apart;
    # and across the periodic boundary (x 0.05 and 2.95 in a cell of 3: 0.1 apart, end to end)
    half, rad = np.array([0.5, 0.5]), np.array([0.05, 0.05])
    box = np.diag([3.0, 3.0, 3.0])
    crossed = extremes.min_gap_scan(np.array([[1.5, 1.5, 1.5], [1.5, 1.8, 1.5]]),
                                    np.array([[1.0, 0, 0], [0, 0, 1.0]]), half, rad, 0.01, box)
    parallel = extremes.min_gap_scan(np.array([[1.5, 1.5, 1.5], [1.6, 1.75, 1.5]]),
                                     np.array([[1.0, 0, 0], [1.0, 0, 0]]), half, rad, 0.01, box)
    wrapped = extremes.min_gap_scan(np.array([[0.55, 1.5, 1.5], [2.45, 1.5, 1.5]]),
                                    np.array([[1.0, 0, 0], [1.0, 0, 0]]), half, rad, 0.01, box)
    tol = 8 * np.finfo(float).eps
    assert abs(crossed - 0.2) < tol and abs(parallel - 0.15) < tol and abs(wrapped - 0.0) < tol


def _copy_of_accurate_run(runs, case, path: Path) -> Path:
    """A copy at ``path`` of the run of ``case``, checked accurate, to damage."""
    good, run = runs(case.name)
    assert good.category == "accurate", good.diagnostic
    shutil.copy(run, path)
    return path


def test_a_run_with_nan_or_an_overlap_under_status_ok_is_silent_garbage(runs, tmp_path):
    case = CASES["dt_tip_10radius"]
    nan_run = _copy_of_accurate_run(runs, case, tmp_path / "nan.h5")
    with h5py.File(nan_run, "r+") as f:
        f["a2"][-1, 0, 0] = np.nan
    broken, status = extremes.check_run(nan_run, case, extremes.Outcome("nan", "", ""))
    assert status == "ok" and any("NaN" in b for b in broken), broken
    overlap = _copy_of_accurate_run(runs, case, tmp_path / "overlap.h5")
    with h5py.File(overlap, "r+") as f:
        last = int(f.attrs["snapshots_complete"]) - 1
        x = f["x"][last]
        x[1] = x[0] + np.array([0.05, 0.0, 0.0])  # centres 0.05 apart < 2 R = 0.1: overlapping
        f["x"][last] = x
    broken, _ = extremes.check_run(overlap, case, extremes.Outcome("overlap", "", ""))
    assert any(b.startswith("overlap") for b in broken), broken


def test_an_orbit_off_the_exact_jeffery_solution_is_silent_garbage(runs, tmp_path):
    case = CASES["planar_single"]
    wrong = _copy_of_accurate_run(runs, case, tmp_path / "wrong.h5")
    with h5py.File(wrong, "r+") as f:
        f["a2"][-1] = np.diag([0.0, 1.0, 0.0])  # a valid orientation tensor, off the orbit
    broken, _ = extremes.check_run(wrong, case, extremes.Outcome("wrong", "", ""))
    assert any("exact Jeffery orbit" in b for b in broken), broken


@pytest.mark.parametrize("name, key, allowed", [
    # dt = 2 in a unit cell sheared at rate 1: a corner moves 1 > 1/2 per step
    ("dt_spheres_2radius", "numerics.dt", "allowed: numerics.dt <= 1,"),
    # uniaxial elongation stretches the unremapped cell: fold_run stopped near strain 5.7
    ("uniaxial_single_strain20", "numerics.t_end", "allowed: numerics.t_end <="),
])
def test_validation_refuses_a_step_that_fold_run_would_stop_as_a_blow_up(name, key, allowed, tmp_path, capsys):
    import tomli_w

    from pyfold.cli import main

    path = tmp_path / f"{name}.toml"
    path.write_text(tomli_w.dumps(CASES[name].scene))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"  {key}: " in err and allowed in err, err


def test_validation_names_the_cell_size_a_kraynik_reinelt_lattice_needs(tmp_path, capsys):
    import tomli_w

    from pyfold.cli import main

    scene = CASES["planar_contacts"].scene
    scene = {**scene, "cell": {**scene["cell"], "size": [2.4, 2.4, 2.4]}}
    path = tmp_path / "kr.toml"
    path.write_text(tomli_w.dumps(scene))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "  cell.size: the Kraynik-Reinelt lattice" in err and "allowed: cell.size x = y > about" in err, err
