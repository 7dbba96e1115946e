"""numerics.stokes.fibre_shells: the shells a calibrated radius adds to near fibres, overlapping or kept apart.

A fibre voxelised at s R (fibre_radius_scale s > 1) carries a shell of (s − 1) R around its geometric
body. Two fibres nearer than 2 (s − 1) R then overlap in the solve: with "overlap" their coverages add
up, the voxels between them become rigid and the pair moves as one body. With "apart" each shell ends
the security zone α short of the other's geometric surface (fortran/grid/fold_voxelise.f90), so the
voxelised bodies stay α apart, as the contacts keep the geometric ones
(docs/fluid_coupled_ci.md#fibre-shells-kept-apart).
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from test_run_common import require_fold_run, run_fold, write_run_file, xi_of

R, L, N = 0.05, 0.5, 48  # β = 5, 4.8 voxels per diameter on the unit cell
ALPHA = 0.2 * R  # the series' security zone, α = 0.1 d
SCALE = 1.3


def _pair(gap, scale, shells, along="y", tol=1e-8):
    """Two parallel fibres along the flow (x) at surface gap ``gap``, apart in ``along`` (y: the
    shear gradient, so the undisturbed flow slides one past the other; z: the vorticity)."""
    from pyfold.native.stokes import Particles, StokesSettings, solve_particles

    axis = {"y": 1, "z": 2}[along]
    x = np.full((2, 3), 0.5)
    x[0, axis] -= R + gap / 2
    x[1, axis] += R + gap / 2
    part = Particles(x=x, p=np.array([[1.0, 0.0, 0.0]] * 2), radius=np.array([R, R]), length=np.array([L, L]),
                     shape=np.array(["fibre", "fibre"]))
    return x, solve_particles(part, [1.0] * 3, [N] * 3, alpha=ALPHA,
                              settings=StokesSettings(tol=tol, fibre_radius_scale=scale, fibre_shells=shells,
                                                      measure_plans=False))


def _sliding(x, sol):
    """The pair's relative velocity along the flow beyond a rigid motion of the two together,
    over the undisturbed flow's (γ̇ = 1 times their distance in y): 0 for a pair moving as one body."""
    rigid = np.cross(sol.omega[0], x[1] - x[0])
    return (sol.v[1] - sol.v[0] - rigid)[0] / (x[1, 1] - x[0, 1])


def test_overlapping_shells_lock_a_near_pair_and_shells_kept_apart_let_it_slide():
    """At the security gap α (0.48 voxel) with s = 1.3 (0.72 voxel of shell each) the overlapping shells
    bridge the gap with rigid voxels: the pair slides by less than 5 % of the undisturbed flow (it moves
    as one body, up to the penalty's rigidity error). Kept apart, the shells leave the fluid gap, and
    the pair slides as two bodies do, by more than 30 % like the geometric pair (s = 1): the 72³ runs
    that s = 1.212 made 8 times too diffusive (docs/fluid_coupled_ci.md) had this locking."""
    locked = _sliding(*_pair(ALPHA, SCALE, "overlap"))
    apart = _sliding(*_pair(ALPHA, SCALE, "apart"))
    geometric = _sliding(*_pair(ALPHA, 1.0, "overlap"))
    assert locked < 0.05, locked
    assert apart > 0.3 and geometric > 0.3, (apart, geometric)


def test_shells_kept_apart_lie_between_the_geometric_and_the_overlapping_bodies():
    """Kept apart, every voxel's χ lies between that of the geometric radius and that of the
    overlapping shells (the geometric body is kept, the shells only yield; a shell's weight is in
    [0, 1]), to the round-off of the sub-voxel sums; far apart (3 R) the two rules agree bit for bit."""
    _, near_apart = _pair(ALPHA, SCALE, "apart", along="z", tol=1e-3)
    _, near_overlap = _pair(ALPHA, SCALE, "overlap", along="z", tol=1e-3)
    _, near_geometric = _pair(ALPHA, 1.0, "apart", along="z", tol=1e-3)
    eps = 64 * np.finfo(float).eps  # the sums over 3³ sub-points of terms <= 1
    assert np.all(near_apart.chi <= near_overlap.chi + eps)
    assert np.all(near_apart.chi >= near_geometric.chi - eps)
    assert near_apart.chi.sum() < near_overlap.chi.sum() - 1.0  # shells did yield, by voxels' worth
    _, far_apart = _pair(3 * R, SCALE, "apart", along="z", tol=1e-3)
    _, far_overlap = _pair(3 * R, SCALE, "overlap", along="z", tol=1e-3)
    assert np.array_equal(far_apart.chi, far_overlap.chi)


def test_bindings_refuse_an_unknown_rule():
    from pyfold.errors import InputError
    from pyfold.native.stokes import StokesSettings

    with pytest.raises(InputError, match="fibre_shells: must be one of"):
        StokesSettings(fibre_shells="split")


def _pair_run(path, stokes_extra):
    """The pair of :func:`_pair` at gap α (shorter, β = 3: the contact search's cell list needs the
    cell to exceed twice the fibre's reach) through fold_run: the positions at the end [m]."""
    gap = ALPHA
    write_run_file(path, x=[[0.5, 0.5 - R - gap / 2, 0.5], [0.5, 0.5 + R + gap / 2, 0.5]], p=[[1.0, 0.0, 0.0]] * 2,
                   radius=R, length=0.3, xi=xi_of(0.3 / (2 * R)), shape=[1, 1], dt=0.01, t_end=0.03, alpha=ALPHA,
                   snapshot_every=1,
                   stokes={"stokes_grid": (N, N, N), "stokes_tolerance": 1e-6, "stokes_fft_plan": np.int64(0),
                           "stokes_fibre_radius_scale": SCALE, **stokes_extra})
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(path) as f:
        return f["x"][-1].copy()  # (particle, xyz) at the end


def test_fold_run_reads_the_rule_and_a_run_file_without_it_overlaps(tmp_path):
    """fold_run reads /setup/resolved/stokes_fibre_shells: kept apart, the pair separates along the
    flow as two bodies (farther than the locked pair), and a run file written before the setting
    existed runs as "overlap", bit for bit (FFTW estimate plans)."""
    require_fold_run()
    from pyfold.native.stokes import FIBRE_SHELLS

    apart = _pair_run(tmp_path / "apart.h5", {"stokes_fibre_shells": np.int64(FIBRE_SHELLS["apart"])})
    overlap = _pair_run(tmp_path / "overlap.h5", {"stokes_fibre_shells": np.int64(FIBRE_SHELLS["overlap"])})
    old = _pair_run(tmp_path / "old.h5", {})  # no stokes_fibre_shells dataset
    assert np.array_equal(old, overlap)
    slid = (apart[1, 0] - apart[0, 0]) - (overlap[1, 0] - overlap[0, 0])
    assert slid > 0.1 * (2 * R + ALPHA) * 0.03, (apart, overlap)  # a tenth of the free sliding over t = 0.03


def test_a_scene_that_keeps_shells_apart_without_shells_is_warned():
    """"apart" acts on the shells of a scale above 1; at the geometric radius it changes nothing and
    the scene is told so."""
    from pyfold.scene import parse_scene
    from pyfold.scene.sheared_fibres import sheared_fibres

    def warned(scale):
        stokes = {"cells_per_diameter": 3, "fibre_shells": "apart"} | (
            {"fibre_radius_scale": scale} if scale != 1.0 else {})
        scene = sheared_fibres(5.0, 5.0, 1, 1.0, hydrodynamics="stokes", stokes=stokes, equivalent_aspect_ratio="zhang")
        return [w for w in parse_scene(scene.toml).warnings if "fibre_shells" in w]

    (text,) = warned(1.0)
    assert "no effect" in text
    assert warned(1.129) == []
