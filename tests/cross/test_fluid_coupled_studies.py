"""The fluid-coupled series, resolution and steady-state studies (studies/interaction_coefficient/
ci_fluid_series.py, ci_resolution.py, steady_state_strain.py): their scenes validate as the sweeps run them, the order and Richardson pieces
recover a known convergence, and pyfold.correlations' fit of the shipped table
(data/ci_fluid_coupled.csv) is the weighted least-squares line with its covariance."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pyfold.correlations import fluid_coupled_ci, fluid_coupled_fit, fluid_coupled_table
from pyfold.scene import parse_scene
from pyfold.sweep.study import load_form

from study_import import STUDIES, import_study

series = import_study("interaction_coefficient", "ci_fluid_series")
resolution = import_study("interaction_coefficient", "ci_resolution")


@pytest.mark.parametrize("name, builder", [("ci_fluid_series", series.scene_of),
                                           ("ci_resolution", resolution.scene_of),
                                           ("ci_resolution_calibrated", resolution.scene_of),
                                           ("steady_state_strain", series.scene_of)])
def test_every_point_of_the_sweeps_is_a_valid_scene_of_the_intended_model(name, builder):
    spec = load_form(STUDIES / "sweeps", name, False)
    for point in spec.points:
        scene = builder(**point, seed=spec.seeds[0], **spec.arguments)
        checked = parse_scene(scene.toml, f"{name}.toml")
        assert checked.hydrodynamics == point.get("model", "stokes")
        if checked.hydrodynamics == "stokes":  # the numerics the docstrings state
            st = checked.scene.numerics.stokes
            assert (st.tolerance, st.solve_every, st.kappa) == (1e-3, 4, 1e3)
        assert scene.side == pytest.approx(2.7) and abs(scene.n_l3 - point.get("n_l3", 5.0)) < 0.05


def test_the_calibrated_resolution_runs_are_the_resolution_runs_with_a_fatter_voxelised_fibre():
    """ci_resolution_calibrated.toml: the grids and seeds of ci_resolution.toml (so the same initial
    states), and one coarser grid, each with a radius scale above 1 that shrinks as the grid is
    refined, written to the run file as stokes_fibre_radius_scale."""
    plain, cal = (load_form(STUDIES / "sweeps", n, False) for n in ("ci_resolution", "ci_resolution_calibrated"))
    assert cal.seeds == plain.seeds and cal.arguments == plain.arguments
    cells = [p["cells_per_diameter"] for p in cal.points]
    assert cells == sorted(cells) and cells[-3:] == list(plain.axes["cells_per_diameter"])
    assert resolution.SERIES_CELLS in cells[:-2]
    scales = [p["fibre_radius_scale"] for p in cal.points]
    assert all(a > b > 1.0 for a, b in zip(scales, scales[1:]))
    for point in cal.points:
        checked = parse_scene(resolution.scene_of(**point, seed=1, **cal.arguments).toml)
        assert checked.resolved_datasets()["stokes_fibre_radius_scale"][0] == point["fibre_radius_scale"]


def test_calibrate_scale_finds_the_scale_of_the_target_and_refuses_a_target_out_of_reach(monkeypatch, tmp_path):
    """The secant iteration on a smooth falling β_e(s) (a stand-in for the single-fibre check,
    β_e = 4.7 s^-1.2) reaches the target within the tolerance, and returns the measured scale
    rounded to the 3 decimals a sweep file holds; a target no scale in [0.5, 2] reaches stops
    with the grid named."""
    calls = []

    def fake(grid, side, cache, beta, scale):
        calls.append(scale)
        return 4.7 * scale ** -1.2

    monkeypatch.setattr(resolution.series, "beta_e_on", fake)
    s, be, pts = resolution.calibrate_scale([42] * 3, 2.7, 4.112, tmp_path)
    assert abs(be - 4.112) <= resolution.CALIBRATION_TOLERANCE * 4.112
    assert s == round(s, 3) and abs(s - (4.7 / 4.112) ** (1 / 1.2)) < 0.01
    assert pts[:2] == [(1.0, fake([], 0, 0, 0, 1.0)), (1.1, fake([], 0, 0, 0, 1.1))]
    with pytest.raises(SystemExit, match="grid 42"):
        resolution.calibrate_scale([42] * 3, 2.7, 0.5, tmp_path)


def test_the_beta10_series_is_the_beta5_series_at_twice_the_aspect_ratio():
    """ci_fluid_series_beta10.toml: every point a valid scene with the series' Stokes numerics on the
    72³ grid it states (3 voxels per diameter of the 0.1 L fibre in the 2.4 L cell), at the φβ its
    comments give; the β = 5 series' scenes keep the default grid bound (their run ids unchanged)."""
    from pyfold.correlations import phi_beta

    spec = load_form(STUDIES / "sweeps", "ci_fluid_series_beta10", False)
    assert spec.arguments["beta"] == 10.0 and series.SERIES[10.0] == "ci_fluid_series_beta10"
    targets = {6.4: 0.5, 3.2: 0.25, 12.7: 1.0}
    assert {p["n_l3"] for p in spec.points} == set(targets)
    for point in spec.points:
        scene = series.scene_of(**point, seed=spec.seeds[0], **spec.arguments)
        checked = parse_scene(scene.toml, "ci_fluid_series_beta10.toml")
        assert checked.hydrodynamics == point["model"]
        assert scene.side == pytest.approx(2.4) and scene.beta == 10.0
        assert phi_beta(scene.n_l3, 10.0) == pytest.approx(targets[point["n_l3"]], abs=2e-3)
        if point["model"] == "stokes":
            st = checked.scene.numerics.stokes
            assert (st.tolerance, st.solve_every, st.kappa, st.cells_per_diameter) == (1e-3, 4, 1e3, 3)
            assert st.max_grid_points >= 72 ** 3
            assert checked.scene.numerics.dt == pytest.approx(0.01)
    assert "max_grid_points" not in series.scene_of(5.0, "stokes", 1, 200.0).toml


def test_the_calibrated_beta10_series_is_the_beta10_series_with_a_calibrated_radius_and_zhangs_beta_e():
    """ci_fluid_series_beta10_calibrated.toml: the points and seeds of the geometric β = 10 series;
    each scene differs from its geometric one only by the Stokes runs' fibre radius scale (> 1) and
    the β_e rule both models record (Zhang's, what the calibration aims the grid fibre at), the step
    (twice), the Stokes runs' solves (every 16th step, Jeffery between) and grid (96³), so the initial
    states are the same; and the calibration it quotes is that of docs/fluid_coupled_ci.md's table
    (1.100 on 96³)."""
    import tomllib

    from pyfold.kinematics import equivalent_aspect_ratio

    plain, cal = (load_form(STUDIES / "sweeps", n, False)
                  for n in ("ci_fluid_series_beta10", "ci_fluid_series_beta10_calibrated"))
    assert cal.points == plain.points and cal.seeds == plain.seeds
    assert cal.arguments == {**plain.arguments, "fibre_radius_scale": 1.1, "equivalent_aspect_ratio": "zhang",
                             "dt": 0.02, "solve_every": 16, "reuse": "jeffery", "cells_per_diameter": 4,
                             "max_grid_points": 900000}
    for point in cal.points:
        a = tomllib.loads(series.scene_of(**point, seed=2, **cal.arguments).toml)
        b = tomllib.loads(series.scene_of(**point, seed=2, **plain.arguments).toml)
        assert a["particles"][0].pop("equivalent_aspect_ratio") == "zhang"
        assert a["numerics"].pop("dt") == 2 * b["numerics"].pop("dt") == 0.02  # time_step_beta10.py
        if point["model"] == "stokes":
            st_a, st_b = a["numerics"]["stokes"], b["numerics"]["stokes"]
            assert st_a.pop("fibre_radius_scale") == 1.1
            # solve_reuse.py: a solve every 16th step, Jeffery between solves
            assert (st_a.pop("reuse"), st_a.pop("solve_every")) == ("jeffery", 16)
            assert st_b.pop("solve_every") == 4
            # ci_resolution_beta10.py: 96³, 4 voxels per diameter
            assert (st_a.pop("cells_per_diameter"), st_b.pop("cells_per_diameter")) == (4, 3)
            assert (st_a.pop("max_grid_points"), st_b.pop("max_grid_points")) == (900000, 400000)
        assert a == b
        checked = parse_scene(series.scene_of(**point, seed=2, **cal.arguments).toml)
        assert checked.families[0].equivalent_aspect_ratio == pytest.approx(
            float(equivalent_aspect_ratio(10.0, "zhang")))


def test_the_time_step_runs_are_the_calibrated_beta10_stokes_runs_at_twice_the_step():
    """studies/speed_accuracy/time_step_beta10.py compares its runs with the calibrated β = 10
    series' runs seed by seed: its scenes differ from the series' φβ = 0.5 Stokes scenes only by
    the step (twice α/(γ̇L)), the end and the snapshot interval, and it finds the series' run of
    each of its seeds by the series' own run ids."""
    import tomllib

    study = import_study("speed_accuracy", "time_step_beta10")
    spec, cal = (load_form(STUDIES / "sweeps", n, False)
                 for n in ("time_step_beta10", "ci_fluid_series_beta10_calibrated"))
    assert spec.seeds == cal.seeds
    args = {k: v for k, v in spec.arguments.items() if k not in study.POINT and k != "t_end"}
    assert args == {k: v for k, v in {**cal.arguments, **study.SERIES_AT_FIRST}.items()
                    if k not in ("t_end", "dt") and v is not None}
    assert study.POINT in [dict(p) for p in cal.points]
    for point in spec.points:
        a = tomllib.loads(series.scene_of(**point, seed=3, **spec.arguments).toml)
        b = tomllib.loads(series.scene_of(**study.POINT, seed=3, **{**cal.arguments, **study.SERIES_AT_FIRST}).toml)
        assert a["numerics"].pop("dt") == pytest.approx(2 * b["numerics"].pop("dt")) == 0.02
        assert a["numerics"].pop("t_end") == study.STRAIN
        b["numerics"].pop("t_end")
        a["output"].pop("snapshot_interval"), b["output"].pop("snapshot_interval")
        assert a == b


def test_the_solve_reuse_runs_are_the_calibrated_beta10_stokes_runs_with_other_solve_intervals():
    """studies/speed_accuracy/solve_reuse.py pairs each setting with its first point seed by
    seed: every scene is the calibrated β = 10 series' φβ = 0.5 Stokes scene (same step) with only
    the end, the snapshot interval and the solve interval and estimate between solves changed, and
    the first point is the series' own setting (its reference)."""
    import tomllib

    study = import_study("speed_accuracy", "solve_reuse")
    time_step = import_study("speed_accuracy", "time_step_beta10")
    spec, cal = (load_form(STUDIES / "sweeps", n, False)
                 for n in ("solve_reuse_beta10", "ci_fluid_series_beta10_calibrated"))
    assert spec.seeds == cal.seeds
    series_point = {"n_l3": spec.arguments["n_l3"], "model": spec.arguments["model"]}
    assert series_point in [dict(p) for p in cal.points]
    first = time_step.SERIES_AT_FIRST  # the series at Δt 0.02 before it took a setting of this study, on 72³
    assert {k: v for k, v in spec.arguments.items() if k not in ("t_end", "n_l3", "model", "dt")} == \
        {k: v for k, v in {**cal.arguments, **first}.items() if k not in ("t_end", "dt") and v is not None}
    b = tomllib.loads(series.scene_of(**series_point, seed=3, **{**cal.arguments, **first, "dt": 0.02}).toml)
    b["numerics"].pop("t_end"), b["output"].pop("snapshot_interval")
    assert study.label(dict(spec.points[0])) == "every 4, linear"
    assert b["numerics"]["stokes"]["solve_every"] == 4 and "reuse" not in b["numerics"]["stokes"]
    for point in spec.points:
        a = tomllib.loads(series.scene_of(**point, seed=3, **spec.arguments).toml)
        assert a["numerics"].pop("t_end") == 20.0
        a["output"].pop("snapshot_interval")
        stokes = a["numerics"]["stokes"]
        assert stokes.pop("reuse") == point["reuse"]
        stokes["solve_every"] = 4
        assert a == b
    assert len({study.label(dict(p)) for p in spec.points}) == len(spec.points)


def test_the_concentrated_solve_reuse_runs_are_the_calibrated_series_concentrated_stokes_runs():
    """solve_reuse.py --beta 10 --concentrated: every scene is the calibrated β = 10 series' φβ = 1.0
    Stokes scene (its grid, radius scale, step and seeds) with only the end, the snapshot interval and
    the solves changed; its first point solves every 4th step (the reference) and the series' own
    setting is among the others."""
    import tomllib

    study = import_study("speed_accuracy", "solve_reuse")
    spec, cal = (load_form(STUDIES / "sweeps", n, False)
                 for n in (study.SWEEPS[10.0, True][0], "ci_fluid_series_beta10_calibrated"))
    assert spec.seeds == cal.seeds
    point = {"n_l3": spec.arguments["n_l3"], "model": spec.arguments["model"]}
    assert point in [dict(p) for p in cal.points] and point["n_l3"] == max(p["n_l3"] for p in cal.points)
    b = tomllib.loads(series.scene_of(**point, seed=3, **cal.arguments).toml)
    b["numerics"].pop("t_end"), b["output"].pop("snapshot_interval")
    assert study.label(dict(spec.points[0])) == "every 4, linear"
    series_label = series.solve_label(cal.arguments["solve_every"], cal.arguments["reuse"])
    assert series_label in [study.label(dict(p)) for p in spec.points[1:]]
    for p in spec.points:
        a = tomllib.loads(series.scene_of(**p, seed=3, **spec.arguments).toml)
        assert a["numerics"].pop("t_end") == 20.0
        a["output"].pop("snapshot_interval")
        a["numerics"]["stokes"].update(solve_every=cal.arguments["solve_every"], reuse=cal.arguments["reuse"])
        assert a == b


def test_the_beta10_resolution_runs_are_the_calibrated_series_on_three_calibrated_grids():
    """studies/interaction_coefficient/ci_resolution_beta10.py: its 96³ scene is the calibrated β = 10
    series' φβ = 0.5 Stokes scene (same grid, step, solves, radius scale) with a shorter end; its
    72³ and 120³ scenes differ from that by the grid and the radius scale calibrated there
    (docs/fluid_coupled_ci.md: 1.212, 1.091), and its control by the solves only, so a seed's runs
    share their initial state; the grid whose bias the study hands to the series is the series'."""
    import tomllib

    study = import_study("interaction_coefficient", "ci_resolution_beta10")
    spec, cal = (load_form(STUDIES / "sweeps", n, False)
                 for n in ("ci_resolution_beta10_calibrated", "ci_fluid_series_beta10_calibrated"))
    assert spec.seeds == cal.seeds
    assert study.SERIES_CELLS == cal.arguments["cells_per_diameter"]
    assert study.SERIES_SOLVES == f"every {cal.arguments['solve_every']}, {cal.arguments['reuse']}"
    point = {"n_l3": spec.arguments["n_l3"], "model": spec.arguments["model"]}
    assert point in [dict(p) for p in cal.points]
    b = tomllib.loads(series.scene_of(**point, seed=1, **cal.arguments).toml)
    b["numerics"].pop("t_end"), b["output"].pop("snapshot_interval")
    scales = {}
    for pt in spec.points:
        a = tomllib.loads(series.scene_of(**pt, seed=1, **spec.arguments).toml)
        assert a["numerics"].pop("t_end") == 20.0
        a["output"].pop("snapshot_interval")
        st = a["numerics"]["stokes"]
        if (pt["solve_every"], pt["reuse"]) == (cal.arguments["solve_every"], cal.arguments["reuse"]):
            scales[st["cells_per_diameter"]] = st["fibre_radius_scale"]
        for key in ("cells_per_diameter", "fibre_radius_scale", "max_grid_points", "solve_every", "reuse"):
            st[key] = b["numerics"]["stokes"][key]
        assert a == b
    assert scales == {3: 1.212, 4: 1.1, 5: 1.091}


def test_the_beta10_resolution_runs_with_shells_apart_differ_from_the_calibrated_ones_by_that_rule_only():
    """ci_resolution_beta10.py --shells apart: each of its scenes is the calibrated sweep's scene of the
    same grid with the series' solves, plus numerics.stokes.fibre_shells = "apart"; the grid whose bias
    it carries is the grid of the series with that rule, whose scenes are the calibrated series' plus
    the rule."""
    import tomllib

    study = import_study("interaction_coefficient", "ci_resolution_beta10")
    apart, cal = (load_form(STUDIES / "sweeps", study.SWEEPS[rule], False) for rule in ("apart", "overlap"))
    assert apart.seeds == cal.seeds
    series_apart = load_form(STUDIES / "sweeps", "ci_fluid_series_beta10_calibrated_apart", False)
    assert study.SHELLS_SERIES_CELLS["apart"] == series_apart.arguments["cells_per_diameter"]
    cal_series = load_form(STUDIES / "sweeps", "ci_fluid_series_beta10_calibrated", False)
    assert {k: v for k, v in series_apart.arguments.items() if k != "fibre_shells"} == cal_series.arguments
    assert series_apart.points == cal_series.points and series_apart.seeds == cal_series.seeds
    solves = (apart.arguments["solve_every"], apart.arguments["reuse"])
    same = {int(p["cells_per_diameter"]): p for p in cal.points if (p["solve_every"], p["reuse"]) == solves}
    assert sorted(same) == sorted(int(p["cells_per_diameter"]) for p in apart.points)
    for pt in apart.points:
        a = tomllib.loads(series.scene_of(**pt, seed=2, **apart.arguments).toml)
        b = tomllib.loads(series.scene_of(**same[int(pt["cells_per_diameter"])], seed=2, **cal.arguments).toml)
        assert a["numerics"]["stokes"].pop("fibre_shells") == "apart"
        assert a == b


def test_the_calibrated_beta5_series_is_the_series_at_the_grid_the_preset_takes():
    """ci_fluid_series_calibrated_apart.toml: the β = 5 series' points and seeds (so the same initial
    states) and more concentrations, each with its twins; its Stokes runs voxelised at the radius
    scale and shell rule of the 42³ row of ci_resolution_calibrated_apart.toml, which is the row
    numerics.preset = "study" takes at β = 5 (pyfold.scene.study_preset.RESOLUTION); both models
    record Zhang's β_e, the ξ of the grid fibre whose changes that row holds. A scene differs from
    the series' scene at its concentration only by those keys."""
    import tomllib

    from pyfold.scene import study_preset as sp

    plain, cal = (load_form(STUDIES / "sweeps", n, False)
                  for n in ("ci_fluid_series", "ci_fluid_series_calibrated_apart"))
    res = load_form(STUDIES / "sweeps", "ci_resolution_calibrated_apart", False)
    assert all(p in cal.points for p in plain.points) and cal.seeds == plain.seeds
    for n_l3 in {p["n_l3"] for p in cal.points}:  # every concentration has its contacts-only twins
        assert sorted(p["model"] for p in cal.points if p["n_l3"] == n_l3) == ["jeffery", "stokes"]
    row = sp.resolution_for(5.0).choice()
    grid = next(p for p in res.points if p["cells_per_diameter"] == series.STOKES["cells_per_diameter"])
    assert (grid["fibre_radius_scale"], res.arguments["fibre_shells"]) == (
        cal.arguments["fibre_radius_scale"], cal.arguments["fibre_shells"])
    assert (row.cells_per_diameter, row.fibre_radius_scale, row.fibre_shells) == (
        series.STOKES["cells_per_diameter"], cal.arguments["fibre_radius_scale"], cal.arguments["fibre_shells"])
    assert cal.arguments["equivalent_aspect_ratio"] == "zhang"
    extra = {"fibre_radius_scale", "fibre_shells"}
    for pt in cal.points:
        a = tomllib.loads(series.scene_of(**pt, seed=3, **cal.arguments).toml)
        b = tomllib.loads(series.scene_of(**pt, seed=3, **plain.arguments).toml)
        assert a["particles"][0].pop("equivalent_aspect_ratio") == "zhang"
        if pt["model"] == "stokes":
            got = {k: a["numerics"]["stokes"].pop(k) for k in extra}
            assert got == {k: cal.arguments[k] for k in extra}
        assert a == b


@pytest.mark.parametrize("flags", [[], ["--calibrated", "--beta", "10", "--shells", "apart"]])
def test_the_shipped_table_is_not_written_from_a_series_it_does_not_ship(flags, tmp_path):
    """--write-data of the geometric β = 5 series (the shipped β = 5 rows are the series on the grid the
    preset takes) or of the β = 10 series with the shells apart (the shipped β = 10 rows overlap them)
    exits 2 naming the option, before any run, with the table untouched."""
    import subprocess
    import sys

    before = series.DATA.with_suffix(".csv").read_bytes()
    proc = subprocess.run([sys.executable, str(STUDIES / "interaction_coefficient" / "ci_fluid_series.py"),
                           "--write-data", "--out", str(tmp_path / "out"), *flags],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "--write-data: the shipped" in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists() and series.DATA.with_suffix(".csv").read_bytes() == before


def test_the_series_reads_the_measured_change_of_its_solves_and_resolution(tmp_path):
    """ci_fluid_series.reuse_errors: the error of a sweep's solve interval is the solve-reuse study's
    paired change of that setting ⊕ its s.e. (closure-free, IBOF trajectory); none for the series'
    own every 4th step; a missing study or setting stops the analysis naming it.
    resolution_errors reads the β = 10 check's summary the same way."""
    import json

    import xarray as xr

    nc = tmp_path / "reuse.nc"
    xr.Dataset({"change_closure_free": ("setting", [0.0, 3e-5]), "change_closure_free_stderr": ("setting", [0.0, 4e-5]),
                "change_ibof_trajectory": ("setting", [0.0, -5e-5]),
                "change_ibof_trajectory_stderr": ("setting", [0.0, 12e-5])},
               coords={"setting": ["every 4, linear", "every 16, jeffery"]}).to_netcdf(nc, engine="h5netcdf")
    assert series.reuse_errors({"dt": 0.02}, nc) is None
    assert series.reuse_errors({"solve_every": 16, "reuse": "jeffery"}, nc) == pytest.approx((5e-5, 13e-5))
    with pytest.raises(SystemExit, match="every 8, jeffery"):
        series.reuse_errors({"solve_every": 8, "reuse": "jeffery"}, nc)
    with pytest.raises(SystemExit, match="solve_reuse.py"):
        series.reuse_errors({"solve_every": 16, "reuse": "jeffery"}, tmp_path / "missing.nc")
    js = tmp_path / "res.json"
    summary = {"closure_free": {"coarse_bias": 3e-4, "coarse_bias_stderr": 4e-4},
               "ibof_trajectory": {"coarse_bias": -6e-4, "coarse_bias_stderr": 8e-4}}
    js.write_text(json.dumps(summary))
    assert series.resolution_errors(js, ("closure_free", "ibof_trajectory")) == pytest.approx((5e-4, 1e-3))
    # the control on the sweep's own grid wins over the 72³ study; another grid's or setting's does not
    args = {"solve_every": 16, "reuse": "jeffery", "cells_per_diameter": 4}
    control = {"cells_per_diameter": 4, "series": "every 16, jeffery", "against": "every 4, linear",
               "closure_free": {"change": 6e-5, "stderr": 8e-5}, "ibof_trajectory": {"change": 0.0, "stderr": 2e-5}}
    js.write_text(json.dumps({**summary, "solve_interval": control}))
    assert series.reuse_errors(args, nc, js) == pytest.approx((1e-4, 2e-5))
    assert series.reuse_errors({**args, "cells_per_diameter": 3}, nc, js) == pytest.approx((5e-5, 13e-5))
    # a measurement at the point's own concentration and grid wins over both, at that concentration only
    here = tmp_path / "concentrated.nc"
    xr.Dataset({"change_closure_free": ("setting", [0.0, 3e-4]), "change_closure_free_stderr": ("setting", [0.0, 4e-4]),
                "change_ibof_trajectory": ("setting", [0.0, 0.0]),
                "change_ibof_trajectory_stderr": ("setting", [0.0, 1e-4])},
               coords={"setting": ["every 4, linear", "every 16, jeffery"]},
               attrs={"n_l3": 12.7, "cells_per_diameter": 4}).to_netcdf(here, engine="h5netcdf")
    values, source = series.reuse_evidence(args, nc, js, here, 12.7)
    assert values == pytest.approx((5e-4, 1e-4)) and str(here) in source
    values, source = series.reuse_evidence(args, nc, js, here, 6.4)
    assert values == pytest.approx((1e-4, 2e-5)) and "phi beta 0.5 on this grid" in source
    assert series.reuse_errors({**args, "cells_per_diameter": 3}, nc, js, here, 12.7) == pytest.approx((5e-5, 13e-5))


def test_the_series_and_its_twins_share_the_initial_state_and_step():
    """A seed's Stokes run and contacts-only twin differ in the model only (paired comparison)."""
    import tomllib

    a = tomllib.loads(series.scene_of(5.0, "stokes", 3, 200.0).toml)
    b = tomllib.loads(series.scene_of(5.0, "jeffery", 3, 200.0).toml)
    for key in ("cell", "flow", "particles", "output"):
        assert a[key] == b[key], key
    assert a["numerics"]["seed"] == b["numerics"]["seed"] and a["numerics"]["dt"] == b["numerics"]["dt"]


def test_the_long_contacts_only_runs_continue_the_series_twins():
    """steady_state_strain.py's runs are the series' contacts-only twins with a later end only, so
    their first 200 strain are those twins' (the same seed, placement, step and records)."""
    import tomllib

    spec, twins = load_form(STUDIES / "sweeps", "steady_state_strain", False), load_form(STUDIES / "sweeps",
                                                                                           "ci_fluid_series", False)
    assert spec.seeds == twins.seeds and spec.arguments["t_end"] > twins.arguments["t_end"]
    assert {p["n_l3"] for p in spec.points} == {p["n_l3"] for p in twins.points if p["model"] == "jeffery"}
    long = tomllib.loads(series.scene_of(5.0, "jeffery", 2, spec.arguments["t_end"]).toml)
    short = tomllib.loads(series.scene_of(5.0, "jeffery", 2, twins.arguments["t_end"]).toml)
    for table in (long, short):
        table.pop("title")
        del table["numerics"]["t_end"], table["output"]["snapshot_interval"]
    assert long == short


def test_an_extended_fluid_run_differs_from_the_series_run_by_its_end_only():
    """pyfold.extend continues a run only for a scene that differs by a larger t_end (the recorded
    snapshot interval kept): the steady-state study's scene for the series' Stokes run."""
    import tomllib

    steady = import_study("interaction_coefficient", "steady_state_strain")
    longer = tomllib.loads(steady.extended_scene(8.0, 3, 400.0))
    recorded = tomllib.loads(series.scene_of(8.0, "stokes", 3, steady.series_t_end()).toml)
    assert longer["numerics"].pop("t_end") == 400.0 and recorded["numerics"].pop("t_end") == steady.series_t_end()
    assert longer == recorded


def test_a_warm_started_fluid_run_is_the_series_run_with_given_centres_and_axes(tmp_path):
    """steady_state_strain.py --warm: the series' Stokes scene, its fibres at the centres and axes
    of the files beside it (here 157 fibres along x on a lattice 1.35 L by 0.225 L by 0.225 L, gaps
    0.35 L and 1.25 α), which load_scene places exactly."""
    import tomllib

    from pyfold.scene import load_scene

    steady = import_study("interaction_coefficient", "steady_state_strain")
    text = steady.warm_scene(8.0, 2, 150.0)
    warm, plain = tomllib.loads(text), tomllib.loads(series.scene_of(8.0, "stokes", 2, 150.0).toml)
    family = warm["particles"][0]
    assert (family.pop("orientation"), family.pop("orientations"), family.pop("positions")) == (
        "given", "orientations.npy", "positions.npy")
    assert plain["particles"][0].pop("orientation") == "isotropic" and warm == plain
    n = plain["particles"][0]["count"]
    g = np.stack(np.meshgrid(np.arange(2), np.arange(12), np.arange(12), indexing="ij"), -1).reshape(-1, 3)[:n]
    x = (g + 0.5) * np.array([1.35, 0.225, 0.225])
    np.save(tmp_path / "positions.npy", x)
    np.save(tmp_path / "orientations.npy", np.tile([1.0, 0.0, 0.0], (n, 1)))
    (tmp_path / "scene.toml").write_text(text)
    resolved = load_scene(tmp_path / "scene.toml")
    assert resolved.hydrodynamics == "stokes"
    fam = resolved.families[0]
    assert fam.orientation == "given" and np.array_equal(fam.positions, x)
    assert np.array_equal(fam.axes, np.tile([1.0, 0.0, 0.0], (n, 1)))


@pytest.mark.parametrize("p", [0.7, 1.0, 2.0, 3.5])
def test_observed_order_and_richardson_recover_a_power_law(p):
    """c(h) = c_inf + k h^p on the study's three grids: the order is p (brentq to its tolerance)."""
    h = [1 / 3.11, 1 / 4.0, 1 / 5.19]
    c = [2e-3 - 1.5e-3 * x ** p for x in h]
    got = resolution.observed_order(c, h)
    assert got == pytest.approx(p, rel=1e-6)
    r = (h[1] / h[2]) ** got
    assert c[2] + (c[2] - c[1]) / (r - 1) == pytest.approx(2e-3, rel=1e-9)


def test_no_order_when_the_differences_change_sign():
    assert math.isnan(resolution.observed_order([1.0, 2.0, 1.5], [0.3, 0.25, 0.17]))


def _rows(points):
    return [{"beta": 5.0, "model": "stokes", "closure": "ibof", "estimator": "trajectory", "phi_beta": x, "ci": y,
             "total_err": e} for x, y, e in points]


def test_fit_is_the_weighted_least_squares_line_with_its_covariance():
    pts = [(0.4, 3.0e-3, 2e-4), (0.8, 4.0e-3, 1e-4), (1.2, 5.5e-3, 3e-4)]
    fit = fluid_coupled_fit(rows=_rows(pts))
    x, y, e = (np.array(v) for v in zip(*pts))
    c, cov = np.polyfit(x, y, 1, w=1 / e, cov="unscaled")  # independent route: numpy's weighted fit
    assert (fit.c1, fit.c0) == pytest.approx(tuple(c), rel=1e-10)
    assert fit.cov[1][1] == pytest.approx(cov[0, 0], rel=1e-10) and fit.cov[0][0] == pytest.approx(cov[1, 1], rel=1e-10)
    value, err = fit(0.8)
    assert value == pytest.approx(c[0] * 0.8 + c[1]) and err == pytest.approx(
        math.sqrt(cov[1, 1] + 2 * 0.8 * cov[0, 1] + 0.64 * cov[0, 0]), rel=1e-10)


def test_two_points_are_interpolated_exactly():
    fit = fluid_coupled_fit(rows=_rows([(0.4, 3e-3, 1e-4), (1.2, 5e-3, 1e-4)]))
    assert fit(0.4)[0] == pytest.approx(3e-3) and fit(1.2)[0] == pytest.approx(5e-3) and fit.chi2 < 1e-20


def test_the_fit_is_not_quoted_outside_its_beta_or_range():
    rows = _rows([(0.4, 3e-3, 1e-4), (1.2, 5e-3, 1e-4)])
    values, words = fluid_coupled_ci(10.0, 0.8, rows=rows)
    assert not values and "beta = 10" in words
    values, words = fluid_coupled_ci(5.0, 2.0, rows=rows)
    assert not values and "outside" in words
    values, words = fluid_coupled_ci(5.0, 0.8, rows=rows)
    assert set(values) == {"ibof (trajectory)"} and values["ibof (trajectory)"][0] == pytest.approx(4e-3)


def test_the_shipped_table_covers_three_concentrations_with_all_errors():
    """Every aspect ratio of the shipped table: three concentrations or more, every error part
    measured (resolution included) and the total their quadrature sum, and a fit of its own."""
    rows = fluid_coupled_table()
    for beta in sorted({r["beta"] for r in rows}):
        stokes = [r for r in rows if r["model"] == "stokes" and r["beta"] == beta]
        assert len({r["n_l3"] for r in stokes}) >= 3, beta
        for r in stokes:
            parts = [r[k] for k in ("stat_err", "settings_err", "shape_err", "resolution_err")]
            assert all(math.isfinite(v) and v >= 0.0 for v in parts) and min(parts[:2] + parts[3:]) > 0.0
            assert r["total_err"] == pytest.approx(math.sqrt(sum(v * v for v in parts)), rel=1e-4)  # 6 digits in the csv
        fit = fluid_coupled_fit("ibof", "trajectory", rows=rows, beta=beta)
        assert math.isfinite(fit.c0) and math.isfinite(fit.c1) and fit.points >= 3 and fit.beta == beta


def test_the_fit_of_a_table_of_several_aspect_ratios_needs_its_beta():
    rows = _rows([(0.4, 3e-3, 1e-4), (1.2, 5e-3, 1e-4)]) + [
        {**r, "beta": 10.0} for r in _rows([(0.25, 1e-3, 1e-4), (1.0, 2e-3, 1e-4)])]
    with pytest.raises(ValueError, match="beta: the table has beta 5, 10"):
        fluid_coupled_fit(rows=rows)
    with pytest.raises(ValueError, match="beta: 20 is not in the table"):
        fluid_coupled_fit(rows=rows, beta=20.0)
    ten = fluid_coupled_fit(rows=rows, beta=10.0)
    assert ten.beta == 10.0 and ten(0.25)[0] == pytest.approx(1e-3) and ten(1.0)[0] == pytest.approx(2e-3)
    assert fluid_coupled_fit(rows=rows, beta=5.0)(0.4)[0] == pytest.approx(3e-3)


def test_an_unmeasured_resolution_error_is_left_out_of_the_total_and_flagged():
    """At β = 10 the resolution study has not run: the rows keep NaN in its column, the total is
    the other parts in quadrature, and ``resolution_in_total`` says which total is which; at β = 5
    a missing resolution file leaves the total unknown (NaN), not smaller."""
    from types import SimpleNamespace

    from pyfold.ensemble import EnsembleMean

    run = SimpleNamespace(stationary=False, onset_time=40.0, t=np.array([0.0, 200.0]),
                          drift={"a_xx": (1e-4, 1e-4)})
    e = EnsembleMean(3e-3, 3e-4, 2e-4, 4)
    rep = SimpleNamespace(runs=[run] * 4, n=4, n_l3=6.3657, ci={"exact": e}, ci_fit={"ibof": e},
                          closures=("exact",), judged=("ibof",))
    shift = {("exact", "steady"): 1e-4, ("ibof", "trajectory"): 2e-4}
    unknown = series.table_rows(6.3657, "stokes", rep, (4e-4, 5e-4), shift, beta=10.0, resolution_unmeasured=True)
    known = series.table_rows(6.3657, "stokes", rep, (4e-4, 5e-4), shift, (7e-4, 8e-4), beta=10.0)
    missing = series.table_rows(6.3657, "stokes", rep, (4e-4, 5e-4), shift, beta=5.0)
    assert len(unknown) == len(known) == len(missing) == 2
    assert all(math.isnan(m["total_err"]) and m["resolution_in_total"] == 1 for m in missing)
    for u, k in zip(unknown, known):
        assert math.isnan(u["resolution_err"]) and u["resolution_in_total"] == 0 and k["resolution_in_total"] == 1
        parts = (u["stat_err"], u["settings_err"], u["shape_err"])
        assert u["total_err"] == pytest.approx(math.sqrt(sum(p * p for p in parts)), rel=1e-12)
        assert k["total_err"] == pytest.approx(math.hypot(u["total_err"], k["resolution_err"]), rel=1e-12)
        assert u["phi_beta"] == pytest.approx(0.5, abs=1e-4) and u["beta"] == 10.0


def test_grid_fibre_shape_interpolates_the_diameter_between_bracketing_measurements():
    """grid_fibre_shape.diameter_for: exact on a linear β_e(d), in any input order; NaN outside the
    measured range; on a convex curve, between the bracketing pair's diameters."""
    shape = import_study("interaction_coefficient", "grid_fibre_shape")
    d = [0.125, 0.1, 0.111, 0.118]
    linear = [20.0 - 100.0 * x for x in d]
    assert shape.diameter_for(8.5, d, linear) == pytest.approx(0.115, rel=1e-12)
    assert math.isnan(shape.diameter_for(20.0, d, linear))
    convex = [1.0 / x ** 2 for x in d]
    got = shape.diameter_for(1.0 / 0.105 ** 2, d, convex)
    assert 0.1 < got < 0.111 and got != pytest.approx(0.105, rel=1e-6)


def test_grid_fibre_shape_refuses_a_bad_aspect_ratio_naming_it(tmp_path):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, str(STUDIES / "interaction_coefficient" / "grid_fibre_shape.py"),
                           "--betas", "9", "1", "--out", str(tmp_path / "out")], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2 and "--betas: 1; aspect ratios must be > 1" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_a_beta10_table_joins_the_shipped_beta5_one_without_touching_its_rows(tmp_path):
    """ci_fluid_series.py --beta 10 --calibrated --write-data: merged_table keeps the shipped table's
    β = 5 rows and header (prefixed beta5_), replaces its β = 10 rows, and a second write replaces
    them rather than adding them twice; pyfold.correlations reads the result and fits each β alone."""
    import shutil

    shipped = tmp_path / "ci_fluid_coupled.csv"
    shutil.copy(series.DATA.with_suffix(".csv"), shipped)
    five = [r for r in fluid_coupled_table(shipped) if r["beta"] == 5.0]
    old_head = {k: v for k, v in series.read_attrs(shipped).items() if k.startswith("beta5_")}
    assert five and old_head
    rows = []
    for r in five:  # a β = 10 table of the same shape: φβ 0.25 / 0.5 / 1.0
        if r["model"] == "stokes":
            rows.append({**r, "beta": 10.0, "phi_beta": r["phi_beta"] * 0.8, "ci": r["ci"] / 2,
                         "resolution_in_total": 1})
    attrs = {"title": "beta 10 table", "command": "the beta 10 command", "seeds": "1 2 3 4"}
    for _ in range(2):
        merged, head = series.merged_table(rows, attrs, 10.0, shipped)
        series.write_table(merged, tmp_path / "ci_fluid_coupled", head)
    back = fluid_coupled_table(shipped)
    assert len(back) == len(five) + len(rows)
    assert [r for r in back if r["beta"] == 5.0] == [{**r, "resolution_in_total": 1.0} for r in five]
    head = series.read_attrs(shipped)
    assert head["title"].endswith("beta = 5, 10 fibres") and head["beta10_command"] == "the beta 10 command"
    assert all(head[k] == v for k, v in old_head.items())
    values, text = fluid_coupled_ci(10.0, 0.5, rows=back)
    assert values and "beta 10" in text
    five_values, _ = fluid_coupled_ci(5.0, 0.78, rows=back)
    assert five_values == fluid_coupled_ci(5.0, 0.78, rows=five)[0]


@pytest.mark.parametrize("beta, sweep", [(5.0, "ci_fluid_series_calibrated_apart"),
                                         (10.0, "ci_fluid_series_beta10_calibrated")])
def test_the_shipped_table_names_the_radius_shells_and_beta_e_of_its_runs(beta, sweep):
    """The header of each aspect ratio's rows in data/ci_fluid_coupled.csv states the voxelised
    radius scale, the shell rule and the β_e rule of the sweep that made them, and takes the shape
    error against the recorded β_e (not Cox's, which these runs do not record)."""
    spec = load_form(STUDIES / "sweeps", sweep, False)
    head = {k: v for k, v in series.read_attrs(series.DATA.with_suffix(".csv")).items()
            if k.startswith(f"beta{beta:g}_")}
    args = spec.arguments
    assert f"'fibre_radius_scale': {args['fibre_radius_scale']!r}" in head[f"beta{beta:g}_stokes_numerics"]
    if "fibre_shells" in args:
        assert f"'fibre_shells': {args['fibre_shells']!r}" in head[f"beta{beta:g}_stokes_numerics"]
    rule = args["equivalent_aspect_ratio"].capitalize()
    assert head[f"beta{beta:g}_scene"].endswith(f"both models recording {rule}'s beta_e")
    assert f"instead of the recorded ({rule}'s)" in head[f"beta{beta:g}_errors"]


def test_the_documented_fits_are_those_of_the_shipped_table():
    """docs/fluid_coupled_ci.md lists the fit of each aspect ratio of data/ci_fluid_coupled.csv as
    ci_fluid_series.fit_lines gives it: a new table without the new fits in the docs fails here."""
    docs = (Path(__file__).resolve().parents[2] / "docs" / "fluid_coupled_ci.md").read_text(encoding="utf-8")
    rows = fluid_coupled_table()
    for beta in sorted({r["beta"] for r in rows}):
        lines = series.fit_lines(rows, beta)
        assert len(lines) == 4, beta
        for line in lines:
            assert line in docs, line
