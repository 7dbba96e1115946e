"""How the RK4 fit of pyfold analyse is run must not change what it finds.

pyfold.fast_fit runs its fit programs through serialised exports in the per-user
cache (pyfold._jax.exported_call) and pyfold.trajectory_fit runs the closures' fits side
by side in threads. Both only change where the same program comes from and when it
runs: the fitted values must be the ones of a fresh trace run one closure at a time,
to the last bit (the same floating-point operations in the same order).
"""
from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from pyfold import _jax
from pyfold.fit import synthetic_dataset
from pyfold.kinematics import simple_shear
from pyfold.models import FolgarTucker
from pyfold.tensors import isotropic_a2

SHEAR = np.asarray(simple_shear(1.0, dim=3))
TIMES = np.linspace(0.0, 20.0, 41)
XI = 0.98
CLOSURES = ("quadratic", "linear")


@pytest.fixture(scope="module")
def data() -> xr.Dataset:
    model = FolgarTucker(ci=0.008, xi=XI, closure="quadratic")
    ds = synthetic_dataset(model, isotropic_a2(3), SHEAR, TIMES, noise=1e-3, seed=20240611)
    return ds.rename({d: n for d, n in zip(ds["a2"].dims, ("time", "i", "j"))})


def _fit(data, closure):
    from pyfold.fast_fit import fit_ci_rk4

    return fit_ci_rk4(closure, TIMES, data["a2"].values, SHEAR, XI, ci_start=0.03)


@pytest.mark.skipif(not _jax._can_serialise(), reason="jax export serialisation needs flatbuffers")
def test_fit_through_an_export_file_equals_the_fit_of_a_fresh_trace(data, tmp_path, monkeypatch):
    monkeypatch.setattr(_jax, "_LOADED", {})
    monkeypatch.setattr(_jax, "_CACHE", None)
    fresh = _fit(data, "quadratic")
    monkeypatch.setattr(_jax, "_CACHE", tmp_path)
    exported = _fit(data, "quadratic")  # exports, then runs the export
    assert len(list((tmp_path / "export").glob("fast_fit_quadratic_3d-*.jaxexport"))) == 1
    _jax._LOADED.clear()
    reread = _fit(data, "quadratic")  # a new process: read from the file
    for res in (exported, reread):
        assert res.success, res.message
        assert res.ci == fresh.ci and res.stderr == fresh.stderr and res.iterations == fresh.iterations
        assert res.step_error == fresh.step_error
        np.testing.assert_array_equal(res.a2, fresh.a2)


def test_fits_side_by_side_equal_the_fits_one_after_the_other(data, monkeypatch):
    from pyfold import trajectory_fit

    run = data.assign(a4=(("time", "i", "j", "k", "l"), np.zeros((TIMES.size,) + (3,) * 4)))
    monkeypatch.setattr(trajectory_fit, "_cores", lambda: 1)
    serial = trajectory_fit.fit_ci_per_closure(run, SHEAR, CLOSURES, XI)
    monkeypatch.setattr(trajectory_fit, "_cores", lambda: 2)
    threaded = trajectory_fit.fit_ci_per_closure(run, SHEAR, CLOSURES, XI)
    assert list(threaded["closure"].values) == list(CLOSURES)
    xr.testing.assert_identical(threaded, serial)
