"""Closure errors measured against a population's own a4 (pyfold.closure_check)."""
import numpy as np
import pytest
import xarray as xr

from pyfold.closure_check import closure_errors
from pyfold.errors import InputError


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
