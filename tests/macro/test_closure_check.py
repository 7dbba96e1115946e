"""Closure errors measured against a population's own a4 (pyfold.closure_check)."""
import numpy as np
import pytest
import xarray as xr

from pyfold.closure_check import (
    COMPONENTS,
    acg_covariance,
    closure_a4,
    closure_errors,
    exact_closure_sampling_floor,
    window_means,
)
from pyfold.closures.exact import acg_a2
from pyfold.errors import InputError

from _roundoff import RATE_OPERATIONS, roundoff_atol


def population_dataset(p_series):
    a2 = np.einsum("tni,tnj->tij", p_series, p_series) / p_series.shape[1]
    a4 = np.einsum("tni,tnj,tnk,tnl->tijkl", p_series, p_series, p_series, p_series) / p_series.shape[1]
    return xr.Dataset(
        {"a2": (("time", "i", "j"), a2), "a4": (("time", "i", "j", "k", "l"), a4)},
        coords={"time": np.arange(len(a2), dtype=float)},
    )


def test_quadratic_exact_and_linear_wrong_for_aligned_population():
    p = np.tile(np.array([0.6, 0.8, 0.0]), (3, 10, 1))
    err = closure_errors(population_dataset(p), ["quadratic", "linear"])
    assert float(err["mean_error_full"].sel(closure="quadratic")) < 1e-14
    assert float(err["mean_error_contracted"].sel(closure="quadratic")) < 1e-14
    # the linear closure is exact only for isotropy: far off for perfect alignment
    assert float(err["mean_error_full"].sel(closure="linear")) > 0.1


def test_linear_exact_for_isotropic_spherical_design():
    g = (1 + np.sqrt(5)) / 2
    v = np.array([[0, 1, g], [0, -1, g], [1, g, 0], [-1, g, 0], [g, 0, 1], [-g, 0, 1]], float)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    err = closure_errors(population_dataset(v[None]), ["linear", "quadratic"])
    assert float(err["error_full"].sel(closure="linear")[0]) < 1e-14
    assert float(err["error_full"].sel(closure="quadratic")[0]) > 0.1


def test_missing_a4_is_named():
    ds = population_dataset(np.tile(np.array([1.0, 0, 0]), (2, 3, 1))).drop_vars("a4")
    with pytest.raises(InputError, match="'a4'"):
        closure_errors(ds, ["quadratic"])


# --- signed components, window means, the exact closure's sampling floor -------------

SHEAR = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])


def test_components_of_aligned_population_are_exact_a4_contraction():
    # p p p p : D = (p.D.p) p p; simple shear at rate 1: D_xy = D_yx = 1/2, gamma_dot = 1
    p = np.array([0.6, 0.8, 0.0])
    err = closure_errors(population_dataset(np.tile(p, (2, 5, 1))), ["quadratic"], velocity_gradient=SHEAR)
    pdp = p[0] * p[1]
    expected = {c: p["xyz".index(c[0])] * p["xyz".index(c[1])] * pdp for c in COMPONENTS[3]}
    tol = roundoff_atol(1.0, RATE_OPERATIONS)
    for c, value in expected.items():
        np.testing.assert_allclose(err["a4_D"].sel(component=c).values, value, rtol=0, atol=tol)
    # the quadratic closure is exact for aligned fibres: every signed component vanishes
    np.testing.assert_allclose(err["error_components"].values, 0.0, rtol=0, atol=tol)


def test_components_recover_a_known_perturbation_of_a4():
    # a4 = f(a2) + delta with delta fully symmetric: the signed components must be
    # -delta:D / gamma_dot, to round-off, and the norm error the norm of that
    rng = np.random.default_rng(7)
    p = rng.standard_normal((4, 50, 3))
    p /= np.linalg.norm(p, axis=-1, keepdims=True)
    ds = population_dataset(p)
    a4_closure = closure_a4("ibof", ds["a2"].values)
    g = rng.standard_normal((4, 3))
    delta = 1e-3 * np.einsum("ti,tj,tk,tl->tijkl", g, g, g, g)  # fully symmetric
    ds["a4"] = (("time", "i", "j", "k", "l"), a4_closure + delta)
    rate = 2.0
    L = rate * SHEAR
    err = closure_errors(ds, ["ibof"], velocity_gradient=L)
    D = 0.5 * (L + L.T)
    expected = -np.einsum("tijkl,kl->tij", delta, D) / rate
    comps = COMPONENTS[3]
    idx = ["xyz".index(c[0]) for c in comps], ["xyz".index(c[1]) for c in comps]
    scale = float(np.abs(ds["a4"].values).max()) * float(np.abs(D).max()) * 9 / rate
    np.testing.assert_allclose(err["error_components"].sel(closure="ibof").values, expected[:, idx[0], idx[1]],
                               rtol=0, atol=roundoff_atol(scale, RATE_OPERATIONS))


def test_window_means_of_constant_and_linear_series():
    t = np.arange(40, dtype=float)
    errors = xr.Dataset(
        {"error_contracted": (("closure", "time"), np.stack([np.full(40, 0.25), 0.01 * t])),
         "a4_D": (("time", "component"), np.tile([1.0, 2.0], (40, 1)))},
        coords={"closure": ["a", "b"], "time": t, "component": ["xx", "xy"]},
    )
    out = window_means(errors, 10.0, 29.0)
    assert out.attrs["n_records"] == 20 and out.attrs["t_start"] == 10.0 and out.attrs["t_end"] == 29.0
    tol = roundoff_atol(1.0, 40)
    # a constant: its own value, no scatter; a line: its value at the window's midpoint
    np.testing.assert_allclose(out["error_contracted"].values, [0.25, 0.195], rtol=0, atol=tol)
    assert float(out["error_contracted_stderr"].sel(closure="a")) <= tol
    np.testing.assert_allclose(out["a4_D"].values, [1.0, 2.0], rtol=0, atol=tol)
    assert "a4_D_stderr" in out and "error_contracted_stderr" in out
    assert "error_contracted_stderr" not in window_means(errors, 0.0, 5.0, stderr=False)


def test_window_means_refuses_an_empty_window():
    errors = xr.Dataset({"e": (("time",), np.ones(10))}, coords={"time": np.arange(10.0)})
    with pytest.raises(InputError, match="need at least 4"):
        window_means(errors, 0.0, 2.0)


@pytest.mark.parametrize("a2", [np.eye(3) / 3, np.diag([0.8, 0.05, 0.15]),
                                np.array([[0.6, 0.1, 0.0], [0.1, 0.3, 0.05], [0.0, 0.05, 0.1]])])
def test_acg_covariance_reproduces_its_second_moment(a2):
    # least squares (LM, xtol = ftol = 1e-14) on a quadrature accurate to ~1e-14
    # (pyfold.closures.exact): 1e-10 leaves four decades for the conditioning of the
    # log-parametrisation down to principal values of 0.05
    np.testing.assert_allclose(np.asarray(acg_a2(acg_covariance(a2))), a2, rtol=0, atol=1e-10)


def test_exact_closure_floor_falls_like_inverse_square_root_of_population():
    # the sample moments of N independent fibres deviate by O(N^-1/2) (central limit
    # theorem), and fec is smooth, so the mean relative error is c N^-1/2 + O(1/N).
    # With 64 populations per N the mean is known to ~4 % (relative s.d. of the error
    # about 0.3, measured by the draws themselves below), so the log-log slope
    # between N = 100 and 6400 is -1/2 within ~0.02 (one s.d.); +-0.1 is 5 s.d.
    a2 = np.diag([0.7, 0.1, 0.2])
    small = exact_closure_sampling_floor(a2, 100, SHEAR, draws=64, seed=1)[0]
    large = exact_closure_sampling_floor(a2, 6400, SHEAR, draws=64, seed=2)[0]
    for e in (small, large):
        assert np.std(e) / np.mean(e) / np.sqrt(e.size) < 0.06
    slope = np.log(large.mean() / small.mean()) / np.log(64.0)
    assert abs(slope + 0.5) < 0.1


def test_exact_closure_floor_is_seeded():
    a2 = np.diag([0.5, 0.2, 0.3])
    a = exact_closure_sampling_floor(a2, 20, SHEAR, draws=3, seed=5)
    b = exact_closure_sampling_floor(a2, 20, SHEAR, draws=3, seed=5)
    np.testing.assert_array_equal(a, b)
