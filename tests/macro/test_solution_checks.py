"""No silent wrong answers in the macro layer.

* :func:`pyfold.fit.steady_state_a2` returns the model's true stationary point for
  every closure (also SQC, which moves the trace) and checks the full residual;
* :func:`pyfold.models.solve_orientation` / :func:`~pyfold.models.solve_batch` flag
  a2 leaving the orientation tensors (linear closure: negative eigenvalue; SQC:
  trace not conserved);
* for models built on the principal axes of a2 (RSC, ...) they flag eigenvalue
  crossings, where those models are ill-posed.
"""
import warnings

import diffrax
import numpy as np
import pytest

from pyfold.errors import (
    ConvergenceError,
    EigenvalueCrossingWarning,
    InadmissibleOrientationWarning,
    PyfoldWarning,
)
from pyfold.fit import steady_state_a2
from pyfold.kinematics import simple_shear, uniaxial_elongation
from pyfold.models import MODELS, RSC, FolgarTucker, solve_batch, solve_orientation

ISO3 = np.eye(3) / 3.0
SHEAR = simple_shear(1.0)


def _no_pyfold_warning(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error", PyfoldWarning)
        return fn(*args, **kwargs)


# --------------------------------------------------------------------------- steady state


@pytest.mark.parametrize(("ci", "dim"), [(0.01, 3), (0.1, 3), (0.01, 2)])
def test_sqc_steady_state_is_the_long_time_limit_of_the_free_integration(ci, dim):
    # SQC contracts to a4_iikl = (a + 2 a.a)_kl / (1 + 2 a:a) != a_kl, so under
    # Folgar-Tucker the trace moves and the stationary point is off tr a2 = 1.
    model = FolgarTucker(ci=ci, xi=1.0, closure="sqc", dim=dim)
    L = simple_shear(1.0, dim=dim)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a_ss = steady_state_a2(model, L)
    # The free integration relaxes at a rate ~ C_I gamma_dot or faster; its value at
    # t = 1000 and t = 2000 must agree (converged) before serving as the reference.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InadmissibleOrientationWarning)  # trace moves: tested below
        sol = solve_orientation(model, np.eye(dim) / dim, L, np.array([0.0, 1000.0, 2000.0]),
                                rtol=1e-12, atol=1e-14, solver=diffrax.Dopri8())
    free = np.asarray(sol.a2)
    assert np.abs(free[2] - free[1]).max() < 1e-11
    assert np.abs(a_ss - free[2]).max() < 1e-8
    assert abs(np.trace(a_ss) - 1.0) > 0.05  # the fixed point really is off the unit trace
    full_residual = np.abs(np.asarray(model.rate(0.0, a_ss, L))).max()  # gamma_dot = 1
    assert full_residual < 1e-10
    # ... and the user is told that this fixed point is not an orientation tensor
    assert any(issubclass(w.category, InadmissibleOrientationWarning) and "tr a2" in str(w.message) for w in caught)


def test_trace_preserving_closure_steady_state_keeps_unit_trace_without_warning():
    model = FolgarTucker(ci=0.01, xi=1.0, closure="ibof")
    a = _no_pyfold_warning(steady_state_a2, model, SHEAR)
    assert np.trace(a) == pytest.approx(1.0, abs=1e-15)
    assert np.abs(np.asarray(model.rate(0.0, a, SHEAR))).max() < 1e-12


def test_steady_state_tolerance_is_relative_to_the_shear_rate():
    # Same state at gamma_dot = 1 and 1000 (the steady state is rate independent);
    # an absolute tolerance of 1e-13 on rates of order 1e3 would be unreachable.
    model = FolgarTucker(ci=0.01, xi=1.0, closure="ibof")
    a1 = steady_state_a2(model, SHEAR)
    a1000 = steady_state_a2(model, simple_shear(1000.0))
    np.testing.assert_allclose(a1000, a1, atol=1e-11)


def test_steady_state_not_converged_names_closure_ci_and_residual():
    model = FolgarTucker(ci=0.01, xi=1.0, closure="sqc")
    with pytest.raises(ConvergenceError, match=r"closure='sqc'.*ci=0\.01|ci=0\.01.*closure='sqc'") as info:
        steady_state_a2(model, SHEAR, max_iter=2)
    assert "max |da2/dt| / gamma_dot" in str(info.value)


# --------------------------------------------------------------------------- admissibility


def _tol_eig(sol, rtol=1e-8, atol=1e-10, d=3):
    # The documented bound: 2 N d (atol + rtol), N = accepted steps.
    return 2.0 * int(sol.stats["num_accepted_steps"]) * d * (atol + rtol)


def test_linear_closure_leaving_the_psd_cone_is_flagged_with_its_time():
    # Known finding (test_models_ft): FT, C_I = 1e-3, xi = 1, shear from isotropy,
    # the linear closure reaches a smallest eigenvalue of about -0.026.
    t = np.linspace(0.0, 200.0, 201)
    with pytest.warns(InadmissibleOrientationWarning, match=r"at t = \d+(\.\d*)? s.*positive semi-definite") as rec:
        sol = solve_orientation(FolgarTucker(ci=1e-3, xi=1.0, closure="linear"), ISO3, SHEAR, t)
    lowest = np.linalg.eigvalsh(np.asarray(sol.a2))[:, 0]
    assert lowest.min() < -0.02
    assert sol.admissible is False
    tol = _tol_eig(sol)
    k = int(np.flatnonzero(lowest < -tol)[0])
    assert sol.first_inadmissible_time == t[k]
    assert f"t = {t[k]:.6g} s" in sol.admissibility_message
    assert f"t = {t[k]:.6g} s" in str(rec[0].message)
    assert "smallest eigenvalue" in sol.admissibility_message


def test_sqc_trajectory_whose_trace_moves_is_flagged():
    t = np.linspace(0.0, 50.0, 51)
    with pytest.warns(InadmissibleOrientationWarning, match="trace not conserved"):
        sol = solve_orientation(FolgarTucker(ci=1e-2, xi=1.0, closure="sqc"), ISO3, SHEAR, t)
    trace = np.trace(np.asarray(sol.a2), axis1=1, axis2=2)
    assert sol.admissible is False
    k = int(np.flatnonzero(t == sol.first_inadmissible_time)[0])
    assert k > 0 and abs(trace[k] - 1.0) > 1e-3
    assert f"tr a2 = {trace[k]:.10g}" in sol.admissibility_message


@pytest.mark.parametrize("closure", ["ibof", "fec"])
def test_admissible_closures_are_not_flagged(closure):
    t = np.linspace(0.0, 200.0, 201)
    sol = _no_pyfold_warning(solve_orientation, FolgarTucker(ci=1e-3, xi=1.0, closure=closure), ISO3, SHEAR, t)
    assert sol.admissible is True
    assert np.isnan(sol.first_inadmissible_time)
    assert sol.admissibility_message == ""


def test_batch_flags_the_offending_member_only():
    # Linear closure: C_I = 1e-3 leaves the PSD cone, C_I = 0.1 stays inside it.
    model = (FolgarTucker(xi=1.0, closure="linear"), {"ci": np.array([0.1, 1e-3])})
    with pytest.warns(InadmissibleOrientationWarning, match=r"1 of 2 members: member 1: .* at t = "):
        sol = solve_batch(model, ISO3, SHEAR, np.linspace(0.0, 200.0, 201))
    np.testing.assert_array_equal(sol.admissible, [True, False])
    assert np.isnan(sol.first_inadmissible_time[0]) and np.isfinite(sol.first_inadmissible_time[1])
    assert sol.admissibility_message[0] == "" and "positive semi-definite" in sol.admissibility_message[1]


# --------------------------------------------------------------------------- eigenvalue crossings


def test_only_principal_axis_models_are_marked_as_using_eigenvectors():
    marked = {name for name, cls in MODELS.items() if cls.uses_eigenvectors}
    assert marked == {"rsc", "ard_rsc", "iard_rpr", "pard", "pard_rpr", "mrd"}


# Uniaxial elongation along x keeps a diagonal a2 diagonal (the frame is fixed by
# symmetry), so the diagonal entries are the eigenvalues and their crossings are
# exact: from diag(0.2, 0.5, 0.3), a_xx grows through a_zz (and later a_yy).
ELONGATION = uniaxial_elongation(1.0)
CROSSING_START = np.diag([0.2, 0.5, 0.3])
RSC_MODEL = RSC(ci=0.01, kappa=0.1, xi=1.0, closure="ibof")


@pytest.fixture(scope="module")
def true_crossing_time():
    t = np.linspace(0.0, 4.0, 4001)
    with pytest.warns(EigenvalueCrossingWarning):
        sol = solve_orientation(RSC_MODEL, CROSSING_START, ELONGATION, t, rtol=1e-11, atol=1e-13)
    a2 = np.asarray(sol.a2)
    assert np.abs(a2 - np.einsum("tii->ti", a2)[:, :, None] * np.eye(3)).max() < 1e-14  # stays diagonal
    diff = a2[:, 0, 0] - a2[:, 2, 2]
    # the ordering of the eigenvalues really swaps, once, in [0, 4]
    assert diff[0] < 0 < diff[-1] and np.count_nonzero(np.diff(np.sign(diff))) == 1
    assert np.all(a2[:, 1, 1] > a2[:, 0, 0])  # a_xx passes a_yy only later
    k = int(np.flatnonzero(diff > 0)[0])
    return t[k - 1] - diff[k - 1] * (t[k] - t[k - 1]) / (diff[k] - diff[k - 1])


def test_rsc_eigenvalue_crossing_is_flagged_at_its_time(true_crossing_time):
    spacing = 0.25
    t = np.arange(0.0, 4.0 + spacing / 2, spacing)
    with pytest.warns(EigenvalueCrossingWarning, match=r"eigenvalues 2 and 3 .* cross at t = ") as rec:
        sol = solve_orientation(RSC_MODEL, CROSSING_START, ELONGATION, t)
    assert abs(sol.crossing_time - true_crossing_time) < spacing
    assert f"t = {sol.crossing_time:.6g} s" in str(rec[0].message)
    assert sol.admissible is True  # a crossing is not an inadmissible a2


def test_rsc_batch_flags_the_crossing_member(true_crossing_time):
    starts = np.stack([np.diag([0.5, 0.3, 0.2]), CROSSING_START])
    with pytest.warns(EigenvalueCrossingWarning, match="1 of 2 members: member 1: "):
        sol = solve_batch(RSC_MODEL, starts, ELONGATION, np.linspace(0.0, 4.0, 17))
    assert np.isnan(sol.crossing_time[0])
    assert abs(sol.crossing_time[1] - true_crossing_time) < 0.25


def test_rsc_without_crossing_is_not_flagged_and_isotropic_start_is_no_crossing():
    # From isotropy (triple eigenvalue at t = 0, which only splits) in shear: z stays
    # a principal axis by symmetry, and its eigenvalue a_zz stays strictly between
    # the two in-plane ones, so no eigenvalue crosses another.
    t = np.linspace(0.0, 100.0, 401)
    sol = _no_pyfold_warning(solve_orientation, RSC_MODEL, ISO3, SHEAR, t)
    a2 = np.asarray(sol.a2)
    in_plane = np.linalg.eigvalsh(a2[:, :2, :2])
    assert np.abs(a2[:, 2, :2]).max() < 1e-14
    assert np.all(in_plane[1:, 1] > a2[1:, 2, 2]) and np.all(a2[1:, 2, 2] > in_plane[1:, 0])
    assert np.isnan(sol.crossing_time) and sol.crossing_message == ""


def test_persistent_degeneracy_is_no_crossing():
    # Transversely isotropic about x, in elongation along x: the (y, z) pair stays
    # exactly degenerate and a_xx only grows away from it.
    sol = _no_pyfold_warning(solve_orientation, RSC_MODEL, np.diag([0.6, 0.2, 0.2]), ELONGATION,
                             np.linspace(0.0, 4.0, 17))
    assert np.isnan(sol.crossing_time)


def test_models_not_built_on_eigenvectors_are_not_checked_for_crossings():
    t = np.linspace(0.0, 4.0, 17)
    sol = _no_pyfold_warning(solve_orientation, FolgarTucker(ci=0.01, xi=1.0, closure="ibof"), CROSSING_START,
                             ELONGATION, t)
    assert sol.crossing_time is None and sol.crossing_message is None
