"""Folgar-Tucker model and the diffrax integration (single runs and batches)."""
import warnings

import numpy as np
import pytest
from scipy.optimize import brentq

import equinox as eqx

from pyfold._jax import jax, jnp
from pyfold.closures import available, get_closure
from pyfold.errors import ConvergenceError, InadmissibleOrientationWarning, InputError, PyfoldWarning
from pyfold.kinematics import simple_shear, uniaxial_elongation
from pyfold.models import FolgarTucker, solve_batch, solve_orientation, status_message

ISO3 = np.eye(3) / 3.0
SHEAR = simple_shear(1.0)


def quadratic_ft_steady_state(ci):
    """Closed form: 2y(y + 3C_I)^2 = C_I for y = a12, quadratic closure, xi = 1
    (docs/physics.md#closed-form-folgar-tucker-steady-state)."""
    y = brentq(lambda y: 2 * y * (y + 3 * ci) ** 2 - ci, 0.0, 1.0, xtol=1e-15, rtol=1e-15)
    a22 = ci / (y + 3 * ci)
    return np.array([[1 - 2 * a22, y, 0], [y, a22, 0], [0, 0, a22]])


@pytest.fixture(scope="module")
def ft_quadratic_batch():
    # one compile for every C_I of the steady-state test
    cis = np.array([0.1, 0.01, 0.003])
    model = (FolgarTucker(xi=1.0, closure="quadratic"), {"ci": cis})
    return cis, solve_batch(model, ISO3, SHEAR, np.array([0.0, 150.0, 3000.0]))


def test_ft_quadratic_steady_state_in_shear_matches_closed_form(ft_quadratic_batch):
    cis, sol = ft_quadratic_batch
    assert np.all(np.asarray(sol.status) == 0)
    np.testing.assert_allclose(sol.a2[0, -1], [[0.6, 0.2, 0], [0.2, 0.2, 0], [0, 0, 0.2]], atol=1e-8)
    for k, ci in enumerate(cis):
        np.testing.assert_allclose(sol.a2[k, -1], quadratic_ft_steady_state(ci), atol=1e-7)


def test_solve_batch_agrees_with_single_solves(ft_quadratic_batch):
    cis, sol = ft_quadratic_batch
    single = solve_orientation(FolgarTucker(ci=cis[1], xi=1.0, closure="quadratic"), ISO3, SHEAR, sol.t)
    # vmapped arithmetic may reorder floating-point operations, so the adaptive
    # step sequence can differ by a few steps; the solutions agree to ~tolerance.
    np.testing.assert_allclose(sol.a2[1], single.a2, atol=1e-9)
    assert abs(int(single.stats["num_steps"]) - int(sol.stats["num_steps"][1])) < 0.05 * int(single.stats["num_steps"])


def test_solve_batch_reports_per_member_status_without_raising():
    # The third member is very stiff (C_I = 1e4): it alone exhausts max_steps.
    model = (FolgarTucker(xi=1.0, closure="quadratic"), {"ci": np.array([0.1, 0.05, 1e4])})
    a0 = np.stack([ISO3, np.diag([0.5, 0.3, 0.2]), ISO3])
    sol = solve_batch(model, a0, SHEAR, np.linspace(0.0, 20.0, 5), max_steps=400)
    np.testing.assert_array_equal(np.asarray(sol.status), [0, 0, 1])
    assert "max" in status_message(int(sol.status[2])).lower()
    assert sol.a2.shape == (3, 5, 3, 3)
    assert np.all(np.isfinite(sol.a2[:2]))
    assert int(sol.stats["num_steps"][2]) == 400


def test_solve_orientation_raises_convergence_error_when_asked():
    model = FolgarTucker(ci=1e4, xi=1.0, closure="quadratic")
    with pytest.raises(ConvergenceError, match="max_steps"):
        solve_orientation(model, ISO3, SHEAR, np.array([0.0, 20.0]), max_steps=50)
    sol = solve_orientation(model, ISO3, SHEAR, np.array([0.0, 20.0]), max_steps=50, throw=False)
    assert int(sol.status) == 1


def test_solve_orientation_validates_inputs():
    model = FolgarTucker(ci=0.01, closure="quadratic")
    with pytest.raises(InputError, match="trace"):
        solve_orientation(model, 2 * ISO3, SHEAR, [0.0, 1.0])
    with pytest.raises(InputError, match="t_eval"):
        solve_orientation(model, ISO3, SHEAR, [1.0, 0.0])
    with pytest.raises(InputError, match="dim"):
        solve_orientation(model, np.eye(2) / 2, SHEAR, [0.0, 1.0])
    with pytest.raises(InputError, match="tr L"):
        solve_orientation(model, ISO3, np.eye(3), [0.0, 1.0])
    with pytest.raises(InputError, match="ci"):
        FolgarTucker(ci=-0.1, closure="quadratic")
    with pytest.raises(InputError, match="allowed"):
        FolgarTucker(ci=0.1, closure="no-such-closure")


# Measured findings (FT, C_I = 1e-3, xi = 1, shear to t = 200 from isotropy), asserted
# for every closure registered in 3-D; a closure not listed must keep tr a2 = 1 and PSD:
# * linear (Hand 1962) leaves the PSD cone: smallest eigenvalue -0.026 (-0.032 at C_I = 0);
# * sqc (symmetrised quadratic) does not conserve the trace: its a4_ijkk = (a + 2 a.a)/3
#   differs from a_ij, so d tr(a2)/dt != 0; |tr a2 - 1| reaches 0.46.
PSD_BREAKERS = {"linear"}
TRACE_BREAKERS = {"sqc"}


class _ClosureSwitch(eqx.Module):
    """One compiled solve for every closure: a dynamic (unbatched) index selects the
    closure, so only the selected branch runs."""

    index: jax.Array
    names: tuple = eqx.field(static=True)

    def __call__(self, a2):
        return jax.lax.switch(self.index, [get_closure(n, 3) for n in self.names], a2)


def _solve_expecting_flag(name, *args, **kwargs):
    """solve_orientation that must warn (InadmissibleOrientationWarning) exactly for
    the closures listed as breakers, and must not warn otherwise."""
    if name in PSD_BREAKERS | TRACE_BREAKERS:
        cause = "positive semi-definite" if name in PSD_BREAKERS else "trace not conserved"
        with pytest.warns(InadmissibleOrientationWarning, match=cause):
            return solve_orientation(*args, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PyfoldWarning)
        return solve_orientation(*args, **kwargs)


@pytest.fixture(scope="module")
def ft_long_shear_per_closure():
    names = available(3)
    t = np.linspace(0.0, 200.0, 201)
    sols = [
        _solve_expecting_flag(
            name,
            FolgarTucker(ci=1e-3, xi=1.0, closure=_ClosureSwitch(index=jnp.asarray(k), names=names)),
            ISO3, SHEAR, t, throw=False)
        for k, name in enumerate(names)
    ]
    return {n: np.asarray(s.a2) for n, s in zip(names, sols)}, {n: int(s.status) for n, s in zip(names, sols)}, \
        {n: s.admissible for n, s in zip(names, sols)}


def test_ft_long_shear_trace_symmetry_and_psd_findings_for_every_closure(ft_long_shear_per_closure):
    a2s, status, admissible = ft_long_shear_per_closure
    assert "linear" in a2s
    for name, a2 in a2s.items():
        assert status[name] == 0, name
        assert admissible[name] == (name not in PSD_BREAKERS | TRACE_BREAKERS), name
        np.testing.assert_array_equal(a2, np.swapaxes(a2, 1, 2), err_msg=name)
        trace_err = np.abs(np.trace(a2, axis1=1, axis2=2) - 1.0).max()
        assert (trace_err > 0.1 if name in TRACE_BREAKERS else trace_err < 1e-10), f"{name}: |tr - 1| = {trace_err:.2e}"
        smallest = np.linalg.eigvalsh(a2).min()
        assert (smallest < -0.01 if name in PSD_BREAKERS else smallest > -1e-10), f"{name}: min eigenvalue {smallest:.2e}"


def test_interaction_term_drives_aligned_state_to_isotropy_at_the_derived_rate():
    # Uniaxial elongation along the fibres: the Jeffery term vanishes for a = e1 e1
    # (D.a + a.D = 2 eps e1e1 = 2 a4:D with a4 = e1e1e1e1), so only
    # 2 C_I gamma_dot (I - 3a) acts, gamma_dot = sqrt(3) eps:
    # da11/dt = -4 sqrt(3) C_I eps, da22/dt = da33/dt = 2 sqrt(3) C_I eps.
    ci, eps = 0.02, 0.7
    L = uniaxial_elongation(eps)
    a0 = np.diag([1.0, 0.0, 0.0])
    expected = 2 * np.sqrt(3) * ci * eps * np.diag([-2.0, 1.0, 1.0])
    model = FolgarTucker(ci=ci, xi=1.0, closure="quadratic")
    np.testing.assert_allclose(model.rate(0.0, a0, L), expected, atol=1e-15)
    h = 1e-4
    sol = solve_orientation(model, a0, L, np.array([0.0, h]))
    slope = (np.asarray(sol.a2[1]) - a0) / h
    np.testing.assert_allclose(slope, expected, rtol=2e-3, atol=1e-12)


def test_ft_planar_keeps_unit_trace_and_reaches_its_steady_state():
    # 2-D FT with the quadratic closure in shear, xi = 1: with a = [[1-y2, y], [y, y2]],
    # steady state needs y (1 + ...) ... checked against the rate being zero.
    model = FolgarTucker(ci=0.02, xi=1.0, closure="quadratic", dim=2)
    sol = solve_orientation(model, np.eye(2) / 2, simple_shear(1.0, dim=2), np.array([0.0, 50.0, 2000.0]))
    a2 = np.asarray(sol.a2)
    np.testing.assert_allclose(np.trace(a2, axis1=1, axis2=2), 1.0, atol=1e-12)
    np.testing.assert_allclose(model.rate(0.0, a2[-1], simple_shear(1.0, dim=2)), 0.0, atol=1e-9)
    assert np.linalg.eigvalsh(a2).min() > 0.0


def test_gradient_of_solution_wrt_ci_matches_finite_difference():
    t = np.array([0.0, 5.0])

    def a11(ci):
        m = FolgarTucker(ci=ci, xi=1.0, closure="quadratic")
        return solve_orientation(m, ISO3, SHEAR, t).a2[-1, 0, 0]

    g = jax.grad(a11)(0.05)
    fd = (a11(0.05 + 1e-5) - a11(0.05 - 1e-5)) / 2e-5
    assert np.isfinite(g)
    assert float(g) == pytest.approx(float(fd), rel=1e-5)
