"""One rule for the cell / interaction-range check, and a single particle per cell.

fold_run's contact search needs every periodic edge longer than twice its range
rc = 2 max(h + R) + alpha + skin (fold_contacts.contact_search_range, checked in
fold_cell_list.cell_list_setup) whenever a pair can exist. The scene layer states the
same rule once (pyfold.scene.shapes.cell_range_violation); these tests check that the
two agree (the formula against the f2py binding, the verdict against fold_run itself on
tiny run files), that a scene fold_run would refuse is refused by `pyfold validate`
(206 fibres in a 2.25^3 cell used to pass), and that a single particle per periodic
cell (no pair: it only meets its own images, which move with it) may exceed half the
cell: validate accepts it and a Stokes run of a simple cubic array of spheres finishes.
"""
from __future__ import annotations

import itertools

import h5py
import numpy as np
import pytest
import tomli_w

from test_run_common import jeffery_scene, run_fold, write_run_file
from pyfold.cli import main
from pyfold.native import geometry as geo
from pyfold.scene import shapes

CODES = shapes.SHAPE_CODES


def _write(path, scene: dict):
    path.write_text(tomli_w.dumps(scene), encoding="utf-8")
    return path


def _scene(particles, size, **model):
    return jeffery_scene(particles, size, t_end=0.02, seed=1, **model)


@pytest.mark.parametrize("alpha", [0.0, 0.004, 0.01, 0.05])
def test_interaction_range_formula_is_fold_runs(alpha):
    """shapes.interaction_range == fold_contacts.contact_search_range (default skin),
    bit for bit, over shapes, sizes and mixtures."""
    cases = [
        [("fibre", 0.05, 1.0)], [("sphere", 0.3, 0.6)], [("spheroid", 0.1, 0.8)], [("spheroid", 0.2, 0.41)],
        [("fibre", 0.05, 1.0), ("sphere", 0.2, 0.4)], [("sphere", 0.05, 0.1), ("spheroid", 0.3, 2.0)],
        [("fibre", 1e-3, 0.05), ("fibre", 0.02, 0.3), ("sphere", 0.01, 0.02)],
    ]
    for parts in cases:
        rc_py = shapes.interaction_range(parts, alpha)
        rc_f = geo.contact_search_range([CODES[s] for s, _, _ in parts], [r for _, r, _ in parts],
                                        [length for _, _, length in parts], alpha=alpha)
        assert rc_py == rc_f, (parts, alpha, rc_py, rc_f)


def _fold_run_accepts(tmp_path, tag, n, shape, radius, length, edge, alpha) -> bool:
    """fold_run's own verdict on a 1-step run (collisions = strategy): exit 0 or exit 2."""
    # particles along z, well apart in x-y: no contact whatever the edge
    x = np.array([[0.25 * edge, 0.25 * edge, 0.5 * edge], [0.75 * edge, 0.75 * edge, 0.5 * edge]])[:n]
    p = np.tile([0.0, 0.0, 1.0], (n, 1))
    path = tmp_path / f"{tag}.h5"
    write_run_file(path, x=x, p=p, radius=radius, length=length, xi=0.0 if shape == "sphere" else 0.9,
                   shape=np.full(n, CODES[shape]), cell_lengths=(edge, edge, edge), collisions=2, alpha=alpha,
                   dt=0.01, t_end=0.01)
    proc = run_fold(path)
    assert proc.returncode in (0, 2), proc.stderr
    if proc.returncode == 2:
        assert "interaction range" in proc.stderr, proc.stderr
    return proc.returncode == 0


def test_cell_rule_agrees_with_fold_run_on_a_sweep(tmp_path):
    """The Python verdict (cell_range_violation) is fold_run's verdict, just below and above
    the edge 2 rc, for fibres and spheres, 2 particles (a pair) and 1 (none): checked by
    running fold_run, and by the binding's cell list (the same cell_list_setup)."""
    checked = 0
    for (shape, radius, length), factor, n in itertools.product(
            [("fibre", 0.05, 1.0), ("sphere", 0.3, 0.6)], [0.97, 0.999, 1.001, 1.05], [2, 1]):
        alpha = 0.01
        rc = shapes.interaction_range([(shape, radius, length)], alpha)
        edge = 2.0 * rc * factor
        python_ok = shapes.cell_range_violation([edge] * 3, 3, False, [(shape, radius, length)], alpha, n) is None
        assert python_ok == (factor > 1.0 or n == 1)
        # the binding: the same cell_list_setup, with the contact range, for n particles
        x = np.array([[0.25 * edge, 0.25 * edge, 0.5 * edge], [0.75 * edge, 0.75 * edge, 0.5 * edge]])[:n]
        try:
            geo.neighbour_pairs(x, geo.Cell((edge,) * 3), geo.contact_search_range(
                [CODES[shape]] * n, [radius] * n, [length] * n, alpha=alpha))
            binding_ok = True
        except Exception as exc:  # noqa: BLE001 - InputError from the cell list
            assert "interaction range" in str(exc)
            binding_ok = False
        assert binding_ok == python_ok, (shape, factor, n)
        if factor in (0.999, 1.001):
            assert _fold_run_accepts(tmp_path, f"{shape}{factor}{n}", n, shape, radius, length, edge, alpha) \
                == python_ok, (shape, factor, n)
            checked += 1
    assert checked == 8


def test_validate_refuses_what_fold_run_refuses_206_fibres(tmp_path, capsys):
    """206 fibres (L = 1, R = 0.05, alpha = 0.01) in a 2.25^3 cell: half-side rule passed,
    fold_run refused (2.25 < 2 x 1.17). Validate now refuses it, naming the range."""
    scene = _scene([{"shape": "fibre", "radius": 0.05, "length": 1.0, "count": 206}], [2.25] * 3, alpha=0.01)
    assert main(["validate", str(_write(tmp_path / "s.toml", scene))]) == 2
    err = capsys.readouterr().err
    assert "particles[0].length" in err and "interaction range rc = 1.17" in err and "half the smallest" in err


def test_single_sphere_larger_than_half_the_cell_is_valid(tmp_path, capsys):
    """A 1-sphere cell with R = 0.45 L (simple cubic array, phi = 0.38) is valid; two such
    spheres (a pair exists) are not."""
    one = _scene([{"shape": "sphere", "radius": 0.45, "count": 1}], [1.0] * 3)
    assert main(["validate", str(_write(tmp_path / "one.toml", one))]) == 0, capsys.readouterr().err
    capsys.readouterr()
    two = _scene([{"shape": "sphere", "radius": 0.45, "count": 2}], [1.0] * 3)
    assert main(["validate", str(_write(tmp_path / "two.toml", two))]) == 2
    assert "interaction range" in capsys.readouterr().err


def test_single_sphere_stokes_grid_needs_the_voxeliser_margin(tmp_path, capsys):
    """The Stokes voxeliser keeps a particle two voxels clear of its own image
    (fold_voxelise.f90): at R = 0.45 L, 4 cells per diameter give a 5^3 grid it refuses;
    validation says so, naming the cells_per_diameter that suffices."""
    scene = _scene([{"shape": "sphere", "radius": 0.45, "count": 1}], [1.0] * 3, hydrodynamics="stokes")
    scene["numerics"]["stokes"] = {"cells_per_diameter": 4}
    assert main(["validate", str(_write(tmp_path / "s.toml", scene))]) == 2
    err = capsys.readouterr().err
    assert "numerics.stokes.cells_per_diameter" in err and "cells_per_diameter >= 22" in err


@pytest.mark.parametrize("radius, cells_per_diameter", [(0.45, 22)])
def test_single_sphere_per_cell_stokes_run(tmp_path, capsys, monkeypatch, radius, cells_per_diameter):
    """`pyfold run` of one sphere per periodic cell, R = 0.45 L (phi = 0.38, beyond the old
    half-side rule), Stokes on a 25^3 grid (the voxeliser's margin needs 22 cells per
    diameter here; at 4 the 7^3 grid of R = 0.3 L under-resolves the sphere and reads below
    Einstein): status ok, and the simple cubic array is stiffer than Einstein's dilute
    1 + 2.5 phi at that fraction."""
    monkeypatch.delenv("PYFOLD_FOLD_RUN", raising=False)
    scene = _scene([{"shape": "sphere", "radius": radius, "count": 1}], [1.0] * 3, hydrodynamics="stokes")
    scene["numerics"]["stokes"] = {"cells_per_diameter": cells_per_diameter, "fft_plan": "estimate"}
    out = tmp_path / "one.h5"
    assert main(["run", str(_write(tmp_path / "one.toml", scene)), "-o", str(out)]) == 0, capsys.readouterr().err
    phi = 4.0 / 3.0 * np.pi * radius**3
    with h5py.File(out) as f:
        assert f.attrs["status"] == "ok"
        eta = np.asarray(f["effective_viscosity"][:])
        assert int(np.prod(f["setup/resolved/stokes_grid"][:])) <= 25**3
    assert eta.size >= 1 and np.all(eta > 1.0 + 2.5 * phi), (eta, 1.0 + 2.5 * phi)
