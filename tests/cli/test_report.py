"""`pyfold report` (pyfold/report.py, the report of `pyfold main`) on tiny contacts-only runs.

Three seeds of one scene (31 fibres, beta = 10, strain 10: seconds each) and one run
of another scene. Checked: the outputs exist and open with xarray; the ensemble
error across seeds is the sample standard deviation of the per-seed values over
sqrt(n); runs of different scenes are refused naming the differing key; a failed
run is refused unless --allow-failed; an existing report is not replaced without
--force; with one run the error bars are the within-run errors and the summary
says so; the summary names every closure and the published correlations.
"""
from __future__ import annotations

import math
import shutil

import h5py
import numpy as np
import pytest
import xarray as xr

from pyfold import report
from pyfold.cli import main
from pyfold.run_checks import DEFAULT_CLOSURES
from pyfold.run_input import fixed_string
from pyfold.scene.sheared_fibres import sheared_fibres

SEEDS = (11, 12, 13)
BETA, N_L3, T_END = 10.0, 2.25, 10.0  # 31 fibres in a 2.4^3 cell, 1000 steps


def _run(folder, name, **kw):
    scene = sheared_fibres(BETA, kw.pop("n_l3", N_L3), kw.pop("seed"), T_END, **kw)
    toml = folder / f"{name}.toml"
    toml.write_text(scene.toml, encoding="utf-8")
    out = folder / f"{name}.h5"
    assert main(["run", str(toml), "-o", str(out)]) == 0
    return out


@pytest.fixture(autouse=True, scope="module")
def short_runs_allowed():
    """These runs (strain 10) are shorter than the one Jeffery period (52) a C_I estimate
    needs; the refusal is tested in test_report_provenance.py, here the other checks are."""
    from pyfold import provenance

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(provenance, "MIN_FIT_PERIODS", 0.0)
        yield


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("report_runs")
    return [_run(folder, f"seed{s}", seed=s) for s in SEEDS]


@pytest.fixture(scope="module")
def other_scene(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("other_scene"), "denser", seed=SEEDS[0], n_l3=2.7)


@pytest.fixture(scope="module")
def ensemble_report(runs, tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "ensemble"
    assert main(["report", *map(str, runs), "--out", str(out)]) == 0
    return out


def test_report_writes_every_output_and_results_open_with_xarray(ensemble_report):
    for name in report.REPORT_FILES:
        assert (ensemble_report / name).stat().st_size > 0, name
    with xr.open_dataset(ensemble_report / "results.nc") as ds:
        assert list(ds["seed"].values) == list(SEEDS)
        assert list(ds["closure"].values) == list(DEFAULT_CLOSURES)
        assert np.all(np.isfinite(ds["ci_rate_regression"].values)) and np.all(np.isfinite(ds["ci_rate_regression_error"].values))
        assert sorted(ds["closure_rank"].values.tolist()) == list(range(1, len(DEFAULT_CLOSURES)))
    assert not [p for p in ensemble_report.iterdir() if p.name.startswith(".")]  # no work folder left


def test_ensemble_error_across_seeds_is_std_over_sqrt_n(ensemble_report):
    with xr.open_dataset(ensemble_report / "results.nc") as ds:
        n = len(SEEDS)
        per_seed = ds["ci_rate_regression_seed"].values
        np.testing.assert_allclose(ds["ci_rate_regression"].values, per_seed.mean(axis=0), rtol=1e-12)
        np.testing.assert_allclose(ds["ci_rate_regression_stderr_across"].values, per_seed.std(axis=0, ddof=1) / math.sqrt(n),
                                   rtol=1e-12)
        pooled = np.sqrt(np.sum(ds["ci_rate_regression_seed_stderr"].values ** 2, axis=0)) / n
        np.testing.assert_allclose(ds["ci_rate_regression_stderr_pooled"].values, pooled, rtol=1e-12)
        np.testing.assert_allclose(ds["ci_rate_regression_error"].values, np.maximum(pooled, per_seed.std(axis=0, ddof=1) / math.sqrt(n)),
                                   rtol=1e-12)
        errors = ds["a4D_error_seed"].values
        np.testing.assert_allclose(ds["a4D_error_stderr_across"].values, errors.std(axis=0, ddof=1) / math.sqrt(n),
                                   rtol=1e-12)


def test_summary_names_every_closure_the_correlations_and_the_steady_state(ensemble_report):
    for name in ("summary.txt", "summary.md"):
        text = (ensemble_report / name).read_text(encoding="utf-8")
        for closure in DEFAULT_CLOSURES:
            assert closure in text, (name, closure)
        assert "Bay 1991" in text and "Phan-Thien 2002" in text
        assert "phi beta" in text or "φβ" in text
        assert "moulding code" in text
        assert "onset" in text and "stationary" in text
    assert "ensemble of 3 seeds" in (ensemble_report / "summary.txt").read_text(encoding="utf-8")


def test_runs_of_different_scenes_are_refused_naming_the_key(runs, other_scene, tmp_path, capsys):
    assert main(["report", str(runs[0]), str(other_scene), "--out", str(tmp_path / "mixed")]) == 2
    err = capsys.readouterr().err
    assert "pyfold report: error:" in err and str(other_scene) in err
    assert "particles[0].count" in err  # 31 fibres vs 37
    assert not (tmp_path / "mixed" / "results.nc").exists()


def test_the_same_seed_twice_is_refused(runs, tmp_path, capsys):
    copy = tmp_path / "copy.h5"
    shutil.copy(runs[0], copy)
    assert main(["report", str(runs[0]), str(copy), "--out", str(tmp_path / "twice")]) == 2
    assert "the same seed" in capsys.readouterr().err


def _failed_copy(run, tmp_path):
    path = tmp_path / "failed.h5"
    shutil.copy(run, path)
    with h5py.File(path, "a") as f:
        n_steps = int(f.attrs["steps_done"])
        f.attrs["status"] = fixed_string("failed: step 801, t = 8.01: NaN in the particle velocities")
        f.attrs["steps_done"] = np.int64(n_steps * 8 // 10)
    return path


def test_failed_run_is_refused_without_allow_failed(runs, tmp_path, capsys):
    failed = _failed_copy(runs[1], tmp_path)
    out = tmp_path / "with_failed"
    assert main(["report", str(runs[0]), str(failed), "--out", str(out), "--closures", "exact,ibof"]) == 2
    err = capsys.readouterr().err
    assert str(failed) in err and "did not finish" in err and "--allow-failed" in err
    assert main(["report", str(runs[0]), str(failed), "--out", str(out), "--closures", "exact,ibof",
                 "--allow-failed"]) == 0
    assert "--allow-failed" in (out / "summary.txt").read_text(encoding="utf-8")


def test_existing_report_is_not_replaced_without_force(runs, tmp_path, capsys):
    out = tmp_path / "one"
    args = ["report", str(runs[0]), "--out", str(out), "--closures", "exact,ibof"]
    assert main(args) == 0
    before = (out / "results.nc").stat().st_mtime_ns
    assert main(args) == 2
    assert "--force" in capsys.readouterr().err
    assert (out / "results.nc").stat().st_mtime_ns == before
    assert main([*args, "--force"]) == 0


def test_one_run_quotes_the_within_run_error_and_says_so(runs, tmp_path):
    out = tmp_path / "single"
    assert main(["report", str(runs[2]), "--out", str(out), "--closures", "exact,ibof,quadratic"]) == 0
    with xr.open_dataset(out / "results.nc") as ds:
        np.testing.assert_allclose(ds["ci_rate_regression_error"].values, ds["ci_rate_regression_seed_stderr"].values[0], rtol=1e-12)
        assert np.all(np.isnan(ds["ci_rate_regression_stderr_across"].values))
    assert "within-run statistical error" in (out / "summary.txt").read_text(encoding="utf-8")


def test_default_out_folder_is_beside_the_first_run(runs, tmp_path):
    run = tmp_path / "alone.h5"
    shutil.copy(runs[0], run)
    assert main(["report", str(run), "--closures", "exact"]) == 0
    assert (tmp_path / "alone_report" / "summary.txt").is_file()


@pytest.mark.parametrize("closure, t_end", [("ibof", 127.5), ("fec", 30.0)])
def test_rk4_prediction_matches_the_adaptive_folgar_tucker_solve(closure, t_end):
    """The figure's Folgar-Tucker a2(t) (the fits' fixed-step RK4, pyfold.fast_fit.predict_ft)
    against pyfold.models.solve_orientation at tight tolerances; RK4's global error is
    O(h^4): measured 8e-6 over a strain of 400 at C_I = 1e-3 and the largest step. A span of
    127.5 = 255 x 0.5 puts the report's 256 output times MAX_STEP apart: one step each,
    the largest the prediction takes."""
    from pyfold.fast_fit import MAX_STEP, predict_ft
    from pyfold.models import FolgarTucker, solve_orientation

    assert MAX_STEP == 0.5
    L = np.zeros((3, 3))
    L[0, 1] = 1.0
    a0 = np.diag([0.34, 0.33, 0.33])
    t = np.linspace(0.0, t_end, report.PREDICTION_POINTS)
    a2 = predict_ft(closure, 1e-3, 0.97, a0, L, t)
    ref = solve_orientation(FolgarTucker(ci=1e-3, xi=0.97, closure=closure), a0, L, t, rtol=1e-9, atol=1e-11).a2
    assert np.max(np.abs(a2 - np.asarray(ref))) < 1e-4


def test_with_seed_sets_the_seed_and_keeps_the_comments():
    from pyfold.commands.main_job import with_seed
    import tomllib

    text = "# scene\n[numerics]\ndt = 0.1   # step\nseed = 2024   # the seed\n[output]\ninterval = 1.0\n"
    out = with_seed(text, 2026)
    assert tomllib.loads(out)["numerics"]["seed"] == 2026 and "# the seed" in out and "# step" in out
    assert tomllib.loads(with_seed("[numerics]\ndt = 0.1\n", 7))["numerics"] == {"dt": 0.1, "seed": 7}
    assert tomllib.loads(with_seed("title = 'x'\n", 7))["numerics"]["seed"] == 7
    # a `seed` key of another table is not the scene's seed
    nested = "[numerics]\ndt = 0.1\n[numerics.stokes]\nseed = 1\n"
    assert tomllib.loads(with_seed(nested, 9))["numerics"]["seed"] == 9


def test_main_job_on_a_small_scene_reports_its_seeds(tmp_path):
    scene = tmp_path / "tiny.toml"
    scene.write_text(sheared_fibres(BETA, N_L3, 5, T_END).toml, encoding="utf-8")
    assert main(["main", "--scene", str(scene), "--seeds", "2", "--closures", "exact,ibof",
                 "--out", str(tmp_path / "main")]) == 0
    result = (tmp_path / "main" / "latest").resolve()
    assert {"run_seed5.h5", "run_seed6.h5", *report.REPORT_FILES} <= {p.name for p in result.iterdir()}
    with xr.open_dataset(result / "results.nc") as ds:
        assert list(ds["seed"].values) == [5, 6]
    assert "Stokes scene: skipped" in (result / "summary.txt").read_text(encoding="utf-8")


@pytest.mark.parametrize("ci_true", [0.0, 2e-3])
def test_trajectory_fit_recovers_the_c_i_of_a_folgar_tucker_trajectory(ci_true):
    """The report's trajectory fit (pyfold.fast_fit.fit_ci_rk4 over the window up to t_end)
    on an a2(t) made by Folgar-Tucker itself (adaptive solve, IBOF) must return its C_I. The
    only model error is the fixed-step RK4's (bounded by 1e-4 in a2 in the test above); it
    moves the optimum by at most that error over the RMS sensitivity |d a2/d C_I| of the
    trajectory, measured here by a central difference. Records past t_end are not fitted."""
    from pyfold.fast_fit import fit_ci_rk4, predict_ft
    from pyfold.models import FolgarTucker, solve_orientation

    L = np.zeros((3, 3))
    L[0, 1] = 1.0
    a0 = np.eye(3) / 3.0
    t = np.linspace(0.0, 80.0, 401)
    a2 = np.array(solve_orientation(FolgarTucker(ci=ci_true, xi=0.97, closure="ibof"), a0, L, t,
                                      rtol=1e-9, atol=1e-11).a2)
    a2[t > 60.0] = np.eye(3) / 3.0  # not Folgar-Tucker: must lie outside the window
    fit = fit_ci_rk4("ibof", t, a2, L, 0.97, t_end=60.0)
    assert fit.success and len(fit.a2) == 301, fit.message
    ci, rms = fit.ci, fit.residual_rms
    h = 5e-4
    grid = np.linspace(0.0, 60.0, report.PREDICTION_POINTS)
    up = predict_ft("ibof", ci_true + h, 0.97, a0, L, grid)
    mid = predict_ft("ibof", ci_true + h / 2 if ci_true == 0.0 else ci_true - h, 0.97, a0, L, grid)
    step = h / 2 if ci_true == 0.0 else 2 * h
    sensitivity = math.sqrt(float(np.mean(((up - mid) / step) ** 2)))
    assert abs(ci - ci_true) <= 2 * 1e-4 / sensitivity, (ci, sensitivity)
    assert rms <= 1e-4
