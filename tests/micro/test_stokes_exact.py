"""Exact-rigidity Stokes solve (numerics.stokes.rigidity = "exact", fold_stokes_rigid):
exact results of the discrete scheme, the rigidity error at the solver tolerance, and its
relation to the penalised solve.

On a binary chi (every voxel empty or full) the penalised solve is a Tikhonov
regularisation of the exact one. With K the exact solve's operator on the solid voxels
(fold_stokes_rigid) and b = E there, the penalty kappa gives the polarisation
tau_k = (K + e W)^-1 b with e = 1 / (kappa - 1) and W = 1 / (2 eta_f) (the solid's
excess viscosity (kappa - 1) eta_f is the polarisation's compliance), and the exact solve
tau* = K^+ b. The particles' stress
is <b, tau>, so in the eigenbasis of K relative to W (eigenvalues s_i > 0, components c_i
of tau*):
    eta_exact - eta_kappa  is proportional to  sum_i c_i^2 s_i e / (s_i + e)  > 0,
which (i) is positive (the penalised particles are softer), (ii) falls monotonically as
kappa grows, (iii) falls by at most the ratio of the e's between two kappas,
(kappa2 - 1) / (kappa1 - 1), and (iv) approaches that ratio as e -> 0 (first order in
1/kappa). The tests check those four statements, not a measured number.
"""
from __future__ import annotations

import numpy as np
import pytest

from test_run_common import one_sphere_scene

from pyfold.native.stokes import Particles, StokesSettings, solve_chi, solve_particles

SHEAR2 = np.array([[0.0, 1.0], [0.0, 0.0]])


def _exact(**kw) -> StokesSettings:
    return StokesSettings(rigidity="exact", measure_plans=False, **kw)


def test_rigid_layers_in_shear_give_the_exact_laminate_viscosity():
    # shear across layers: with the rotated differences (velocity at the corners) the
    # shear stress is uniform, so eta_eff = 1 / <1 / eta> over the rows, exactly on the grid:
    # a rigid row (coverage >= 1/2, here 1 and 0.7) adds 0, a row of coverage 0.3 has the
    # harmonic mixing's kappa -> infinity viscosity eta_f / (1 - 0.3), a fluid row eta_f.
    # The Lees-Edwards basis must not change that.
    n, eta_f = 16, 2.0
    prof = np.zeros(n)
    prof[4:8] = 1.0
    prof[8] = 0.7
    prof[3] = 0.3
    chi = np.broadcast_to(prof[None, :], (n, n)).copy()
    sol = solve_chi(chi, np.array([[1.0, 0.37], [0.0, 0.8]]), SHEAR2, _exact(eta_f=eta_f, tol=1e-12))
    assert sol.eta_eff == pytest.approx(eta_f * n / ((n - 6) + (1 - 0.3)), rel=1e-10)
    assert sol.eta_dissipation == pytest.approx(sol.eta_eff, rel=1e-10)
    assert np.abs(sol.u[..., 1]).max() < 1e-10 * np.abs(sol.u[..., 0]).max()


def test_rigid_layers_3d_with_kappa_irrelevant():
    n = 12
    prof = np.zeros(n)
    prof[2:5] = 1.0
    chi = np.broadcast_to(prof[None, :, None], (8, n, 6)).copy()
    G = np.zeros((3, 3))
    G[0, 1] = 0.7
    eta = [solve_chi(chi, np.diag([1.0, 1.2, 0.9]), G, _exact(kappa=k, tol=1e-12)).eta_eff for k in (10.0, 1e9)]
    assert eta[0] == pytest.approx(n / (n - 3), rel=1e-10)
    assert eta[1] == eta[0]  # kappa plays no part


@pytest.fixture(scope="module")
def symmetric_sphere():
    # radius 5 voxels, centred on a grid corner of a 32^3 cell: the voxel set is symmetric
    # under x <-> y, under which the strain E_xy is invariant and a spin about z changes
    # sign, so the strain part of the spin vanishes: omega_z = -gamma_dot/2 exactly (up
    # to the solve), whatever the discretisation.
    P = Particles(x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=5 / 32, length=10 / 32, shape="sphere")
    tol = 1e-10
    return tol, solve_particles(P, [1, 1, 1], (32, 32, 32), settings=_exact(tol=tol))


def test_symmetric_sphere_spins_at_half_the_shear_rate_to_the_solver_tolerance(symmetric_sphere):
    tol, sol = symmetric_sphere
    assert sol.omega[0, 2] == pytest.approx(-0.5, abs=100 * tol)
    assert np.abs(sol.omega[0, :2]).max() < 100 * tol
    assert np.abs(sol.v[0]).max() < 100 * tol  # at the centre of the shear


def test_rigidity_error_is_the_solver_tolerance(symmetric_sphere):
    tol, sol = symmetric_sphere
    # the residual is the strain left on the solid voxels relative to E (fold_stress's
    # solid strain over the same voxels); the recursive and the true residual differ by
    # round-off only, far below tol
    assert sol.residual <= tol
    assert sol.solid_strain <= 2 * tol
    # Hill's lemma: <sigma>:E = <sigma:eps> once the constraint holds
    assert sol.eta_dissipation == pytest.approx(sol.eta_eff, rel=10 * tol)
    assert sol.eta_eff > 1.0


def _tikhonov_gaps(solve, kappas):
    exact = solve(StokesSettings(rigidity="exact", tol=1e-12, measure_plans=False)).eta_eff
    return [exact - solve(StokesSettings(kappa=k, tol=1e-12, measure_plans=False)).eta_eff for k in kappas]


def _check_tikhonov(gap, kappas):
    # solver error of each penalised eta: <= (kappa - 1) (tol + eps_op) of the particles'
    # part (fold_stokes_trust), 1e-7 of it at kappa 1e4: far below the gaps (~1e-4 of it)
    assert all(g > 0 for g in gap)  # (i)
    assert gap[0] > gap[1] > gap[2]  # (ii)
    r1, r2 = gap[0] / gap[1], gap[1] / gap[2]
    bound = [(kappas[i + 1] - 1) / (kappas[i] - 1) for i in range(2)]
    assert r1 <= bound[0] * (1 + 1e-6) and r2 <= bound[1] * (1 + 1e-6)  # (iii)
    assert r2 >= r1  # (iv): the ratio climbs towards kappa2 / kappa1


def test_penalised_solve_of_a_binary_solid_converges_to_the_exact_one_like_one_over_kappa():
    # a cube of 5^3 voxels off-centre: chi is 0 or 1, so any mixing rule gives the same
    n = 20
    chi = np.zeros((n, n, n))
    chi[4:9, 6:11, 3:8] = 1.0
    G = np.zeros((3, 3))
    G[0, 1] = 1.0
    kappas = [1e2, 1e3, 1e4]
    _check_tikhonov(_tikhonov_gaps(lambda st: solve_chi(chi, np.eye(3), G, st), kappas), kappas)


def _scene(path, **stokes):
    """:func:`one_sphere_scene` with t_end = 0.1, no output keys, and these ``[numerics.stokes]`` keys."""
    return one_sphere_scene(path, **{"numerics.t_end": 0.1, "numerics.time_scheme": None, "output": None,
                                     "numerics.stokes": {"cells_per_diameter": 4, "fft_plan": "estimate", **stokes}})


@pytest.mark.parametrize("stokes, key", [
    ({"rigidity": "exact", "fft_precision": "single", "tolerance": 1e-3}, "numerics.stokes.fft_precision"),
    ({"rigidity": "exact", "backend": "hypre"}, "numerics.stokes.backend"),
    ({"rigidity": "rigid"}, "numerics.stokes.rigidity"),
])
def test_validate_refuses_what_the_exact_solve_cannot_do_naming_the_key(tmp_path, capsys, stokes, key):
    from pyfold.cli import main

    assert main(["validate", str(_scene(tmp_path / "s.toml", **stokes))]) == 2
    assert key in capsys.readouterr().err


def test_validate_accepts_exact_rigidity_without_a_kappa_check(tmp_path, capsys):
    from pyfold.cli import main

    # tolerance 1e-2 would refuse kappa 1e3 under the penalty (kappa_max ~ 1/tol);
    # exact rigidity carries no penalty, so nothing limits it
    assert main(["validate", str(_scene(tmp_path / "s.toml", rigidity="exact", tolerance=1e-2))]) == 0


def _tiny_exact_run(path, tol):
    """Three particles (sphere, spheroid, fibre) in a 1.25^3 cell, 24^3 grid, exact rigidity."""
    from test_run_common import write_run_file, xi_of

    x = 1.25 * np.array([[0.3, 0.3, 0.3], [0.72, 0.62, 0.55], [0.35, 0.8, 0.8]])
    p = np.array([[1.0, 0.0, 0.0], [0.6, 0.64, 0.48], [0.0, 0.6, 0.8]])
    write_run_file(path, x=x, p=p, radius=[0.1, 0.075, 0.06], length=[0.2, 0.3, 0.3], xi=[0.0, xi_of(2.0), 0.7],
                   shape=[2, 3, 1], dt=0.02, t_end=0.1, collisions=2, alpha=0.01, output_every=1, snapshot_every=5,
                   cell_lengths=(1.25, 1.25, 1.25),
                   stokes={"stokes_grid": (24, 24, 24), "stokes_tolerance": tol, "stokes_rigidity": np.int64(1)})


def test_fold_run_exact_np2_equals_np1_to_the_solver_tolerance(tmp_path):
    from test_run_common import require_fold_run, run_fold

    require_fold_run()
    xr = pytest.importorskip("xarray")
    tol = 1e-10
    runs = []
    for ranks in (1, 2):
        path = tmp_path / f"np{ranks}.h5"
        _tiny_exact_run(path, tol)
        proc = run_fold(path, np_ranks=ranks)
        assert proc.returncode == 0, proc.stderr
        runs.append(xr.open_dataset(path, engine="h5netcdf"))
    one, two = runs
    # slab and serial transforms round differently: the same CG to tol, fields equal to ~tol
    for ds in (one, two):
        # the solver residual is the strain left in the particles (fold_stokes_rigid)
        assert np.all(ds.stokes_residual.values <= tol)
    its1, its2 = one.stokes_iterations.values, two.stokes_iterations.values
    assert np.all(np.abs(its1 - its2) <= 0.1 * its1)
    np.testing.assert_allclose(two.effective_viscosity.values, one.effective_viscosity.values, rtol=1e-8)
    np.testing.assert_allclose(two.x.values, one.x.values, rtol=0, atol=1e-9)
    np.testing.assert_allclose(two.a2.values, one.a2.values, rtol=0, atol=1e-9)
    assert np.all(one.effective_viscosity.values > 1.0)


def test_warm_start_carries_the_multiplier_only_where_the_voxel_stays_rigid():
    # The zero start has relative residual exactly 1. A multiplier carried onto a partly
    # covered voxel enters the residual multiplied by that voxel's compliance
    # (1 - chi) / (2 eta_f chi), which is unbounded as the coverage chi -> 0 (a fibre moving
    # by a fraction of a voxel leaves such voxels behind: this scene gave 4e2 .. 1.4e5).
    # Carried only where the voxel was and stays rigid (compliance 0), the guess's residual
    # is E minus the strain of the previous step's multiplier, which a step of 0.02 strain
    # changes by a fraction of itself: O(1), and the warm start must take no more
    # iterations than solving from zero would, with the same stopping rule, to within the
    # scatter of CG counts (a tenth).
    from pyfold.native.stokes import march

    rng = np.random.default_rng(3)
    x = np.array([[0.3, 0.25, 0.5], [0.7, 0.75, 0.4], [0.5, 0.5, 0.8], [0.2, 0.8, 0.2]])
    p = rng.normal(size=(4, 3))
    p /= np.linalg.norm(p, axis=1)[:, None]
    P = Particles(x=x, p=p, radius=1 / 16, length=0.5, shape="fibre")
    runs = {warm: march(P, [1, 1, 1], (32, 32, 32), dt=0.02, nsteps=6, scheme="ab2",
                        settings=_exact(tol=1e-6, warm_start=warm)) for warm in (True, False)}
    warm, cold = runs[True], runs[False]
    np.testing.assert_array_equal(cold.initial_residual, 1.0)
    assert np.all(warm.initial_residual[1:] < 10.0), warm.initial_residual
    assert warm.iterations[1:].sum() <= 1.1 * cold.iterations[1:].sum()
