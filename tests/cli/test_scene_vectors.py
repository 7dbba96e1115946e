"""Axis vectors of a scene (``direction``, ``orientations``) are normalised at the door:
any finite non-zero vector, however large or small its components, becomes its unit
vector; a zero or non-finite one is refused naming the key and the row; numpy warns
about nothing (an overflow in the norm once turned ``[1e308, 1e308, 0]`` into a zero
axis that passed `pyfold validate` and failed `pyfold run` with a wrong cause).

Tolerance: the unit vector is v / m (m = max |v_i|: exact for the largest component,
one rounding for the others), then divided by the square root of a sum of squares
of numbers in [0, 1] (3 products, 2 sums, a square root and a division, each one
rounding of at most eps/2, eps = 2^-52): within 8 eps of the exact unit vector in
every component.
"""
from __future__ import annotations

import math
import warnings

import h5py
import numpy as np
import pytest

from conftest import base_scene, write_scene
from pyfold.cli import main
from pyfold.scene import load_scene
from pyfold.scene.vectors import unit_rows

EPS = np.finfo(np.float64).eps
TOL = 8 * EPS
HUGE = np.finfo(np.float64).max
TINY = 5e-324  # the smallest subnormal

# (case, rows, exact unit rows)
EXTREME = [
    ("huge, equal", [[1e308, 1e308, 0.0]], [[1 / math.sqrt(2), 1 / math.sqrt(2), 0.0]]),
    ("largest float", [[HUGE, -HUGE, HUGE]], [[1 / math.sqrt(3), -1 / math.sqrt(3), 1 / math.sqrt(3)]]),
    ("subnormal", [[TINY, 0.0, TINY]], [[1 / math.sqrt(2), 0.0, 1 / math.sqrt(2)]]),
    ("3-4-5 at 1e300", [[3e300, 4e300]], [[0.6, 0.8]]),
    ("3-4-5 at 1e-310", [[0.0, 3e-310, 4e-310]], [[0.0, 0.6, 0.8]]),
    ("mixed scales", [[1e308, 1e-308, 0.0]], [[1.0, 0.0, 0.0]]),
]


@pytest.mark.parametrize("case, rows, exact", EXTREME, ids=[c[0] for c in EXTREME])
def test_unit_rows_of_extreme_vectors_are_exact_to_round_off_without_warnings(case, rows, exact):
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        unit, why = unit_rows(rows)
    assert why is None
    np.testing.assert_allclose(unit, exact, rtol=0.0, atol=TOL)
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0, rtol=0.0, atol=TOL)


@pytest.mark.parametrize("rows, expected", [
    ([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], "row 1 is zero"),
    ([[np.inf, 0.0, 0.0]], "row 0 is not finite"),
    ([[1.0, 0.0], [np.nan, 1.0]], "row 1 is not finite"),
])
def test_unit_rows_refuses_zero_and_non_finite_rows_naming_the_row(rows, expected):
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        unit, why = unit_rows(rows, "row")
    assert unit is None and expected in why


def _aligned(direction):
    scene = base_scene()
    scene["particles"][0].update(orientation="aligned", direction=direction)
    return scene


def _given(rows):
    scene = base_scene()
    scene["particles"][0].update(orientation="given", orientations=rows, count=len(rows))
    return scene


def test_huge_direction_validates_to_its_unit_vector_without_warnings(tmp_path, capsys):
    path = write_scene(tmp_path / "s.toml", _aligned([1e308, 1e308, 0.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["validate", str(path)]) == 0
    err = capsys.readouterr().err
    assert "Warning" not in err and "overflow" not in err, err
    family = load_scene(path).families[0]
    np.testing.assert_allclose(family.axes, [[1 / math.sqrt(2), 1 / math.sqrt(2), 0.0]], rtol=0.0, atol=TOL)


def test_huge_orientations_validate_to_their_unit_vectors(tmp_path, capsys):
    rows = [[1e308, 1e308, 0.0], [0.0, -1e308, 1e308]] * 4
    path = write_scene(tmp_path / "s.toml", _given(rows))
    assert main(["validate", str(path)]) == 0, capsys.readouterr().err
    r = 1 / math.sqrt(2)
    np.testing.assert_allclose(load_scene(path).families[0].axes, [[r, r, 0.0], [0.0, -r, r]] * 4, rtol=0.0,
                               atol=TOL)


def test_huge_orientations_in_a_csv_file_validate_to_their_unit_vectors(tmp_path):
    (tmp_path / "axes.csv").write_text("px,py,pz\n" + "1e308,1e308,0\n" * 8, encoding="utf-8")
    scene = base_scene()
    scene["particles"][0].update(orientation="given", orientations="axes.csv")
    path = write_scene(tmp_path / "s.toml", scene)
    r = 1 / math.sqrt(2)
    np.testing.assert_allclose(load_scene(path).families[0].axes, [[r, r, 0.0]] * 8, rtol=0.0, atol=TOL)


@pytest.mark.parametrize("scene, key, expected", [
    (_aligned([0.0, 0.0, 0.0]), "particles[0].direction", "is zero"),
    (_given([[1.0, 0.0, 0.0]] * 7 + [[0.0, 0.0, 0.0]]), "particles[0].orientations", "row 7 is zero"),
], ids=["zero direction", "zero orientation row"])
def test_zero_axis_is_refused_naming_the_key(tmp_path, capsys, scene, key, expected):
    assert main(["validate", str(write_scene(tmp_path / "s.toml", scene))]) == 2
    err = capsys.readouterr().err
    assert key in err and expected in err, err


def test_run_with_a_huge_direction_starts_from_the_unit_axis(tmp_path, fake_fold_run, capsys):
    """`pyfold run` once failed here with "placement failed ... lower the volume fraction"."""
    path = write_scene(tmp_path / "s.toml", _aligned([1e308, 1e308, 0.0]))
    out = tmp_path / "out.h5"
    assert main(["run", str(path), "-o", str(out)]) == 0, capsys.readouterr().err
    with h5py.File(out, "r") as f:
        p = f["initial"]["p"][()]
    r = 1 / math.sqrt(2)
    np.testing.assert_allclose(p, np.tile([r, r, 0.0], (len(p), 1)), rtol=0.0, atol=TOL)
