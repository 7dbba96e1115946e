"""The levers of the C_I speed-accuracy trade (studies/speed_accuracy/ci_stokes_settings.py and its
ranks sweep, studies/speed_accuracy/pareto.py): every point of the sweeps is a valid scene with
the numerics its row names, the ranks rows run the setting they name on the ranks they name, and
the resolution rows of the Pareto table are the paired changes against the finest grid."""
from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from pyfold.ensemble import ensemble_mean, paired_difference
from pyfold.scene import parse_scene
from pyfold.sweep.study import load_form

from study_import import STUDIES, import_study

settings = import_study("speed_accuracy", "ci_stokes_settings")


@pytest.mark.parametrize("name", ["ci_stokes_settings", "ci_stokes_settings_ranks"])
def test_every_point_of_the_sweeps_is_a_valid_scene_with_the_numerics_of_its_row(name):
    spec = load_form(STUDIES / "sweeps", name, False)
    for point in spec.points:
        scene = settings.scene_of(**point, seed=spec.seeds[0], **spec.arguments)
        checked = parse_scene(scene.toml, f"{name}.toml").scene.numerics.stokes
        wanted = {**settings.REFERENCE_STOKES, **settings.SETTINGS[point["setting"]][0]}
        for key, value in wanted.items():
            assert getattr(checked, key) == value, (point, key)


def test_the_ranks_rows_name_the_setting_and_the_ranks_their_sweep_runs():
    spec = load_form(STUDIES / "sweeps", "ci_stokes_settings_ranks", False)
    serial = load_form(STUDIES / "sweeps", "ci_stokes_settings", False)
    assert spec.resources.np > 1 and serial.resources.np == 1
    assert spec.seeds == serial.seeds and spec.arguments == serial.arguments  # paired with the serial runs
    run = {(setting, ranks) for setting, ranks, _ in settings.RANKED.values()}
    assert {(p["setting"], spec.resources.np) for p in spec.points} == run
    # ranks are resources, not numerics: no preset row is made of them
    rows = [{"setting": name} for name in settings.RANKED]
    assert settings.measured(rows) == {}


def test_the_resolution_rows_are_paired_changes_against_the_finest_grid(tmp_path):
    pareto = import_study("speed_accuracy", "pareto")
    rng = np.random.default_rng(3)
    cpds, seeds = [3, 4, 5], [1, 2, 3, 4]
    values = {est: 1e-3 + rng.normal(0.0, 2e-4, (3, 4)) for est in ("closure_free", "ibof_trajectory")}
    ds = xr.Dataset({f"ci_{est}_cox": (("cells_per_diameter", "seed"), v) for est, v in values.items()}
                    | {f"ci_{est}_cox_stderr": (("cells_per_diameter", "seed"), np.full((3, 4), 1e-4))
                       for est in values}
                    | {"cpu_s": (("cells_per_diameter", "seed"), np.outer([100.0, 200.0, 400.0], np.ones(4)))},
                    coords={"cells_per_diameter": cpds, "seed": seeds,
                            "h_over_d": ("cells_per_diameter", [1 / 3.1, 1 / 4.0, 1 / 5.2])})
    path = tmp_path / "ci_resolution.nc"
    ds.to_netcdf(path, engine="h5netcdf")
    rows = pareto.resolution_rows(path)
    assert [r.answer for r in rows] == ["ci_resolution"] * 3 + ["ci_resolution_trajectory"] * 3
    for est, answer in (("closure_free", "ci_resolution"), ("ibof_trajectory", "ci_resolution_trajectory")):
        v = values[est]
        got = {round(r.vpd, 2): r for r in rows if r.answer == answer}
        ref = got[5.2]
        assert ref.error == pytest.approx(ensemble_mean(v[2], np.full(4, 1e-4)).error, rel=1e-12)
        assert math.isnan(ref.error_stderr) and "[reference]" in ref.setting
        for i, vpd in enumerate((3.1, 4.0)):
            d = paired_difference(v[i], v[2])
            assert got[vpd].error == pytest.approx(abs(d.mean), rel=1e-12)
            assert got[vpd].error_stderr == pytest.approx(d.stderr, rel=1e-12)
            assert got[vpd].cpu_s == pytest.approx([100.0, 200.0][i])
    assert pareto.resolution_rows(tmp_path / "absent.nc") == []


def test_ranked_runs_key_the_ranks_sweep_by_its_rows(tmp_path):
    done = {(("semi-dilute", "tol1e-3_every4"), 1): tmp_path / "a.h5",
            (("concentrated", "tol1e-3_every4"), 2): tmp_path / "b.h5",
            (("semi-dilute", "tol1e-4"), 1): tmp_path / "c.h5"}  # no RANKED row runs this setting
    (row, (setting, ranks, _)), = settings.RANKED.items()
    got = settings.ranked_runs(done, ranks)
    assert got == {("semi-dilute", row, 1): tmp_path / "a.h5", ("concentrated", row, 2): tmp_path / "b.h5"}
    assert settings.ranked_runs(done, ranks + 1) == {}  # run on other ranks: not these rows
