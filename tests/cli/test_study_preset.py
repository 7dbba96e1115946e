"""`numerics.preset = "study"`: the numerical keys a scene leaves unset are chosen from the
measured evidence (pyfold/scene/study_preset.py), keys the scene states win, and the choice
and its evidence are recorded in the resolved scene and the run file.

The mechanism is checked on an evidence table made for the test (so each rule has a case
whose outcome is known); the shipped table is checked for consistency with the preset's rule.
"""
from __future__ import annotations

import math
from types import MappingProxyType

import pytest
import tomli_w

from pyfold.scene import parse_scene
from pyfold.scene import study_preset as sp

FIBRE = {"shape": "fibre", "length": 1.0, "radius": 0.1}  # beta = 5, as the measured scenes


def _scene(count: int = 98, side: float = 2.7, numerics: dict | None = None, stokes: dict | None = None,
           output: dict | None = None, particle: dict | None = None, **model) -> str:
    num = {"t_end": 1.0, "preset": "study", **(numerics or {})}
    num = {k: v for k, v in num.items() if v is not None}
    if stokes:
        num["stokes"] = stokes
    data = {"cell": {"dim": 3, "size": [side] * 3}, "flow": {"type": "simple_shear", "rate": 1.0},
            "particles": [dict(particle or FIBRE, count=count)], "model": {"hydrodynamics": "stokes", **model},
            "numerics": num}
    if output:
        data["output"] = output
    return tomli_w.dumps(data)


def _m(name, stokes, change, cpu, dt_factor=1.0):
    return sp.Measured(name=name, stokes=stokes, dt_factor=dt_factor, closure_free=change, closure_free_stderr=0.1,
                       trajectory=change, trajectory_stderr=0.2, cpu_ratio=cpu)


REF = _m("tol1e-4", {"cells_per_diameter": 3, "kappa": 1e3, "tolerance": 1e-4}, 0.0, 1.0)


def _evidence(settings):
    return MappingProxyType({"semi-dilute": sp.RegimeEvidence(
        regime="semi-dilute", beta=5.0, n_l3=5.0, n_fibres=98, seeds=4, reference=REF, settings=tuple(settings),
        period_error=-0.16)})


def _grid(cells, change, cpu, scale=1.0, shells="overlap"):
    return sp.GridMeasured(cells, f"{cells}", scale, closure_free=change, closure_free_stderr=0.1, trajectory=change,
                           trajectory_stderr=0.2, cpu_ratio=cpu, fibre_shells=shells)


@pytest.fixture
def evidence(monkeypatch):
    """Replace the preset's tables by ones made for the test; no resolution study unless given."""
    def use(settings, grids=None, beta_evidence=None):
        monkeypatch.setattr(sp, "EVIDENCE", _evidence(settings))
        monkeypatch.setattr(sp, "BETA_EVIDENCE", MappingProxyType(beta_evidence or {}))
        monkeypatch.setattr(sp, "RESOLUTION", MappingProxyType(
            {5.0: sp.ResolutionEvidence(beta=5.0, scene="test scene", grids=tuple(grids), study="test study")}
            if grids else {}))
    return use


def test_the_cheapest_admissible_setting_fills_the_unset_keys_and_the_step(evidence):
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6),
              _m("every4", {"tolerance": 1e-3, "solve_every": 4}, 0.3, 0.3, dt_factor=2.0),
              _m("cheapest but off", {"tolerance": 1e-2, "rigidity": "exact"}, 0.8, 0.1)])
    r = parse_scene(_scene(), "s.toml")
    st = r.scene.numerics.stokes
    assert (st.tolerance, st.solve_every) == (1e-3, 4)
    # dt = 2 alpha / (gamma_dot L), alpha = 0.1 R by default, and a divisor of t_end
    assert r.dt == pytest.approx(1.0 / math.ceil(1.0 / (2 * 0.01 / 1.0)))
    assert "every4" in r.preset_reason and "0.30" in r.preset_reason and "cheapest but off" not in r.preset_reason
    assert "at 3 voxels per diameter" in r.preset_reason and "-16 %" in r.preset_reason


def test_without_an_admissible_cheaper_setting_the_reference_numerics_are_used_and_named(evidence):
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.8, 0.6), _m("every4", {"solve_every": 4}, 0.6, 0.2)])
    r = parse_scene(_scene(), "s.toml")
    st = r.scene.numerics.stokes
    assert (st.tolerance, st.solve_every, st.cells_per_diameter) == (1e-4, 1, 3)
    assert "the reference numerics tol1e-4" in r.preset_reason and "tol1e-3 0.80" in r.preset_reason


def test_keys_the_scene_states_win_and_are_named(evidence):
    evidence([_m("every4", {"tolerance": 1e-3, "solve_every": 4}, 0.3, 0.3)])
    r = parse_scene(_scene(numerics={"dt": 0.005}, stokes={"solve_every": 2}), "s.toml")
    assert r.scene.numerics.stokes.solve_every == 2 and r.scene.numerics.stokes.tolerance == 1e-3
    assert r.dt == 0.005
    assert "kept as the scene states: solve_every" in r.preset_reason


def test_a_chosen_step_divides_the_output_intervals_the_scene_gives(evidence):
    evidence([_m("dt", {"tolerance": 1e-3}, 0.1, 0.5, dt_factor=3.0)])
    r = parse_scene(_scene(output={"interval": 0.25}), "s.toml")
    assert r.dt <= 3 * 0.01 / 1.0 + 1e-15
    assert abs(0.25 / r.dt - round(0.25 / r.dt)) < 1e-9 and abs(1.0 / r.dt - round(1.0 / r.dt)) < 1e-9


def test_without_evidence_for_the_scene_the_defaults_stand_and_the_reason_says_why(evidence):
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)])
    spheres = _scene(count=20, particle={"shape": "sphere", "radius": 0.2})
    r = parse_scene(spheres, "s.toml")
    assert r.scene.numerics.stokes.tolerance == 1e-6
    assert "no measured evidence" in r.preset_reason and r.dt > 0


def test_a_scene_without_preset_and_without_dt_is_refused_naming_the_key():
    from pyfold.errors import InputError

    with pytest.raises(InputError, match="numerics.dt"):
        parse_scene(_scene(numerics={"preset": None}), "s.toml")


def test_the_shipped_evidence_follows_the_preset_rule():
    assert sp.EVIDENCE, "pyfold/scene/study_preset.py holds no measurement"
    for regime, ev in sp.EVIDENCE.items():
        assert ev.regime == regime and ev.reference.cpu_ratio == 1.0 and ev.reference.change() == 0.0
        for m in ev.settings:
            values = (m.closure_free, m.closure_free_stderr, m.trajectory, m.trajectory_stderr, m.cpu_ratio)
            assert all(math.isfinite(v) and v >= 0 for v in values), (regime, m)
        _, chosen = sp.choice_for(regime)
        cheaper_admissible = [m for m in ev.settings if sp.admissible(m) and m.cpu_ratio < chosen.cpu_ratio]
        assert not cheaper_admissible and (chosen is ev.reference or sp.admissible(chosen))


def test_the_reason_is_written_to_the_run_file(evidence, tmp_path):
    from pyfold.scene import load_scene

    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)])
    path = tmp_path / "s.toml"
    path.write_text(_scene())
    datasets = load_scene(path).resolved_datasets()
    assert "numerics_preset_reason" in datasets and "tol1e-3" in datasets["numerics_preset_reason"][0]


def test_settings_error_is_the_measured_absolute_change():
    """The absolute error a study carries for a setting (pyfold.scene.study_preset.RegimeEvidence.settings_error)
    equals the paired change and its s.e. in quadrature that docs/speed_accuracy.md tabulates in absolute
    units (semi-dilute, a solve every 4th step: closure-free +4.6e-5 ± 1.7e-4, IBOF +2.0e-4 ± 2.4e-4;
    the stored ratios carry two digits, hence the 10 %)."""
    import math

    from pyfold.scene.study_preset import EVIDENCE

    ev = EVIDENCE["semi-dilute"]
    m = next(s for s in ev.settings if s.name == "tol1e-3_every4")
    closure_free, trajectory = ev.settings_error(m)
    assert closure_free == pytest.approx(math.hypot(4.6e-5, 1.7e-4), rel=0.1)
    assert trajectory == pytest.approx(math.hypot(2.0e-4, 2.4e-4), rel=0.1)


def test_the_coarsest_grid_within_the_rule_is_filled_with_its_calibrated_radius(evidence):
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)],
             grids=[_grid(2, 0.9, 1.0, 1.3), _grid(3, 0.3, 2.0, 1.2), _grid(4, 0.0, 4.0, 1.1)])
    r = parse_scene(_scene(), "s.toml")
    st = r.scene.numerics.stokes
    assert (st.cells_per_diameter, st.fibre_radius_scale) == (3, 1.2)
    assert r.stokes_grid == (42, 42, 42)  # 2.7 / (0.2 / 3) = 40.5, rounded up to 2^a 3^b 5^c 7^d
    assert "cells_per_diameter = 3, the coarsest grid" in r.preset_reason
    assert "2 voxels per diameter 0.90" in r.preset_reason
    assert not any("too coarse" in w for w in r.warnings)


def test_a_calibrated_grid_brings_the_shell_rule_its_study_ran(evidence):
    """The radius and the shell rule are one calibration: the preset fills both from the grid's
    row; a scene that states another rule keeps it, and the reason says the measurement's."""
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)],
             grids=[_grid(3, 0.1, 1.0, 1.129, "apart"), _grid(4, 0.0, 2.0, 1.094, "apart")])
    r = parse_scene(_scene(), "s.toml")
    st = r.scene.numerics.stokes
    assert (st.cells_per_diameter, st.fibre_radius_scale, st.fibre_shells) == (3, 1.129, "apart")
    assert "fibre_shells = 'apart'" in r.preset_reason and "ran with fibre_shells" not in r.preset_reason
    r = parse_scene(_scene(stokes={"fibre_shells": "overlap"}), "s.toml")
    assert r.scene.numerics.stokes.fibre_shells == "overlap"
    assert "ran with fibre_shells = 'apart', this scene with 'overlap'" in r.preset_reason
    # a geometric row (scale 1) leaves the rule to the scene: the default stands
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)], grids=[_grid(3, 0.1, 1.0), _grid(4, 0.0, 2.0)])
    assert parse_scene(_scene(), "s.toml").scene.numerics.stokes.fibre_shells == "overlap"


def test_the_main_jobs_scene_gets_its_resolution_studys_grid_without_a_too_coarse_warning():
    """data/scenes/fluid_coupled.toml leaves the grid to the preset: 3 voxels per diameter with the
    calibrated radius and the shells apart, the row the shipped β = 5 resolution study admits, and
    records the grid fibre's β_e (Zhang's rule) that row's changes were measured with."""
    from pyfold.commands.main_job import FLUID_SCENE
    from pyfold.scene import load_scene

    r = load_scene(FLUID_SCENE)
    row = sp.resolution_for(5.0).choice()
    st = r.scene.numerics.stokes
    assert (st.cells_per_diameter, st.fibre_radius_scale, st.fibre_shells) == (
        row.cells_per_diameter, row.fibre_radius_scale, row.fibre_shells)
    assert row.fibre_shells == "apart" and sp.admissible(row)
    assert r.stokes_grid == (42, 42, 42)
    assert r.scene.particles[0].equivalent_aspect_ratio == "zhang"
    assert not any("too coarse" in w for w in r.warnings) and "too coarse" not in r.preset_reason
    # the coarse grid's warning: the viscosity stays biased, the rotation is the calibrated radius'
    coarse = [w for w in r.warnings if w.startswith("numerics.stokes.cells_per_diameter: the Stokes grid")]
    assert len(coarse) == 1 and "fibre_radius_scale = 1.129" in coarse[0]
    assert "rotation rates are biased" not in coarse[0]
    assert "rotation rates are biased" in next(
        w for w in parse_scene(_scene(stokes={"cells_per_diameter": 3, "fibre_radius_scale": 1.0}), "s.toml").warnings
        if w.startswith("numerics.stokes.cells_per_diameter: the Stokes grid"))


def test_a_stated_grid_known_to_be_too_coarse_is_kept_and_the_run_says_so(evidence):
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)],
             grids=[_grid(2, 0.9, 1.0), _grid(3, 0.3, 2.0), _grid(4, 0.0, 4.0)])
    r = parse_scene(_scene(stokes={"cells_per_diameter": 2}), "s.toml")
    assert r.scene.numerics.stokes.cells_per_diameter == 2
    assert "known to be too coarse" in r.preset_reason and "3 voxels per diameter keeps it" in r.preset_reason
    too_coarse = [w for w in r.warnings if "too coarse for C_I" in w]
    assert len(too_coarse) == 1 and too_coarse[0].startswith("numerics.stokes.cells_per_diameter = 2")
    # a stated grid within the rule: no warning
    r = parse_scene(_scene(stokes={"cells_per_diameter": 4}), "s.toml")
    assert not any("too coarse for C_I" in w for w in r.warnings) and "finest grid of test study" in r.preset_reason
    # coarser than the coarsest measured grid, which already fails: known too coarse as well
    r = parse_scene(_scene(stokes={"cells_per_diameter": 1}), "s.toml")
    assert any("too coarse for C_I" in w for w in r.warnings)


def test_the_grid_budget_follows_the_grid_the_preset_chose_but_not_a_stated_one(evidence):
    from pyfold.errors import InputError

    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)], grids=[_grid(9, 0.1, 1.0), _grid(10, 0.0, 2.0)])
    r = parse_scene(_scene(), "s.toml")
    n = math.prod(r.stokes_grid)
    assert r.scene.numerics.stokes.max_grid_points == n > 64 ** 3 and f"raised to the grid's {n}" in r.preset_reason
    with pytest.raises(InputError, match="numerics.stokes.max_grid_points"):
        parse_scene(_scene(stokes={"cells_per_diameter": 9}), "s.toml")
    # under hydrodynamics = "auto" the budget decides whether the solver runs: the scene's, left alone
    r = parse_scene(_scene(hydrodynamics="auto"), "s.toml")
    assert r.scene.numerics.stokes.max_grid_points == 64 ** 3 and r.hydrodynamics != "stokes"


def test_a_setting_measured_against_another_is_judged_by_the_sum_of_the_chain(evidence):
    step = _m("dt2", {"tolerance": 1e-3}, 0.3, 0.5, dt_factor=2.0)
    chained = sp.Measured(name="every8", stokes={"tolerance": 1e-3, "solve_every": 8}, dt_factor=2.0,
                          closure_free=0.3, closure_free_stderr=0.1, trajectory=0.1, trajectory_stderr=0.2,
                          cpu_ratio=0.2, against="dt2")
    evidence([step, chained])
    ev, chosen = sp.choice_for("semi-dilute")
    total = ev.total(chained)
    assert total.closure_free == pytest.approx(0.6)
    assert total.closure_free_stderr == pytest.approx(math.hypot(0.1, 0.1), abs=0.005)  # kept to 2 digits
    assert chosen.name == "dt2"  # every8 passes on its own change (0.3) but not on the chain's (0.6)


def test_another_aspect_ratio_takes_its_own_evidence_and_any_other_the_beta_5_rows(evidence):
    own = sp.RegimeEvidence(regime="semi-dilute", beta=10.0, n_l3=6.4, n_fibres=88, seeds=4, reference=REF,
                            settings=(_m("beta10 row", {"tolerance": 1e-3, "solve_every": 16}, 0.2, 0.1),),
                            period_error=0.0)
    evidence([_m("tol1e-3", {"tolerance": 1e-3}, 0.1, 0.6)], beta_evidence={("semi-dilute", 10.0): own})
    thin = dict(FIBRE, radius=0.05)
    r = parse_scene(_scene(count=88, side=2.4, particle=thin, stokes={"max_grid_points": 10 ** 6}), "s.toml")
    assert r.scene.numerics.stokes.solve_every == 16 and "beta10 row" in r.preset_reason
    assert "this scene's beta" not in r.preset_reason
    r = parse_scene(_scene(count=98, particle=dict(FIBRE, radius=1 / 14)), "s.toml")  # beta = 7
    assert "tol1e-3" in r.preset_reason and "this scene's beta = 7: not measured" in r.preset_reason


def test_the_shipped_resolution_evidence_follows_the_preset_rule():
    assert sp.RESOLUTION, "pyfold/scene/study_preset.py holds no resolution study"
    for beta, res in sp.RESOLUTION.items():
        cells = [g.cells_per_diameter for g in res.grids]
        assert res.beta == beta and cells == sorted(set(cells)) and len(cells) >= 3, res
        assert res.finest.change() == 0.0 and res.grids[0].cpu_ratio == 1.0
        assert all(a.cpu_ratio < b.cpu_ratio for a, b in zip(res.grids, res.grids[1:]))
        chosen = res.choice()
        assert chosen is res.finest or sp.admissible(chosen)
        assert not any(sp.admissible(g) for g in res.grids if g.cells_per_diameter < chosen.cells_per_diameter)
    for (regime, beta), ev in sp.BETA_EVIDENCE.items():
        assert ev.regime == regime and ev.beta == beta and ev.reference.change() == 0.0
        names = {m.name for m in ev.settings}
        assert all(m.against is None or m.against in names for m in ev.settings)


def test_a_recomputed_resolution_study_is_checked_against_the_stored_rows():
    stored = sp.RESOLUTION[10.0]
    same = list(stored.grids)
    assert sp.resolution_check(10.0, same) == ([], [])
    g = same[1]
    off = sp.GridMeasured(g.cells_per_diameter, g.grid, g.fibre_radius_scale, closure_free=g.closure_free + 5.0,
                          closure_free_stderr=g.closure_free_stderr, trajectory=g.trajectory,
                          trajectory_stderr=g.trajectory_stderr, cpu_ratio=g.cpu_ratio)
    notes, bad = sp.resolution_check(10.0, [off])
    assert len(bad) == 1 and "closure_free" in bad[0] and not notes
    rescaled = sp.GridMeasured(g.cells_per_diameter, g.grid, 1.0, g.closure_free, g.closure_free_stderr, g.trajectory,
                               g.trajectory_stderr, g.cpu_ratio)
    assert any("radius scale" in b for b in sp.resolution_check(10.0, [rescaled])[1])
    assert sp.resolution_check(7.0, same)[1]
