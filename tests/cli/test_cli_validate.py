"""`pyfold validate`: malformed scenes are rejected with exit 2 and a message naming the
key; the bundled scenes are valid and their normalised form is itself valid."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

from conftest import base_scene, write_scene
from pyfold.cli import main

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted((ROOT / "data" / "scenes").glob("*.toml"))


def _set(path: str, value):
    """Edit that sets scene[path] (dots and [index]); value None deletes the key."""
    def edit(scene):
        keys = path.replace("[", ".").replace("]", "").split(".")
        node = scene
        for k in keys[:-1]:
            node = node[int(k)] if k.isdigit() else node.setdefault(k, {})
        if value is None:
            del node[keys[-1]]
        else:
            node[keys[-1]] = value
    return edit


def _both(*edits):
    def edit(scene):
        for e in edits:
            e(scene)
    return edit


SPHERES = {"name": "beads", "shape": "sphere", "radius": 0.1, "count": 4}

# (case id, edit of the base scene, text the message must contain: the key path, and a detail)
MALFORMED = [
    ("top-level typo", _set("partcles", []), ["partcles", "did you mean 'particles'"]),
    ("particle key typo", _set("particles[0].raduis", 0.05), ["particles[0].raduis", "did you mean 'radius'"]),
    ("model key typo", _set("model.colisions", "none"), ["model.colisions", "did you mean 'collisions'"]),
    ("negative alpha", _set("model.alpha", -0.001), ["model.alpha", "greater than or equal to 0"]),
    ("alpha above radius", _set("model.alpha", 0.2), ["model.alpha", "smallest particle radius"]),
    ("2-D cell, 3-D gradient", _both(_set("cell.dim", 2), _set("cell.size", [4.0, 4.0]), _set("flow.type", "general"),
                                     _set("flow.rate", None),
                                     _set("flow.gradient", [[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])),
     ["flow.gradient", "2 x 2"]),
    ("non-traceless gradient", _both(_set("flow.type", "general"), _set("flow.rate", None),
                                     _set("flow.gradient", [[1.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])),
     ["flow.gradient", "tr L = 0"]),
    ("dt above end time", _set("numerics.dt", 0.5), ["numerics.dt", "<= numerics.t_end"]),
    ("t_end not a multiple of dt", _set("numerics.t_end", 0.205), ["numerics.t_end", "multiple of numerics.dt"]),
    ("Couette walls, elongation", _both(_set("cell.boundary", "couette"), _set("flow.type", "planar_elongation")),
     ["flow.type", "simple shear"]),
    ("uniaxial elongation beyond the admissible time", _both(_set("flow.type", "uniaxial_elongation"),
                                                          _set("numerics.t_end", 20.0)),
     ["numerics.t_end", "allowed: numerics.t_end <="]),
    ("stokes in elongation", _both(_set("flow.type", "planar_elongation"), _set("model.hydrodynamics", "stokes")),
     ["model.hydrodynamics", "simple shear only"]),
    ("2-D uniaxial elongation", _both(_set("cell.dim", 2), _set("cell.size", [4.0, 4.0]),
                                      _set("flow.type", "uniaxial_elongation")), ["flow.type", "3-D cell"]),
    ("output interval not a multiple of dt", _set("output.interval", 0.015), ["output.interval", "multiple of"]),
    ("snapshot interval beyond t_end", _set("output.snapshot_interval", 0.5), ["output.snapshot_interval", "<= numerics.t_end"]),
    ("fraction beyond random rod packing", _both(_set("particles[0].count", None),
                                                 _set("particles[0].volume_fraction", 0.6)),
     ["particles[0].volume_fraction", "random placement", "Philipse"]),
    ("fraction beyond random sphere packing", _both(_set("particles", [dict(SPHERES, count=None, volume_fraction=0.66)]),
                                                    lambda s: s["particles"][0].pop("count")),
     ["particles[0].volume_fraction", "Berryman"]),
    ("negative radius", _set("particles[0].radius", -0.05), ["particles[0].radius", "greater than or equal to 1e-30"]),
    ("radius given as text", _set("particles[0].radius", "0.05"), ["particles[0].radius", "must be a number"]),
    ("aspect ratio <= 1", _both(_set("particles", [SPHERES, {"shape": "spheroid", "radius": 0.1, "aspect_ratio": 0.8,
                                                             "count": 2}])),
     ["particles[1].aspect_ratio", "aspect ratio > 1"]),
    ("Cox rule on a short fibre", _set("particles[0].length", 0.3), ["particles[0].length", "cox", "zhang"]),
    ("count and volume fraction", _set("particles[0].volume_fraction", 0.01), ["particles[0].count", "exactly one"]),
    ("zero count", _set("particles[0].count", 0), ["particles[0].count", "greater than or equal to 1"]),
    ("sphere with a length", _set("particles", [dict(SPHERES, length=0.2)]), ["particles[0].length", "sphere"]),
    ("rule on a spheroid", _set("particles", [{"shape": "spheroid", "radius": 0.1, "length": 1.0, "count": 2,
                                               "equivalent_aspect_ratio": "zhang"}]),
     ["particles[0].equivalent_aspect_ratio", "only for fibres"]),
    ("cell size vs dim", _set("cell.size", [4.0, 4.0]), ["cell.size", "3 side lengths"]),
    ("dim 4", _set("cell.dim", 4), ["cell.dim", "2 or 3"]),
    ("fft stokes with Couette walls", _both(_set("cell.boundary", "couette"), _set("model.hydrodynamics", "stokes"),
                                            _set("numerics.stokes", {"backend": "fft"})),
     ["numerics.stokes.backend", "fully periodic", "allowed: 'hypre' or 'auto'"]),
    ("hypre stokes in a periodic cell", _both(_set("model.hydrodynamics", "stokes"),
                                              _set("numerics.stokes", {"backend": "hypre"})),
     ["numerics.stokes.backend", "Lees-Edwards", "allowed: 'fft' or 'auto'"]),
    ("stokes grid over the budget", _set("model.hydrodynamics", "stokes"),
     ["numerics.stokes.max_grid_points", "160 x 160 x 160"]),
    ("unknown time scheme", _set("numerics.time_scheme", "rk4"), ["numerics.time_scheme", "'ab2'"]),
    ("unknown collision mode", _set("model.collisions", "smart"), ["model.collisions", "'strategy'"]),
    ("lubrication without spheres", _set("model.lubrication", True), ["model.lubrication", "spheres"]),
    ("fibre longer than half the cell", _set("particles[0].length", 2.5), ["particles[0].length", "half the smallest"]),
    ("given orientations, wrong number", _both(_set("particles[0].orientation", "given"),
                                               _set("particles[0].orientations", [[1.0, 0.0, 0.0]])),
     ["particles[0].orientations", "count = 8"]),
    ("zero aligned direction", _both(_set("particles[0].orientation", "aligned"),
                                     _set("particles[0].direction", [0.0, 0.0, 0.0])), ["particles[0].direction", "non-zero"]),
    ("duplicate family names", _set("particles", [SPHERES, dict(SPHERES, radius=0.05)]), ["particles[1].name", "unique"]),
    ("negative seed", _set("numerics.seed", -1), ["numerics.seed", "greater than or equal to 0"]),
    ("kappa < 1", _set("numerics.stokes", {"kappa": 0.5}), ["numerics.stokes.kappa", "greater than or equal to 1"]),
    ("missing numerics", _set("numerics", None), ["numerics", "required key is missing"]),
    ("integer as real is fine but real as integer is not", _set("particles[0].count", 8.0),
     ["particles[0].count", "must be an integer"]),
]


def test_table_has_at_least_twenty_distinct_cases():
    assert len({case[0] for case in MALFORMED}) == len(MALFORMED) >= 20


@pytest.mark.parametrize("case, edit, expected", MALFORMED, ids=[c[0] for c in MALFORMED])
def test_malformed_scene_rejected_with_exit_2_naming_the_key(case, edit, expected, tmp_path, capsys):
    scene = base_scene()
    edit(scene)
    path = write_scene(tmp_path / "bad.toml", scene)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pyfold validate: error:")
    for text in expected:
        assert text in err, f"{case}: {text!r} not in the message:\n{err}"


def test_every_problem_of_a_stage_reported_at_once(tmp_path, capsys):
    # Stage 1 (schema: keys, types, ranges) lists all its problems together ...
    scene = base_scene()
    scene["model"]["alpha"] = -1.0
    scene["particles"][0]["raduis"] = 0.1
    scene["numerics"]["seed"] = "one"
    assert main(["validate", str(write_scene(tmp_path / "bad.toml", scene))]) == 2
    err = capsys.readouterr().err
    assert "3 problems" in err and "model.alpha" in err and "particles[0].raduis" in err and "numerics.seed" in err
    # ... and so does stage 2 (rules tying keys together), once the schema passes.
    scene = base_scene()
    scene["numerics"]["dt"] = 1.0
    scene["model"]["lubrication"] = True
    scene["particles"][0]["length"] = 3.0
    assert main(["validate", str(write_scene(tmp_path / "bad2.toml", scene))]) == 2
    err = capsys.readouterr().err
    assert "3 problems" in err and "numerics.dt" in err and "model.lubrication" in err and "particles[0].length" in err


def test_toml_syntax_error_and_missing_file_exit_2(tmp_path, capsys):
    bad = tmp_path / "syntax.toml"
    bad.write_text("[cell\ndim = 3\n")
    assert main(["validate", str(bad)]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    assert main(["validate", str(tmp_path / "absent.toml")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_real_subprocess_exit_status_2(tmp_path):
    scene = base_scene()
    scene["model"]["alpha"] = -0.5
    path = write_scene(tmp_path / "bad.toml", scene)
    proc = subprocess.run([sys.executable, "-m", "pyfold.cli", "validate", str(path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "model.alpha" in proc.stderr


@pytest.mark.parametrize("scene_file", SCENES, ids=[p.name for p in SCENES])
def test_bundled_scene_valid_and_normalised_form_is_a_fixed_point(scene_file, tmp_path, capsys):
    assert main(["validate", str(scene_file)]) == 0
    first = capsys.readouterr().out
    # the normalised scene carries the resolved choice, not "auto"
    assert "hydrodynamics = jeffery" in first or "hydrodynamics = stokes" in first
    assert 'hydrodynamics = "auto"' not in first
    normalised = tmp_path / "normalised.toml"
    normalised.write_text(first)
    assert main(["validate", str(normalised), "--json"]) == 0
    again = capsys.readouterr().out
    import json

    assert json.loads(again) == tomllib.loads(first)


def test_required_bundled_scenes_present():
    names = {p.name for p in SCENES}
    assert {"default.toml", "annotated.toml", "couette_disks_seed.toml"} <= names
