"""The whole chain on a dilute scene: direct simulation -> C_I fit -> closure test.

Dilute fibres move by Jeffery kinematics without contacts, so Folgar–Tucker fed
with the run's own a4 ("exact" closure) must fit C_I = 0 (on its bound), and the
closure errors must be measured against that same a4 (docs/physics.md#dilute-suspensions).
This is the test of `pyfold analyse` and of the main job's pipeline.
"""
import pytest
import xarray as xr

from pyfold.cli import main as cli_main

from conftest_chain import write_dilute_scene  # noqa: F401  (helper module next to this file)


@pytest.fixture(scope="module")
def dilute_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("chain")
    scene = write_dilute_scene(folder / "dilute.toml")
    out = folder / "run.h5"
    assert cli_main(["run", str(scene), "-o", str(out)]) == 0
    return out


def test_analyse_fits_ci_zero_with_the_runs_own_a4_and_judges_closures(dilute_run, tmp_path):
    out = tmp_path / "analysis"
    # strain 4 is shorter than one Jeffery period: --force (the fit of C_I = 0 is exact here)
    assert cli_main(["analyse", str(dilute_run), "--closures", "exact", "--out", str(out), "--force"]) == 0
    results = xr.open_dataset(out / "results.nc", engine="h5netcdf")
    assert float(results["ci_recommended"].sel(closure="exact")) < 1e-5
    assert int(results["success"].sel(closure="exact")) == 1
    # Jeffery motion is exact per step, so Folgar–Tucker with the run's a4 reproduces
    # a2 up to the cubic interpolation of a4 between records 0.05 apart (O(h^3);
    # measured 3.7e-7; linear interpolation gave ~1e-4 and a biased C_I = 1.6e-5) and
    # the RK4 error of pyfold.fast_fit (one step of 0.05 per record, O(h^4))
    assert float(results["residual_rms"].sel(closure="exact")) < 1e-5
    # the fit says which step it used and what that step may have moved C_I by: no more
    # than a tenth of its standard error (pyfold.fast_fit.STEP_ERROR_SHARE)
    assert float(results["rk4_step"].sel(closure="exact")) <= 0.05 * (1 + 1e-12)
    exact = results.sel(closure="exact")
    assert 0.0 <= float(exact["ci_step_error"]) <= max(0.1 * float(exact["ci_recommended_stderr"]), 1e-10)
    assert (out / "a2_dns_vs_fitted_ft.png").stat().st_size > 10_000
    assert (out / "closures_vs_dns.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["analyse", "/nonexistent/run.h5"], "RUN.h5: no such file"),
        (["main", "--scene", "/nonexistent/scene.toml"], "--scene: no such scene file"),
        (["main", "--np", "0"], "--np: must be an integer >= 1"),
        (["main", "--closures", ","], "--closures: give at least one closure name"),
    ],
)
def test_bad_arguments_exit_2_naming_the_option(argv, fragment, capsys):
    assert cli_main(argv) == 2
    assert fragment in capsys.readouterr().err


def test_unknown_closure_is_rejected_naming_the_allowed_ones(dilute_run, tmp_path, capsys):
    assert cli_main(["analyse", str(dilute_run), "--closures", "nosuch", "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "nosuch" in err and "ibof" in err
