"""`hydrodynamics = "auto"` records the measured effect of hydrodynamics on C_I in its reason.

The evidence rows live in pyfold/scene/hydrodynamics_evidence.py (recomputed from the run
files by studies/speed_accuracy/pareto.py); the reason of a dilute and of a semi-dilute
fibre scene must quote the row of its regime, and a jeffery choice the C_I error it costs.
"""
from __future__ import annotations

import math

import tomli_w

from pyfold.cli import main as cli_main
from pyfold.scene import parse_scene
from pyfold.scene.hydrodynamics_evidence import EVIDENCE, SIGNIFICANCE_LEVEL, auto_evidence, evidence_for

FIBRE = {"shape": "fibre", "length": 1.0, "radius": 0.1}  # beta = 5, as the measured scenes


def _scene_text(count: int, side: float = 3.0, **stokes) -> str:
    data = {
        "cell": {"dim": 3, "size": [side] * 3},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [dict(FIBRE, count=count)],
        "model": {"hydrodynamics": "auto"},
        "numerics": {"dt": 0.02, "t_end": 0.2, **({"stokes": stokes} if stokes else {})},
    }
    return tomli_w.dumps(data)


def _half_unit(x: float, digits: int = 3) -> float:
    return 0.5 * 10.0 ** (math.floor(math.log10(abs(x))) - digits + 1)


def test_every_evidence_row_is_a_finite_paired_measurement_consistent_with_its_verdict():
    for regime, row in EVIDENCE.items():
        assert row.regime == regime
        values = (row.delta_ci, row.delta_ci_stderr, row.p, row.ci_jeffery, row.ci_stokes, row.ci_stokes_stderr,
                  row.traj_delta_ci, row.traj_delta_ci_stderr, row.traj_p, row.period_error)
        assert all(math.isfinite(v) for v in values), f"{regime}: unmeasured entries {values}"
        assert row.delta_ci_stderr > 0 and 0 < row.p <= 1 and row.seeds >= 4
        assert row.significant == (row.p < SIGNIFICANCE_LEVEL)
        # the ensemble difference and the paired mean are the same mean over the same seeds;
        # each stored value is rounded to 3 significant digits (error <= half a unit of the last)
        bound = sum(_half_unit(v) for v in (row.ci_stokes, row.ci_jeffery, row.delta_ci))
        assert abs((row.ci_stokes - row.ci_jeffery) - row.delta_ci) <= bound * (1 + 1e-12)


def test_dilute_fibre_scene_gets_jeffery_and_the_dilute_measurement(tmp_path):
    r = parse_scene(_scene_text(count=20))  # n L^3 = 20/27 = 0.74: dilute
    assert r.regime == "dilute" and r.hydrodynamics == "jeffery"
    row = EVIDENCE["dilute"]
    assert r.reason.startswith("hydrodynamics = jeffery (auto): dilute")
    assert row.quote() in r.reason
    assert row.study in r.reason and "expected C_I error of this choice" in r.reason
    assert f"{abs(row.delta_ci):.1e} ± {row.delta_ci_stderr:.1e}" in r.reason


def test_semi_dilute_fibre_scene_gets_stokes_and_the_accuracy_of_that_choice():
    r = parse_scene(_scene_text(count=130))  # n L^3 = 4.81: semi-dilute (below L/d = 5)
    assert r.regime == "semi-dilute" and r.hydrodynamics == "stokes"
    row = EVIDENCE["semi-dilute"]
    assert r.reason.startswith("hydrodynamics = stokes (auto): semi-dilute")
    assert row.quote() in r.reason and "beyond its statistical error" in r.reason
    assert f"the Stokes model's C_I there: {row.ci_stokes:.1e} ± {row.ci_stokes_stderr:.1e}" in r.reason


def test_semi_dilute_scene_over_the_grid_budget_is_told_the_c_i_error_of_jeffery():
    r = parse_scene(_scene_text(count=130, cells_per_diameter=12))  # 180^3 > the default budget
    assert r.regime == "semi-dilute" and r.hydrodynamics == "jeffery"
    row = EVIDENCE["semi-dilute"]
    assert "exceeds numerics.stokes.max_grid_points" in r.reason and row.quote() in r.reason
    assert f"expected C_I error of this choice: {abs(row.delta_ci):.1e} ± {row.delta_ci_stderr:.1e}" in r.reason


def test_concentrated_scene_quotes_the_densest_measured_regime_and_says_so():
    row, same = evidence_for("concentrated")
    assert row is EVIDENCE["semi-dilute"] and not same
    assert "nearest measured regime: semi-dilute" in auto_evidence("concentrated", "jeffery")
    assert evidence_for("spheres") is None and auto_evidence("spheres", "stokes") == ""


def test_validate_prints_the_evidence_in_the_recorded_reason(tmp_path, capsys):
    path = tmp_path / "dilute.toml"
    path.write_text(_scene_text(count=20))
    assert cli_main(["validate", str(path)]) == 0
    out = " ".join(capsys.readouterr().out.split())  # the CLI may wrap long lines
    assert "hydrodynamics = jeffery (auto)" in out and EVIDENCE["dilute"].study in out
