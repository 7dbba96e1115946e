"""numerics.stokes.fibre_radius_scale: the voxelised fibre's radius apart from its geometric one.

On a coarse grid a voxelised cylinder turns like a more slender fibre (docs/jeffery_orbits.md);
the scale s gives the Stokes solve a fibre of radius s R while the contacts, the volume
fraction and the Jeffery shape factor keep R (fortran/grid/fold_voxelise.f90). The tests
compare with the one thing that must be identical, the fibre whose geometric radius is s R:
the products s R agree to the last bit in both languages, so χ and the rigid motion must too.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from test_run_common import require_fold_run, run_fold, write_run_file, xi_of

SCALE = 1.3


def _solve(radius, scale, shapes=("fibre",), grid=24, side=1.5):
    """The bindings' solve with FFTW estimate plans (bitwise reproducible)."""
    from pyfold.native.stokes import Particles, StokesSettings, solve_particles

    n = len(shapes)
    x = np.array([[0.5 * side, 0.5 * side, 0.5 * side], [0.5 * side, 0.5 * side, 0.2 * side]])[:n]
    p = np.array([[0.6, 0.8, 0.0], [1.0, 0.0, 0.0]])[:n]
    r = np.array(radius, dtype=float)[:n]
    length = np.where(np.array(shapes) == "fibre", 1.0, 2 * r)
    part = Particles(x=x, p=p, radius=r, length=length, shape=np.array(shapes))
    return solve_particles(part, [side] * 3, [grid] * 3,
                           settings=StokesSettings(tol=1e-8, fibre_radius_scale=scale, measure_plans=False))


def test_a_scaled_fibre_is_the_fibre_of_the_scaled_radius_and_a_sphere_keeps_its_own():
    """One β = 5 fibre (R = 0.1, 3.2 voxels per diameter) voxelised with s = 1.3 has bit for bit the
    χ and rigid velocities of a fibre of radius 0.13; a sphere beside it keeps its χ (the scale
    is for fibres only); the scale changes the fibre's rotation by far more than round-off."""
    R = 0.1
    scaled = _solve([R, 0.15], SCALE, ("fibre", "sphere"))
    fat = _solve([SCALE * R, 0.15], 1.0, ("fibre", "sphere"))
    assert np.array_equal(scaled.chi, fat.chi)
    assert np.array_equal(scaled.omega, fat.omega) and np.array_equal(scaled.v, fat.v)
    sphere_alone = _solve([0.15, 0.15], SCALE, ("sphere",) * 2)
    sphere_unscaled = _solve([0.15, 0.15], 1.0, ("sphere",) * 2)
    assert np.array_equal(sphere_alone.chi, sphere_unscaled.chi)
    plain = _solve([R], 1.0)
    # a fatter fibre is blunter (smaller β_e): at sin²θ = 0.64 > 1/2 Jeffery's
    # |ω| = γ̇ (β_e² sin²θ + cos²θ)/(β_e² + 1) falls with β_e (by ~1 % from β_e 4.7 to 4.1)
    assert abs(_solve([R], SCALE).omega[0, 2]) < abs(plain.omega[0, 2]) * (1 - 1e-3)


def test_bindings_refuse_a_scale_outside_the_registry_range():
    from pyfold.errors import InputError
    from pyfold.native.stokes import StokesSettings

    with pytest.raises(InputError, match=r"fibre_radius_scale: must be in \[0\.5, 2\]"):
        StokesSettings(fibre_radius_scale=2.5)


def _fibre_run(path, radius, stokes_extra, drop=()):
    n, beta = 24, 4.0
    write_run_file(path, x=[[0.5, 0.5, 0.5]], p=[[0.6, 0.8, 0.0]], radius=radius, length=2 * beta * 0.05,
                   xi=xi_of(beta), shape=[1], dt=0.02, t_end=0.1, snapshot_every=1, drop=drop,
                   stokes={"stokes_grid": (n, n, n), "stokes_tolerance": 1e-8, "stokes_fft_plan": np.int64(0),
                           **stokes_extra})
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stderr
    # the solver line says when the voxelised radius is not the geometric one
    assert ("fibres voxelised at  1.300 times their radius" in proc.stdout) == \
        (stokes_extra.get("stokes_fibre_radius_scale", 1.0) == SCALE), proc.stdout
    with h5py.File(path) as f:
        return f["p"][:, 0].copy(), f["x"][:, 0].copy()


def test_fold_run_turns_a_scaled_fibre_as_the_fibre_of_the_scaled_radius(tmp_path):
    """fold_run reads /setup/resolved/stokes_fibre_radius_scale: a fibre of R = 0.05 at s = 1.3 moves
    bit for bit as one of R = 0.065 at s = 1 (FFTW estimate plans: reproducible). A run file
    without the dataset (written before the setting existed) runs at s = 1."""
    require_fold_run()
    p_scaled, x_scaled = _fibre_run(tmp_path / "scaled.h5", 0.05, {"stokes_fibre_radius_scale": SCALE})
    p_fat, x_fat = _fibre_run(tmp_path / "fat.h5", SCALE * 0.05, {"stokes_fibre_radius_scale": 1.0})
    assert np.array_equal(p_scaled, p_fat) and np.array_equal(x_scaled, x_fat)
    p_plain, _ = _fibre_run(tmp_path / "plain.h5", 0.05, {"stokes_fibre_radius_scale": 1.0})
    p_old, _ = _fibre_run(tmp_path / "old.h5", 0.05, {}, drop=("stokes_fibre_radius_scale",))
    assert np.array_equal(p_plain, p_old)
    assert np.max(np.abs(p_plain - p_scaled)) > 1e-6


def test_contacts_keep_the_geometric_radius(tmp_path):
    """Two parallel fibres along the flow, apart in the vorticity direction by a surface gap of
    R/2 > α: at s = 1.5 their voxelised bodies overlap, but the contact step sees the geometric
    gap (recorded min_gap stays R/2 to within the motion of 5 steps, no correction)."""
    require_fold_run()
    n, R, L = 32, 0.04, 0.32
    gap = 0.5 * R
    z0 = 0.5 - (R + gap / 2)
    path = tmp_path / "pair.h5"
    write_run_file(path, x=[[0.5, 0.5, z0], [0.5, 0.5, z0 + 2 * R + gap]], p=[[1.0, 0.0, 0.0]] * 2, radius=R,
                   length=L, xi=xi_of(L / (2 * R)), shape=[1, 1], dt=0.01, t_end=0.05, alpha=0.2 * R, collisions=1,
                   stokes={"stokes_grid": (n, n, n), "stokes_tolerance": 1e-6, "stokes_fibre_radius_scale": 1.5})
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(path) as f:
        min_gap = f["min_gap"][:]
        corrections = f["n_corrections"][:]
    assert np.all(corrections == 0)
    # fibres along the flow at the same height barely move apart: 5 steps of 0.01 at shear rate 1
    assert np.all(np.abs(min_gap - gap) < 0.1 * gap), min_gap


def test_a_scaled_scene_that_records_the_default_beta_e_is_warned():
    """A scene whose fibres the solve turns at a calibrated radius but whose runs record the default
    rule's β_e gets a warning naming both keys; naming the rule (what the calibration aimed at)
    silences it, and so does the geometric radius."""
    from pyfold.scene import parse_scene
    from pyfold.scene.sheared_fibres import sheared_fibres

    def warned(scale, rule):
        stokes = {"cells_per_diameter": 3} | ({"fibre_radius_scale": scale} if scale != 1.0 else {})
        scene = sheared_fibres(5.0, 5.0, 1, 1.0, hydrodynamics="stokes", stokes=stokes,
                               equivalent_aspect_ratio=rule)
        return [w for w in parse_scene(scene.toml).warnings if w.startswith("numerics.stokes.fibre_radius_scale")]

    (text,) = warned(1.129, None)
    assert "particles.equivalent_aspect_ratio" in text and "'cox'" in text
    assert warned(1.129, "zhang") == [] and warned(1.0, None) == []
