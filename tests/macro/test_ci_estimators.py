"""C_I estimators (pyfold.ci_estimators) and steady-state detection (pyfold.steady_state).

Every check has a known truth: a Folgar-Tucker trajectory integrated with a known
C_I and the IBOF closure (a4 = closure(a2) along it), an exact Jeffery population
(C_I = 0), a steady state of a known C_I, and seeded synthetic series (exponential
relaxation plus AR(1) noise) whose stationary mean is known.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from pyfold._jax import jnp
from pyfold.ci_estimators import ci_rate_regression, ci_steady_state_match, three_point_derivative
from pyfold.errors import InputError
from pyfold.fit import steady_state_a2, synthetic_dataset
from pyfold.kinematics import simple_shear
from pyfold.models import FolgarTucker, jeffery_vectors
from pyfold.steady_state import blocking_stderr, detect_steady_state
from pyfold.tensors import a2_from_vectors, a4_from_vectors, isotropic_a2

SHEAR = np.asarray(simple_shear(1.0, dim=3))
XI = 0.98
#: One fine record grid (h = 0.05, strain 0..20); h = 0.1 and 0.2 are its subsamples,
#: so one compiled solve serves every spacing.
FINE = np.linspace(0.0, 20.0, 401)


@pytest.fixture(scope="module", params=[3e-3, 1e-2])
def ft_ibof(request):
    ci = request.param
    data = synthetic_dataset(FolgarTucker(ci=ci, xi=XI, closure="ibof"), isotropic_a2(3), SHEAR, FINE,
                             with_a4=True, rtol=1e-12, atol=1e-14)
    return ci, data["a2"].values, data["a4"].values


# --------------------------------------------------------------------------- (c) rate regression


def test_three_point_derivative_is_exact_for_parabolas_on_a_non_uniform_grid():
    t = np.cumsum(np.random.default_rng(1).uniform(0.5, 1.5, 30))
    y = 3.0 - 2.0 * t + 0.7 * t**2
    assert np.allclose(three_point_derivative(t, y), (-2.0 + 1.4 * t)[1:-1], rtol=1e-12, atol=1e-11)


def test_rate_regression_recovers_ci_at_second_order_in_the_record_spacing(ft_ibof):
    """Error O(h^2): the three-point derivative error is (h^2/6) a2''' (module docs);
    halving h divides it by 4 (3 to 5 allows for the next, O(h^4), term)."""
    ci, a2, a4 = ft_ibof
    errors = []
    for stride in (4, 2, 1):  # h = 0.2, 0.1, 0.05
        r = ci_rate_regression(FINE[::stride], a2[::stride], a4[::stride], SHEAR, XI)
        errors.append(abs(r.ci - ci))
    assert errors[-1] < 2e-3 * ci
    for coarse, fine in zip(errors[:-1], errors[1:]):
        assert 3.0 < coarse / fine < 5.0, errors


def test_rate_regression_on_a_window_and_a_non_uniform_grid(ft_ibof):
    ci, a2, a4 = ft_ibof
    rng = np.random.default_rng(3)
    keep = np.sort(np.concatenate([[0, FINE.size - 1], rng.choice(np.arange(1, FINE.size - 1), 200, replace=False)]))
    r = ci_rate_regression(FINE[keep], a2[keep], a4[keep], SHEAR, XI, window=(5.0, 15.0))
    assert 5.0 <= r.t_start and r.t_end <= 15.0
    assert abs(r.ci - ci) < 2e-2 * ci


def test_rate_regression_of_an_exact_jeffery_population_gives_zero():
    """Fibres following Jeffery's equation exactly: a2(t) obeys Jeffery's moment
    equation with the population's own a4, so C_I = 0 up to the O(h^2) derivative
    error (h = 0.05: below 1e-5 here) and within its standard error."""
    p0 = np.random.default_rng(7).normal(size=(500, 3))
    p = np.asarray(jeffery_vectors(p0, SHEAR, FINE, XI))
    a2 = np.asarray(jnp.stack([a2_from_vectors(q) for q in p]))
    a4 = np.asarray(jnp.stack([a4_from_vectors(q) for q in p]))
    r = ci_rate_regression(FINE, a2, a4, SHEAR, XI)
    assert abs(r.ci) < 1e-5
    assert abs(r.ci) <= 3.0 * r.stderr + 1e-6


def test_rate_regression_rejects_bad_arguments(ft_ibof):
    _, a2, a4 = ft_ibof
    with pytest.raises(InputError, match="a4"):
        ci_rate_regression(FINE, a2, a4[:, 0], SHEAR, XI)
    with pytest.raises(InputError, match="t:"):
        ci_rate_regression(FINE[::-1], a2, a4, SHEAR, XI)
    with pytest.raises(InputError, match="xi"):
        ci_rate_regression(FINE, a2, a4, SHEAR, 1.5)
    with pytest.raises(InputError, match="L:"):
        ci_rate_regression(FINE, a2, a4, np.zeros((3, 3)), XI)
    with pytest.raises(InputError, match="window"):
        ci_rate_regression(FINE, a2, a4, SHEAR, XI, window=(30.0, 40.0))


# --------------------------------------------------------------------------- (b) steady-state match


@pytest.mark.parametrize("ci_true", [3e-3, 1e-2])
def test_steady_state_match_recovers_a_known_ci(ci_true):
    a2 = steady_state_a2(FolgarTucker(ci=ci_true, xi=XI, closure="ibof"), SHEAR)
    se = np.full((3, 3), 1e-3)
    m = ci_steady_state_match(a2, "ibof", XI, SHEAR, a2_stderr=se)
    assert abs(m.ci - ci_true) < 1e-6 * ci_true
    assert m.residual_rms < 1e-9
    # the propagated error is the linearised response: checked against a perturbed match
    delta = np.zeros((3, 3))
    delta[0, 1] = delta[1, 0] = 1e-5
    shifted = ci_steady_state_match(a2 + delta, "ibof", XI, SHEAR)
    predicted = m.sensitivity[1] * 1e-5  # component (0, 1) is the second independent one
    assert abs((shifted.ci - m.ci) - predicted) < 0.05 * abs(predicted)
    assert 0.0 < m.stderr < math.inf
    root = ci_steady_state_match(a2, "ibof", XI, SHEAR, component=(0, 0), a2_stderr=se)
    assert abs(root.ci - ci_true) < 1e-6 * ci_true
    assert root.stderr == pytest.approx(1e-3 / abs(root.gradient[0]), rel=1e-12)


def test_steady_state_match_on_a_subset_of_components_ignores_the_others():
    """Least squares over (a11, a12) of a steady state whose a22, a33 were changed (trace
    kept): the changed components do not enter, so the known C_I is recovered as
    exactly as from the whole tensor; the Gauss-Newton sensitivity of the subset
    match (with a_33 = 1 - a11 - a22 among the components) predicts the response to
    a perturbation to first order."""
    ci_true = 3e-3
    a2 = np.asarray(steady_state_a2(FolgarTucker(ci=ci_true, xi=XI, closure="ibof"), SHEAR))
    moved = a2.copy()
    moved[1, 1] += 0.02
    moved[2, 2] -= 0.02
    m = ci_steady_state_match(moved, "ibof", XI, SHEAR, components=[(0, 0), (1, 0)])
    assert abs(m.ci - ci_true) < 1e-6 * ci_true
    assert m.method == "least_squares a_00 a_01" and not m.on_bound
    # the whole-tensor match sees the moved components and lands elsewhere
    assert abs(ci_steady_state_match(moved, "ibof", XI, SHEAR).ci - ci_true) > 1e-2 * ci_true
    # sensitivity with a_dd in the subset: perturb a11 by +delta, a33 by -delta
    three = ci_steady_state_match(a2, "ibof", XI, SHEAR, components=[(0, 0), (1, 1), (2, 2)])
    delta = 1e-5
    shifted = a2.copy()
    shifted[0, 0] += delta
    shifted[2, 2] -= delta
    moved3 = ci_steady_state_match(shifted, "ibof", XI, SHEAR, components=[(0, 0), (1, 1), (2, 2)])
    predicted = three.sensitivity[0] * delta  # a11 is the first independent component
    assert abs((moved3.ci - three.ci) - predicted) < 0.05 * abs(predicted)
    with pytest.raises(InputError, match="components"):
        ci_steady_state_match(a2, "ibof", XI, SHEAR, components=[(0, 0)], component=(0, 0))
    with pytest.raises(InputError, match="components"):
        ci_steady_state_match(a2, "ibof", XI, SHEAR, components=[(0, 3)])


def test_steady_state_match_beyond_the_closures_jeffery_fixed_point_is_on_the_lower_bound():
    """As C_I -> 0+ Folgar-Tucker's steady state in shear tends to the closure's fixed
    point of Jeffery's equation, its most aligned steady state (a11 falls as C_I
    grows). A target more aligned than the state at the lower bound is matched by no
    C_I in the bounds: least squares returns the bound itself and says so, the a11
    root is not bracketed, and span holds the steady states at both bounds."""
    lo, hi = 1e-6, 0.5
    edge = np.asarray(steady_state_a2(FolgarTucker(ci=lo, xi=XI, closure="ibof"), SHEAR))
    target = edge.copy()
    target[0, 0] += 0.03
    target[2, 2] -= 0.03
    with pytest.warns(RuntimeWarning, match="search bound"):
        m = ci_steady_state_match(target, "ibof", XI, SHEAR, bounds=(lo, hi))
    assert m.on_bound and m.ci == lo
    # both solves converge to |da2/dt| <= 1e-13; the inverse Jacobian at the fixed point is O(1 / the
    # Jeffery frequency ~ 0.1): the states agree to ~1e-12, 1e-10 leaves room
    np.testing.assert_allclose(m.span[0], edge[[0, 0, 0, 1, 1], [0, 1, 2, 1, 2]], rtol=0, atol=1e-10)
    assert m.span[1][0] < m.span[0][0]  # less aligned at the upper bound
    with pytest.raises(InputError, match="not reached"):
        ci_steady_state_match(target, "ibof", XI, SHEAR, bounds=(lo, hi), component=(0, 0))


def test_steady_state_match_rejects_bad_arguments():
    a2 = np.diag([0.8, 0.1, 0.1])
    with pytest.raises(InputError, match="a2_steady"):
        ci_steady_state_match(np.eye(3), "ibof", XI, SHEAR)
    with pytest.raises(InputError, match="a2_stderr"):
        ci_steady_state_match(a2, "ibof", XI, SHEAR, a2_stderr=np.ones(4))
    with pytest.raises(InputError, match="bounds"):
        ci_steady_state_match(a2, "ibof", XI, SHEAR, bounds=(0.0, 1.0))


# --------------------------------------------------------------------------- steady-state detection

TAU, AMP, PHI, SIGMA, MEAN, N = 50.0, 1.0, 0.9, 0.05, 0.3, 4000


def relaxation_with_ar1(seed: int, amplitude: float = AMP):
    """``MEAN + A exp(-t/TAU)`` plus stationary AR(1) noise (phi = 0.9, marginal s.d.
    SIGMA): integrated autocorrelation time (1 + phi)/(1 - phi) = 19 samples."""
    rng = np.random.default_rng(seed)
    t = np.arange(N, dtype=np.float64)
    e = rng.normal(0.0, SIGMA * math.sqrt(1.0 - PHI**2), N)
    x = np.empty(N)
    x[0] = rng.normal(0.0, SIGMA)
    for k in range(1, N):
        x[k] = PHI * x[k - 1] + e[k]
    return t, MEAN + amplitude * np.exp(-t / TAU) + x


def test_detection_onset_and_coverage_of_the_standard_error():
    """200 seeded repeats. Onset: MSER cuts where the remaining bias is comparable
    with the noise, so the residual bias A exp(-t0/TAU) at the onset is below 3 SIGMA
    (t0 > TAU ln(A / 3 SIGMA) = 1.9 TAU) and the cut is not wasteful (t0 < 10 TAU).
    Coverage of mean +- 1.96 s.e.: Binomial(200, 0.95) lies in [180, 200] with
    probability > 99.9 % (mean 190, s.d. 3.1)."""
    covered, onsets, flagged = 0, [], 0
    for seed in range(200):
        t, y = relaxation_with_ar1(seed)
        s = detect_steady_state(t, y)
        onsets.append(s.onset_time)
        flagged += not s.stationary
        covered += abs(s.mean - MEAN) <= 1.96 * s.stderr
        assert s.n_eff < s.n_samples
    onsets = np.array(onsets)
    assert np.all(AMP * np.exp(-onsets / TAU) < 3 * SIGMA), onsets.min()
    assert np.all(onsets < 10 * TAU), onsets.max()
    assert 180 <= covered <= 200, covered
    # false alarms (drift at 3 s.e., MSER minimum late): a few per cent at most
    assert flagged <= 20, flagged


def test_blocking_standard_error_of_ar1_is_unbiased_on_average():
    """True s.e. of the mean of AR(1): SIGMA sqrt(tau_int / n), tau_int = 19."""
    ratios = [blocking_stderr(relaxation_with_ar1(s, amplitude=0.0)[1])[0] / (SIGMA * math.sqrt(19.0 / N))
              for s in range(100)]
    assert 0.9 < np.mean(ratios) < 1.1


def test_detection_of_a_tensor_series_and_of_a_drift():
    t, y = relaxation_with_ar1(11)
    _, z = relaxation_with_ar1(12, amplitude=-0.5)
    s = detect_steady_state(t, np.stack([y, z, np.ones_like(y)], axis=1))
    assert s.mean.shape == (3,) and s.stderr[2] == 0.0 and s.mean[2] == 1.0
    drifting = MEAN + 1e-4 * t + relaxation_with_ar1(13, amplitude=0.0)[1] - MEAN
    d = detect_steady_state(t, drifting)
    assert not d.stationary and ("drift" in d.message or "second half" in d.message), d.message
    with pytest.raises(InputError, match="y"):
        detect_steady_state(t, y[:-1])
    with pytest.raises(InputError, match="t"):
        detect_steady_state(t[::-1], y)
