"""Symmetries of a finite cylinder's rotation rate that the equivalent-aspect-ratio study uses.

studies/jeffery_orbits/equivalent_aspect_ratio.py computes the Jeffery period of a cylinder
as T = 4 int_0^{pi/2} dtheta / |omega(theta)| from fixed-orientation solves. That rests on
two exact properties of the DISCRETE problem (a centred particle, a cubic grid with an even
voxel count, so the particle centre sits on a voxel corner, zero Lees-Edwards offset):

* mirror x -> -x (or y -> -y) maps the grid and the body at theta onto the body at -theta
  and reverses both the rotation and the shear, so omega(-theta) = omega(theta);
* a quarter turn about z maps the body at theta onto theta + pi/2, keeps the vorticity W
  and reverses the rate of strain E; omega is linear in (E, W) and W alone turns every
  viscosity field rigidly at -gamma_dot / 2, so omega(theta) + omega(theta + pi/2) = -gamma_dot
  (Jeffery's and Bretherton's constant term, here for any body shape).

Only the CG stopping test separates the two sides: with the Green-operator
preconditioner the spectrum of the preconditioned operator lies within a ratio kappa
(the viscosity contrast; Moulinec & Suquet 1998), so each rate carries a relative error
of at most kappa * tol, and a sum or difference of two at most 2 kappa tol gamma_dot.
"""
import numpy as np
import pytest

from pyfold.native.stokes import Particles, solve_particles
from test_run_common import stokes_settings

BETA, VPD, N = 3.0, 4, 18  # 18^3 grid, 4 voxels per diameter, cell 1.5 fibre lengths
KAPPA, TOL, SHEAR_RATE = 1.0e3, 1.0e-9, 1.0
BOUND = 2 * KAPPA * TOL * SHEAR_RATE  # worst case of two CG stopping errors


def omega_z(theta: float) -> float:
    h = 1.0 / N  # cell of unit edge
    d = VPD * h
    P = Particles(x=[[0.5, 0.5, 0.5]], p=[[np.cos(theta), np.sin(theta), 0.0]], radius=d / 2, length=BETA * d,
                  shape="fibre")
    sol = solve_particles(P, [1, 1, 1], (N, N, N), shear_rate=SHEAR_RATE,
                          settings=stokes_settings(kappa=KAPPA, tol=TOL, fibre_ends="flat"))
    assert sol.residual <= TOL
    return float(sol.omega[0, 2])


@pytest.mark.parametrize("theta", [0.3, 1.1])
def test_cylinder_rotation_rate_is_even_in_the_orientation_angle(theta):
    assert abs(omega_z(theta) - omega_z(-theta)) <= BOUND


@pytest.mark.parametrize("theta", [0.0, 0.3])
def test_cylinder_rotation_rates_a_quarter_turn_apart_sum_to_the_vorticity(theta):
    assert abs(omega_z(theta) + omega_z(theta + np.pi / 2) + SHEAR_RATE) <= BOUND


def test_off_corner_cylinder_breaks_the_mirror_symmetry_beyond_the_bound():
    # the same check must fail when the symmetry is absent: shift the centre by a third
    # of a voxel along x AND y, so that neither mirror (x -> -x or y -> -y, each of which
    # maps theta to -theta) maps the voxel grid onto itself
    h = 1.0 / N
    d = VPD * h
    rates = []
    for th in (0.3, -0.3):
        P = Particles(x=[[0.5 + h / 3, 0.5 + h / 3, 0.5]], p=[[np.cos(th), np.sin(th), 0.0]], radius=d / 2,
                      length=BETA * d, shape="fibre")
        rates.append(solve_particles(P, [1, 1, 1], (N, N, N), settings=stokes_settings(kappa=KAPPA, tol=TOL))
                     .omega[0, 2])
    assert abs(rates[0] - rates[1]) > BOUND
