"""An ensemble is one scene run with several seeds (pyfold.run_analysis.check_same_scene): runs
that differ in any scene or resolved value are refused, naming the key; runs that differ only in
the seed, the free texts or the prose that explains the scene (its warnings, the reasons for a
model or a preset's numerics, whose wording may change between versions) are one ensemble."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from pyfold import run_analysis
from pyfold.errors import InputError


@pytest.fixture
def runs(monkeypatch):
    """Run files as their setups: path -> resolved values (the scene holds the seed and a count)."""
    import pyfold.run_input as run_input

    table: dict[str, dict] = {}
    monkeypatch.setattr(run_input, "read_setup", lambda path: SimpleNamespace(
        scene={"particles": [{"count": 98}], "numerics": {"seed": table[path]["seed"]}, "title": f"seed {path}"},
        resolved=table[path]))
    return table


def test_runs_that_differ_in_seed_and_prose_only_are_one_ensemble(runs):
    base = {"kappa": 1000.0, "stokes_grid": [42, 42, 42], "scene_warnings": "the grid is coarse",
            "numerics_preset_reason": "measured on ...", "hydrodynamics_reason": "requested"}
    runs["a.h5"] = {**base, "seed": 1}
    runs["b.h5"] = {**base, "seed": 2, "scene_warnings": "the grid is coarse: the viscosity is biased",
                    "numerics_preset_reason": "measured on ..., 8 seeds"}
    assert run_analysis.check_same_scene(["a.h5", "b.h5"]) == [1, 2]


def test_a_run_of_another_scene_or_the_same_seed_is_refused_naming_why(runs):
    runs["a.h5"] = {"kappa": 1000.0, "seed": 1}
    runs["b.h5"] = {"kappa": 100.0, "seed": 2}
    with pytest.raises(InputError, match="resolved/kappa"):
        run_analysis.check_same_scene(["a.h5", "b.h5"])
    runs["b.h5"] = {"kappa": 1000.0, "seed": 1}
    with pytest.raises(InputError, match="the same seed 1"):
        run_analysis.check_same_scene(["a.h5", "b.h5"])
