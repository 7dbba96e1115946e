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


@pytest.fixture
def evidence(monkeypatch):
    def use(settings):
        monkeypatch.setattr(sp, "EVIDENCE", _evidence(settings))
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
