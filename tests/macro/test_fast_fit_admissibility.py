"""The RK4 fit of pyfold.fast_fit never reports a C_I whose trajectory leaves the
orientation tensors (symmetric, unit trace, eigenvalues in [0, 1], finite), and the
run's own a4 ("exact") keeps the trace of the integrated a2 (ContractedTable)."""
import itertools

import numpy as np
import pytest
import xarray as xr

from pyfold import fast_fit
from pyfold._jax import jnp
from pyfold.closures import TabulatedA4
from pyfold.kinematics import simple_shear
from pyfold.models import jeffery_vectors
from pyfold.tensors import a2_from_vectors, a4_from_vectors

SHEAR = np.asarray(simple_shear(1.0, dim=3))
XI = 0.98  # beta ~ 10, as tests/macro/test_fit.py
EPS = float(np.finfo(np.float64).eps)


def _population(t):
    """a2, a4 of 400 fibres following Jeffery (C_I = 0) in shear from random directions."""
    rng = np.random.default_rng(7)
    p0 = rng.normal(size=(400, 3))
    p0 /= np.linalg.norm(p0, axis=1, keepdims=True)
    p = jeffery_vectors(jnp.asarray(p0), jnp.asarray(SHEAR), jnp.asarray(t), XI)
    return np.asarray(a2_from_vectors(p)), np.asarray(a4_from_vectors(p))


def _sym4(T):
    return sum(T.transpose(perm) for perm in itertools.permutations(range(4))) / 24.0


def test_admissibility_names_the_first_record_and_its_cause():
    a = np.repeat(np.diag([0.5, 0.3, 0.2])[None], 6, axis=0)
    tol = 1e-12
    assert fast_fit.admissibility(a, tol) == (-1, "")
    # within the tolerance (round-off) is admissible
    b = a.copy()
    b[1, 2, 2] += 0.5 * tol
    assert fast_fit.admissibility(b, tol)[0] == -1
    cases = [
        ((3, 2, 2), 1e-6, "trace"),  # tr = 1 + 1e-6
        ((2, 2, 2), -0.3, "negative eigenvalue"),  # a33 = -0.1, tr = 0.7: both named
        ((4, 0, 1), 0.01, "asymmetry"),
    ]
    for (k, i, j), delta, cause in cases:
        b = a.copy()
        b[k, i, j] += delta
        first, why = fast_fit.admissibility(b, tol)
        assert first == k and cause in why, (k, why)
    b = a.copy()
    b[2] = np.diag([1.2, -0.1, -0.1])  # unit trace, eigenvalues outside [0, 1]
    first, why = fast_fit.admissibility(b, tol)
    assert first == 2 and "negative eigenvalue" in why and "above 1" in why and "trace" not in why
    b = a.copy()
    b[5, 0, 0] = np.nan
    b[4, 1, 1] = np.inf
    assert fast_fit.admissibility(b, tol) == (4, "non-finite a2")
    # measured from the start's own trace error (the data's), as the program does
    b = a + 1e-9 * np.eye(3) / 3
    assert fast_fit.admissibility(b, tol)[0] == -1


def test_contracted_table_contracts_to_the_a2_it_is_given():
    t = np.array([0.0, 1.0, 2.0])
    _, a4 = _population(t)
    table = fast_fit.contracted_table(t, a4)
    plain = TabulatedA4(t, a4)
    rng = np.random.default_rng(3)
    m = rng.normal(size=(3, 3))
    a2 = m @ m.T
    a2 /= np.trace(a2)
    for time in (0.3, 1.7):
        x = np.asarray(table(jnp.asarray(a2), time))
        # a4_ijkk = a2_ij: the entries are <= 1 and the correction a few flops each
        np.testing.assert_allclose(np.einsum("ijkk->ij", x), a2, rtol=0, atol=16 * EPS)
        np.testing.assert_allclose(x, _sym4(x), rtol=0, atol=16 * EPS)  # fully symmetric
        # on the run's own a2 (the contraction of its a4) the correction vanishes
        own = np.einsum("ijkk->ij", np.asarray(plain(None, time)))
        np.testing.assert_allclose(np.asarray(table(jnp.asarray(own), time)), np.asarray(plain(None, time)),
                                   rtol=0, atol=16 * EPS)
    # in 2-D (planar orientation): the same formula with d = 2
    rng2 = np.random.default_rng(4)
    p2 = rng2.normal(size=(3, 50, 2))
    p2 /= np.linalg.norm(p2, axis=-1, keepdims=True)
    table2 = fast_fit.contracted_table(t, np.asarray(a4_from_vectors(jnp.asarray(p2))))
    a2_2 = np.array([[0.7, 0.1], [0.1, 0.3]])
    x2 = np.asarray(table2(jnp.asarray(a2_2), 0.5))
    np.testing.assert_allclose(np.einsum("ijkk->ij", x2), a2_2, rtol=0, atol=16 * EPS)
    np.testing.assert_allclose(x2, _sym4(x2), rtol=0, atol=16 * EPS)


def test_exact_fit_of_another_model_keeps_the_trace():
    """Folgar-Tucker at xi = 0.9 with the a4 of a Jeffery population at xi = 0.98: the
    model does not reproduce the data, so the integrated a2 leaves the run's. With the
    recorded a4 alone the trace then obeys d tr/dt = 2 xi D:(a2 - a2_run) and runs away
    (the long default run: tr a2 = 6); with ContractedTable it is 1 to round-off and the
    fit is admissible. Over a strain of 100 at the records of
    test_rk4_fit_with_the_populations_own_a4_holds_ci_zero_on_its_bound (same size class)."""
    t = np.linspace(0.0, 100.0, 201)
    a2, a4 = _population(t)
    res = fast_fit.fit_ci_rk4("exact", t, a2, SHEAR, 0.9, a4=a4, ci_start=0.01)
    assert res.success and res.admissible, res.message
    steps = int(np.sum(np.ceil(np.diff(t) / res.step * (1 - 1e-12))))
    tol = fast_fit.admissible_tol(steps, 0.9, 100.0)  # γ̇ = 1
    assert np.max(np.abs(np.trace(res.a2, axis1=1, axis2=2) - 1.0)) <= tol
    assert np.isfinite(res.ci) and res.ci >= 0.0
    # the population's own shape factor: Jeffery, C_I = 0 as in tests/macro/test_fit.py
    own = fast_fit.fit_ci_rk4("exact", t, a2, SHEAR, XI, a4=a4, ci_start=0.01)
    assert own.success and own.admissible, own.message
    assert 0.0 <= own.ci <= 1e-6


def test_fit_leaving_the_orientation_tensors_is_reported_failed_with_time_and_cause():
    """A deliberately bad "exact" closure: the recorded a4 plus 1000 times a harmonic
    tensor H (fully symmetric, H_ijkk = 0, H:D != 0 in shear). It drives a2 out of the
    orientation tensors within the first record at every C_I: diffusion strong enough
    to hold it (C_I ~ 1e3) is beyond RK4's stability at any step the fit tries."""
    t = np.linspace(0.0, 10.0, 41)
    a2, a4 = _population(t)
    T = np.zeros((3,) * 4)
    T[0, 0, 1, 1] = 1.0
    S = _sym4(T)
    table = fast_fit.contracted_table(np.array([0.0, 1.0]), np.stack([S, S]))
    H = np.asarray(table(jnp.zeros((3, 3)), 0.5))  # S corrected to contract to a2 = 0
    assert np.abs(np.einsum("ijkk->ij", H)).max() <= 16 * EPS
    assert abs(np.einsum("ijkl,kl->ij", H, 0.5 * (SHEAR + SHEAR.T))[0, 1]) > 0.1
    res = fast_fit.fit_ci_rk4("exact", t, a2, SHEAR, XI, a4=a4 + 1e3 * H, ci_start=0.01)
    assert not res.success and not res.admissible
    assert np.isnan(res.ci) and np.isnan(res.stderr)
    assert res.inadmissible_time == t[1]
    smallest = fast_fit.MAX_STEP / 2**fast_fit.MAX_REFINEMENTS  # every halving was tried
    assert res.step == pytest.approx(smallest)
    assert res.inadmissible_step == round(t[1] / smallest)
    assert any(c in res.inadmissible_cause for c in ("trace", "negative eigenvalue", "non-finite"))
    assert "closure exact" in res.message and "t = 0.25 s" in res.message and res.inadmissible_cause in res.message


def test_summary_table_prints_failed_instead_of_a_ci():
    from pyfold.trajectory_fit import summary_table

    fits = xr.Dataset(
        {
            "ci": ("closure", [np.nan, 3e-4]),
            "ci_stderr": ("closure", [np.nan, 1e-5]),
            "residual_rms": ("closure", [np.nan, 0.03]),
            "success": ("closure", np.array([0, 1], dtype=np.int8)),
            "admissible": ("closure", np.array([0, 1], dtype=np.int8)),
            "inadmissible_time": ("closure", [45.0, np.nan]),
        },
        coords={"closure": ["exact", "fec"]},
    )
    errors = xr.Dataset({"mean_error_contracted": ("closure", [0.2])}, coords={"closure": ["fec"]})
    lines = summary_table(fits, errors).splitlines()
    assert "failed" in lines[1] and "t = 45 s" in lines[1] and "nan" not in lines[1]
    assert "3.000e-04" in lines[2] and "failed" not in lines[2]


def test_diffrax_fit_whose_trajectory_leaves_the_orientation_tensors_reports_no_value():
    """pyfold.fit.fit_parameters: the linear closure with C_I held at or below 2e-3
    leaves the positive semi-definite cone in shear at xi = 1 (smallest eigenvalue
    about -0.026 at C_I = 1e-3, tests/macro/test_solution_checks.py); fitted to an
    admissible history (quadratic closure), the optimum lies in that range, and the
    fit must say so instead of reporting it."""
    from pyfold.fit import fit_parameters, synthetic_dataset
    from pyfold.models import FolgarTucker
    from pyfold.tensors import isotropic_a2

    t = np.linspace(0.0, 200.0, 101)
    data = synthetic_dataset(FolgarTucker(ci=1e-3, xi=1.0, closure="quadratic"), isotropic_a2(3), SHEAR, t)
    res = fit_parameters(data, FolgarTucker(ci=1e-3, xi=1.0, closure="linear"), ("ci",), SHEAR,
                         bounds={"ci": (0.0, 2e-3)})
    assert not res.success
    assert np.isnan(res.values["ci"]) and np.isnan(res.stderr["ci"])
    assert res.message.startswith("closure linear: a2 leaves the orientation tensors at t = ")
    assert "positive semi-definite" in res.message
    # the time named is a sample time
    named = float(res.message.split("at t = ")[1].split(" s")[0])
    assert np.min(np.abs(t - named)) <= 1e-6 * named
