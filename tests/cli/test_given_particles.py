"""Particles at given positions and orientations (`[[particles]] positions`, `orientations`):
inline or from a .csv / .npy file relative to the scene; the count is the number of rows;
validation refuses (exit 2, key path and allowed range) a count or fraction that disagrees,
a centre outside the cell, a zero axis, gaps below alpha (naming the first pair) and a mix
of given and random families; `pyfold run` starts from exactly the given state."""
from __future__ import annotations

import itertools
import sys
from pathlib import Path

import h5py
import numpy as np

from conftest import write_scene
from pyfold.cli import main
from pyfold.scene import load_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "micro"))
from test_run_common import jeffery_scene  # noqa: E402

#: 2 x 2 x 2 simple cubic array of spheres in a 2^3 cell (spacing 1, R = 0.3)
SC = [[0.5 + i, 0.5 + j, 0.5 + k] for k, j, i in itertools.product(range(2), repeat=3)]


def _scene(particles, size=(2.0, 2.0, 2.0), **model):
    return jeffery_scene(particles, size, t_end=0.05, seed=4, **model)


def _spheres(**kw):
    return {"name": "beads", "shape": "sphere", "radius": 0.3, "positions": SC, **kw}


def _invalid(tmp_path, capsys, scene, *expected):
    assert main(["validate", str(write_scene(tmp_path / "bad.toml", scene))]) == 2
    err = capsys.readouterr().err
    for text in expected:
        assert text in err, err
    return err


def test_run_reproduces_a_simple_cubic_array_bit_for_bit(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("PYFOLD_FOLD_RUN", raising=False)
    fibres_axes = [[1.0, 2.0, 2.0]] * 8
    scene = _scene([_spheres()])
    out = tmp_path / "sc.h5"
    assert main(["run", str(write_scene(tmp_path / "sc.toml", scene)), "-o", str(out)]) == 0, capsys.readouterr().err
    with h5py.File(out) as f:
        assert f.attrs["status"] == "ok"
        x0 = f["initial/x"][:]
        assert x0.dtype == np.float64 and np.array_equal(x0, np.asarray(SC, dtype=np.float64))
        assert np.allclose(np.linalg.norm(f["initial/p"][:], axis=1), 1.0)
    # fibres with given axes (normalised) and positions: the run file holds exactly them
    scene = _scene([{"shape": "fibre", "radius": 0.02, "length": 0.4, "positions": SC, "orientations": fibres_axes}])
    out = tmp_path / "fib.h5"
    assert main(["run", str(write_scene(tmp_path / "fib.toml", scene)), "-o", str(out)]) == 0, capsys.readouterr().err
    with h5py.File(out) as f:
        assert np.array_equal(f["initial/x"][:], np.asarray(SC))
        assert np.allclose(f["initial/p"][:], np.asarray(fibres_axes) / 3.0, rtol=0, atol=1e-15)


def test_positions_from_csv_with_and_without_header_and_npy(tmp_path, monkeypatch):
    data = tmp_path / "data"
    data.mkdir()
    (data / "h.csv").write_text("x,y,z\n" + "\n".join(",".join(repr(v) for v in r) for r in SC) + "\n")
    (data / "n.csv").write_text("\n".join(",".join(repr(v) for v in r) for r in SC))
    np.save(data / "p.npy", np.asarray(SC))
    axes = np.tile([0.0, 0.0, 2.0], (8, 1))
    np.save(data / "axes.npy", axes)
    monkeypatch.chdir(tmp_path.parent)  # relative paths are taken from the scene's folder, not the cwd
    for name in ("h.csv", "n.csv", "p.npy"):
        scene = _scene([{"shape": "fibre", "radius": 0.02, "length": 0.4, "positions": f"data/{name}",
                         "orientations": "data/axes.npy"}])
        res = load_scene(write_scene(tmp_path / f"{name}.toml", scene))
        fam = res.families[0]
        assert fam.count == 8 and fam.orientation == "given"
        assert np.array_equal(fam.positions, np.asarray(SC)), name
        assert np.array_equal(fam.axes, np.tile([0.0, 0.0, 1.0], (8, 1)))


def test_orientation_rule_applies_without_orientations(tmp_path):
    scene = _scene([{"shape": "fibre", "radius": 0.02, "length": 0.4, "positions": SC}])
    a = load_scene(write_scene(tmp_path / "a.toml", scene)).families[0]
    b = load_scene(write_scene(tmp_path / "b.toml", scene)).families[0]
    assert a.orientation == "isotropic" and np.array_equal(a.axes, b.axes)  # seeded
    assert np.allclose(np.linalg.norm(a.axes, axis=1), 1.0)
    scene["particles"][0].update(orientation="aligned", direction=[0.0, 3.0, 0.0])
    c = load_scene(write_scene(tmp_path / "c.toml", scene)).families[0]
    assert np.array_equal(c.axes, np.tile([0.0, 1.0, 0.0], (8, 1)))


def test_count_and_fraction_must_agree(tmp_path, capsys):
    assert main(["validate", str(write_scene(tmp_path / "ok.toml", _scene([_spheres(count=8)])))]) == 0
    capsys.readouterr()
    _invalid(tmp_path, capsys, _scene([_spheres(count=7)]), "particles[0].count",
             "must equal the number of rows of particles[0].positions (8), got 7")
    _invalid(tmp_path, capsys, _scene([_spheres(volume_fraction=0.3)]), "particles[0].volume_fraction",
             "positions has 8 rows")


def test_positions_inside_the_cell(tmp_path, capsys):
    bad = [list(r) for r in SC]
    bad[5][1] = 2.0
    _invalid(tmp_path, capsys, _scene([_spheres(positions=bad)]), "particles[0].positions", "row 5", "0 <= y < 2")
    bad[5][1] = -0.1
    _invalid(tmp_path, capsys, _scene([_spheres(positions=bad)]), "particles[0].positions", "row 5")
    _invalid(tmp_path, capsys, _scene([_spheres(positions=[[0.5, 0.5]] * 8)]), "particles[0].positions",
             "3 components")


def test_orientations_non_zero_and_one_per_row(tmp_path, capsys):
    axes = [[1.0, 0.0, 0.0]] * 8
    axes[3] = [0.0, 0.0, 0.0]
    fib = {"shape": "fibre", "radius": 0.02, "length": 0.4, "positions": SC}
    _invalid(tmp_path, capsys, _scene([{**fib, "orientations": axes}]), "particles[0].orientations", "row 3 is zero")
    _invalid(tmp_path, capsys, _scene([{**fib, "orientations": [[1.0, 0.0, 0.0]] * 7}]), "particles[0].orientations",
             "one axis per particle")
    _invalid(tmp_path, capsys, _scene([{**fib, "orientation": "isotropic", "orientations": [[1.0, 0, 0]] * 8}]),
             "particles[0].orientations", "only with orientation = 'given'")


def test_overlapping_configuration_names_the_first_pair(tmp_path, capsys):
    close = [list(r) for r in SC]
    close[6] = [0.5, 1.5 - 1e-3, 0.5 + 0.6]  # 0.6 from row 2 (gap 0 < alpha), 1 from row 6's neighbours
    close[7] = [1.5, 1.5, 1.5]
    err = _invalid(tmp_path, capsys, _scene([_spheres(positions=close)]), "particles[0].positions",
                   "particles[0].positions: row 2 and row 6 are", "allowed: every gap >= alpha")
    assert ", overlapping" not in err
    close[6] = [0.5, 1.5, 0.5 + 0.5]  # overlapping
    _invalid(tmp_path, capsys, _scene([_spheres(positions=close)]), "row 2 and row 6", ", overlapping")
    # periodic images count: a pair across the boundary
    wrap = [list(r) for r in SC]
    wrap[1] = [1.95, 0.5, 0.5]  # 0.55 from row 0 through the x face
    _invalid(tmp_path, capsys, _scene([_spheres(positions=wrap)]), "particles[0].positions: row 0 and row 1 are")


def test_gap_exactly_alpha_is_allowed(tmp_path, capsys):
    alpha = 0.03
    pts = [[0.5, 0.5, 0.5], [0.5 + 0.6 + alpha, 0.5, 0.5]]
    scene = _scene([{"shape": "sphere", "radius": 0.3, "positions": pts}], size=(3.0, 3.0, 3.0), alpha=alpha)
    assert main(["validate", str(write_scene(tmp_path / "ok.toml", scene))]) == 0, capsys.readouterr().err


def test_mixing_given_and_random_families_refused(tmp_path, capsys):
    scene = _scene([_spheres(), {"shape": "sphere", "radius": 0.05, "count": 3}])
    _invalid(tmp_path, capsys, scene, "particles[1].positions", "cannot be mixed", "give positions for every family")
    # two given families: the gap rule spans them, naming both
    scene = _scene([_spheres(), {"name": "small", "shape": "sphere", "radius": 0.05, "positions": [[0.5, 0.5, 0.852]]}])
    _invalid(tmp_path, capsys, scene, "particles[0].positions: row 0 and particles[1].positions row 0 are")
    scene["particles"][1]["positions"] = [[1.0, 1.0, 1.0]]
    assert main(["validate", str(write_scene(tmp_path / "ok.toml", scene))]) == 0, capsys.readouterr().err


def test_bad_files(tmp_path, capsys):
    _invalid(tmp_path, capsys, _scene([_spheres(positions="nope.csv")]), "particles[0].positions", "no such file")
    (tmp_path / "p.txt").write_text("0.5,0.5,0.5\n")
    _invalid(tmp_path, capsys, _scene([_spheres(positions="p.txt")]), "particles[0].positions", ".csv or .npy")
    (tmp_path / "two.csv").write_text("0.5,0.5\n1.5,1.5\n")
    _invalid(tmp_path, capsys, _scene([_spheres(positions="two.csv")]), "particles[0].positions",
             "one row of 3 numbers")
    (tmp_path / "nan.csv").write_text("0.5,0.5,0.5\nnan,1,1\n")
    _invalid(tmp_path, capsys, _scene([_spheres(positions="nan.csv")]), "particles[0].positions",
             "row 1 is not finite")


def test_2d_walls_given_fibres(tmp_path, capsys):
    """2-D (two components), Couette walls: the gap to a wall must be >= alpha/2."""
    scene = {
        "cell": {"dim": 2, "size": [2.0, 1.0], "boundary": "couette"},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [{"shape": "fibre", "radius": 0.02, "length": 0.3, "positions": [[0.5, 0.5], [1.5, 0.5]],
                       "orientations": [[1.0, 1.0], [0.0, 2.0]]}],
        "numerics": {"dt": 0.01, "t_end": 0.05},
    }
    fam = load_scene(write_scene(tmp_path / "ok.toml", scene)).families[0]
    assert np.allclose(fam.axes, [[2**-0.5, 2**-0.5], [0.0, 1.0]], rtol=0, atol=1e-15)
    scene["particles"][0]["positions"][1] = [1.5, 0.85]  # tip at y = 1.02 beyond the wall
    _invalid(tmp_path, capsys, scene, "particles[0].positions: row 1 is -0.02 from a wall", "alpha/2")


def test_schema_errors_name_the_key_once(tmp_path, capsys):
    """positions is an array of rows or a file name: a value of neither form gets one line."""
    err = _invalid(tmp_path, capsys, _scene([_spheres(positions=5)]),
                   "particles[0].positions: must be an array or a string, got 5")
    assert "constrained-str" not in err and "list[" not in err
    rows = [list(r) for r in SC]
    rows[2][1] = "a"
    err = _invalid(tmp_path, capsys, _scene([_spheres(positions=rows)]), "particles[0].positions[2][1]: must be a number")
    assert "1 problem in the scene" in err
