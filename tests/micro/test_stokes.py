"""Fictitious-domain Stokes solver (fortran/stokes) against exact and published results.

Small sizes only (the whole file runs in well under a minute); the convergence
studies at larger sizes live in studies/stokes_validation and benchmarks/.
"""
import numpy as np
import pytest

from pyfold.errors import ConvergenceError, InputError
from pyfold.native.stokes import Particles, StokesSettings, march, solve_chi, solve_particles
from test_run_common import stokes_settings

SHEAR = np.array([[0.0, 1.0], [0.0, 0.0]])


def laminate(ny, dims):
    """chi(y): a slab, a partial layer and fluid; independent of x (and z)."""
    prof = np.zeros(ny)
    prof[ny // 3: ny // 2] = 1.0
    prof[ny // 2] = 0.3
    return np.broadcast_to(prof[None, :, None] if len(dims) == 3 else prof[None, :], dims).copy()


@pytest.mark.parametrize("derivative, n", [("fd", 16), ("spectral", 15)])
def test_laminate_in_shear_has_harmonic_mean_viscosity_on_a_sheared_lattice(derivative, n):
    # shear across layers: sigma_xy is uniform, so eta_eff = 1/<1/eta> exactly (also
    # discretely: voxel values); the skewed Lees-Edwards basis must not change that
    kappa, eta_f = 50.0, 2.0
    chi = laminate(n, (n, n))
    settings = stokes_settings(kappa=kappa, eta_f=eta_f, tol=1e-11, derivative=derivative, mixing="arithmetic")
    lattice = np.array([[1.0, 0.37], [0.0, 0.8]])
    sol = solve_chi(chi, lattice, SHEAR, settings)
    eta = eta_f * (1 + (kappa - 1) * chi[0])
    exact = 1.0 / np.mean(1.0 / eta)
    assert sol.eta_eff == pytest.approx(exact, rel=1e-9)
    assert sol.eta_dissipation == pytest.approx(exact, rel=1e-9)
    assert sol.stress[0, 1] == pytest.approx(exact * 1.0, rel=1e-9)
    # the flow is u_x(y) only
    assert np.abs(sol.u[..., 1]).max() < 1e-10 * np.abs(sol.u[..., 0]).max()


def test_laminate_3d_and_any_mixing_rule():
    n = 12
    chi = laminate(n, (8, n, 6))
    G = np.zeros((3, 3))
    G[0, 1] = 0.7
    settings = stokes_settings(kappa=1e3, tol=1e-11, mixing="harmonic")
    sol = solve_chi(chi, np.diag([1.0, 1.2, 0.9]), G, settings)
    eta = 1.0 / ((1 - chi[0, :, 0]) + chi[0, :, 0] / 1e3)
    assert sol.eta_eff == pytest.approx(1.0 / np.mean(1.0 / eta), rel=1e-9)


def test_uniform_viscosity_leaves_the_mean_flow_undisturbed():
    sol = solve_chi(np.full((8, 10), 0.4), np.eye(2), SHEAR, stokes_settings(kappa=10.0, mixing="arithmetic"))
    assert sol.iterations == 0
    assert np.abs(sol.u).max() == 0.0
    assert sol.eta_eff == pytest.approx(1 + 9 * 0.4, rel=1e-14)


@pytest.fixture(scope="module")
def sphere():
    # radius 4 voxels in a 32^3 periodic cell (phi = 0.82 %), off-centre in y
    P = Particles(x=[[0.5, 0.3, 0.45]], p=[[1.0, 0.0, 0.0]], radius=0.125, length=0.25, shape="sphere")
    return P, solve_particles(P, [1, 1, 1], (32, 32, 32), shear_rate=1.0, settings=stokes_settings(kappa=1e3))


def test_sphere_in_shear_spins_at_half_the_shear_rate(sphere):
    _, sol = sphere
    # u = (gamma_dot y, 0, 0): vorticity/2 = -gamma_dot/2 about z
    assert sol.omega[0, 2] == pytest.approx(-0.5, rel=0.01)
    assert np.abs(sol.omega[0, :2]).max() < 0.002  # voxel anisotropy only


def test_sphere_drifts_with_the_mean_flow(sphere):
    P, sol = sphere
    # frame rule of fold_cell: u_mean = G (x - c), c the cell centre
    expect = 1.0 * (P.x[0, 1] - 0.5)
    assert abs(sol.v[0, 0] - expect) < 0.005 * 0.125
    assert np.abs(sol.v[0, 1:]).max() < 0.002 * 0.125


def test_dilute_sphere_intrinsic_viscosity_is_einstein(sphere):
    _, sol = sphere
    phi = sol.solid_fraction
    assert phi == pytest.approx(4 / 3 * np.pi * 0.125**3, rel=0.01)  # partial volumes: right volume
    intrinsic = (sol.eta_eff - 1.0) / phi
    # Einstein (1906) 2.5; the simple-cubic lattice correction at phi = 0.8 % is a few %
    assert intrinsic == pytest.approx(2.5, rel=0.10)
    # Hill: <sigma>:E = <sigma:eps> for a balanced field, an independent solver check
    assert sol.eta_dissipation == pytest.approx(sol.eta_eff, rel=1e-5)
    assert sol.rigidity[0] < 0.01


def test_rigidity_error_falls_like_inverse_kappa_and_iterations_grow_slower_than_sqrt_kappa():
    P = Particles(x=[[0.5, 0.5]], p=[[0.8, 0.6]], radius=0.06, length=0.3, shape="spheroid")
    kappas = np.array([10.0, 100.0, 1000.0, 10000.0])
    rig, its = [], []
    for k in kappas:
        sol = solve_particles(P, [1, 1], (96, 96), settings=stokes_settings(kappa=k, tol=1e-8))
        rig.append(sol.rigidity[0])
        its.append(sol.iterations)
    slope_rig = np.polyfit(np.log(kappas[:3]), np.log(rig[:3]), 1)[0]
    slope_its = np.polyfit(np.log(kappas), np.log(its), 1)[0]
    assert -1.15 < slope_rig < -0.8
    assert rig[3] < rig[2]
    assert slope_its < 0.55


def test_spheroid_rotation_rate_approaches_jeffery_under_refinement():
    # beta = 3 prolate spheroid in a cell 3 lengths wide: Jeffery's lambda = 0.8 is
    # the difference of the rotation rates with the axis along the gradient and
    # along the flow, omega_y - omega_x = -gamma_dot lambda (Jeffery 1922)
    beta, lam = 3.0, 0.8
    errors = []
    for n in (24, 36):
        om = []
        for p in ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]):
            P = Particles(x=[[0.5, 0.5, 0.5]], p=[p], radius=1 / 18, length=2 * beta / 18, shape="spheroid")
            om.append(solve_particles(P, [1, 1, 1], (n, n, n), settings=stokes_settings(tol=1e-6)).omega[0, 2])
        assert om[0] + om[1] == pytest.approx(-1.0, abs=0.01)  # sum = vorticity: -gamma_dot
        errors.append(abs((om[0] - om[1]) / lam - 1.0))
    assert errors[1] < errors[0]
    assert errors[1] < 0.06


def _orbit_angle(scheme, dt, t_end=0.96):
    # start at t0 = -0.48 so the Lees-Edwards offset s = t Ly stays in [-Lx/2, Lx/2):
    # a basis re-choice (wrap) changes the discretisation by a jump, which would
    # cost AB2 one order (see the study's notes)
    th = np.deg2rad(100.0)
    P = Particles(x=[[0.5, 0.5]], p=[[np.cos(th), np.sin(th)]], radius=1 / 16, length=6 / 16, shape="spheroid")
    res = march(P, [1, 1], (48, 48), dt=dt, nsteps=int(round(t_end / dt)), t0=-0.48, scheme=scheme,
                settings=stokes_settings(tol=1e-10))
    assert np.allclose(np.linalg.norm(res.p, axis=-1), 1.0, atol=1e-13)  # exact rotations
    p = res.p[-1, 0]
    return np.arctan2(p[1], p[0])


@pytest.mark.parametrize("scheme, order", [("euler", 1.0), ("ab2", 2.0)])
def test_time_stepping_order_on_a_jeffery_orbit(scheme, order):
    # successive differences theta(dt) - theta(dt/2) shrink by 2^order (asymptotic pair)
    angles = np.array([_orbit_angle(scheme, dt) for dt in (0.08, 0.04, 0.02, 0.01)])
    diffs = np.abs(np.diff(angles))
    assert np.log2(diffs[1] / diffs[2]) == pytest.approx(order, abs=0.3)
    assert diffs[0] > diffs[1] > diffs[2]


def test_lees_edwards_basis_choice_does_not_change_the_physics():
    # offsets s and s - Lx describe the same lattice; with nx == ny the grids coincide
    P = Particles(x=[[0.5, 0.5]], p=[[0.6, 0.8]], radius=0.05, length=0.3, shape="fibre")
    a = solve_particles(P, [1, 1], (64, 64), shear_offset=0.3)
    b = solve_particles(P, [1, 1], (64, 64), shear_offset=0.3 - 1.0)
    assert b.omega[0, 2] == pytest.approx(a.omega[0, 2], rel=0.02)
    assert b.eta_eff == pytest.approx(a.eta_eff, rel=0.01)


@pytest.mark.parametrize("shape, radius, length", [("sphere", 0.1, 0.2), ("spheroid", 0.06, 0.4),
                                                    ("fibre", 0.05, 0.4)])
def test_partial_volume_chi_has_the_particle_volume_and_moves_smoothly(shape, radius, length):
    exact = {"sphere": 4 / 3 * np.pi * radius**3, "spheroid": 4 / 3 * np.pi * length / 2 * radius**2,
             "fibre": np.pi * radius**2 * length}[shape]
    vols = []
    for shift in np.linspace(0.0, 1 / 32, 5):
        P = Particles(x=[[0.5 + shift, 0.45, 0.5]], p=[[0.48, 0.6, 0.64]], radius=radius, length=length,
                      shape=shape)
        sol = solve_particles(P, [1, 1, 1], (32, 32, 32), shear_offset=0.2,
                              settings=stokes_settings(kappa=1.0, max_iter=1))
        vols.append(sol.chi.sum() / 32**3)
    tol = 0.01 if shape != "fibre" else 0.02  # sharp cylinder edges
    assert np.allclose(vols, exact, rtol=tol)
    assert np.ptp(vols) < 0.005 * exact


def test_bad_settings_and_non_convergence_are_reported():
    with pytest.raises(InputError, match="derivative"):
        StokesSettings(derivative="chebyshev")
    with pytest.raises(InputError, match="kappa"):
        StokesSettings(kappa=0.5)
    P = Particles(x=[[0.5, 0.5]], p=[[1.0, 0.0]], radius=0.1, length=0.2, shape="sphere")
    with pytest.raises(ConvergenceError, match="residual"):
        solve_particles(P, [1, 1], (32, 32), settings=stokes_settings(max_iter=3, tol=1e-12))
    with pytest.raises(InputError, match="own periodic image"):
        big = Particles(x=[[0.5, 0.5]], p=[[1.0, 0.0]], radius=0.05, length=0.98, shape="fibre")
        solve_particles(big, [1, 1], (32, 32))


@pytest.mark.parametrize("kappa", [10.0, 1e3])
def test_extrapolated_initial_guess_changes_iterations_not_the_solution(kappa):
    # The guess only changes where CG starts: both marches stop at the relative
    # preconditioned residual tol, and the preconditioned operator's spectrum lies in
    # [eta_min, eta_max]/eta0, so each solve's relative error is at most kappa * tol.
    # Over t_end the positions (axes) then differ by at most 2 t_end kappa tol max|v|
    # (max|omega|), with |v| <= gamma_dot Ly/2 and |omega| <= gamma_dot here.
    th = np.deg2rad(100.0)
    P = Particles(x=[[0.5, 0.6]], p=[[np.cos(th), np.sin(th)]], radius=1 / 16, length=6 / 16, shape="spheroid")
    tol, dt, nsteps = 1e-10, 0.02, 16
    runs = {g: march(P, [1, 1], (48, 48), dt=dt, nsteps=nsteps, t0=-0.16, scheme="ab2",
                     settings=stokes_settings(tol=tol, kappa=kappa, guess=g)) for g in ("previous", "extrapolate")}
    a, b = runs["previous"], runs["extrapolate"]
    assert np.all(a.residual <= tol) and np.all(b.residual <= tol)
    bound = 2 * dt * nsteps * kappa * tol
    assert np.abs(a.x - b.x).max() <= bound * 0.5
    assert np.abs(a.p - b.p).max() <= bound * 1.0
    assert np.abs(b.initial_residual[2:] - a.initial_residual[2:]).max() > 0  # the guesses differ
