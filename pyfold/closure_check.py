"""Closures tested against a direct simulation's own fourth-order tensor.

A direct simulation gives both ``a2(t)`` and the exact ``a4(t)`` of its fibre
population, so a closure ``f`` can be judged without any orientation model:

    e_F(t) = ||f(a2(t)) − a4(t)||_F / ||a4(t)||_F                (whole tensor)
    e_D(t) = ||(f(a2) − a4):D||_F / ||a4:D||_F                    (what enters the
                                                                    Folgar–Tucker rate)

The second error is the one that matters for orientation prediction: the
Folgar–Tucker equation only sees ``a4`` through ``a4:D`` (Advani & Tucker 1987;
Cintra & Tucker 1995 fit their closures by exactly this contraction).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import xarray as xr

from pyfold._jax import jax, jnp
from pyfold.closures import available, get_closure
from pyfold.errors import InputError
from pyfold.kinematics import rate_of_strain


def _require(data: xr.Dataset, name: str, ndim: int) -> np.ndarray:
    if name not in data:
        raise InputError(f"data: variable {name!r} is required for a closure test (have {list(data.data_vars)})")
    values = np.asarray(data[name].values, dtype=np.float64)
    if values.ndim != ndim:
        raise InputError(f"data[{name!r}]: expected {ndim} dimensions (time first), got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise InputError(f"data[{name!r}]: contains NaN or infinity")
    return values


def closure_errors(
    data: xr.Dataset,
    closures: Sequence[str] | None = None,
    velocity_gradient: np.ndarray | None = None,
) -> xr.Dataset:
    """Errors of each closure against the data's own ``a4`` at every time.

    Parameters
    ----------
    data
        Dataset with ``a2(time, i, j)`` and ``a4(time, i, j, k, l)`` (a pyfold run,
        or any population statistics).
    closures
        Registered closure names; default: every closure available in the data's
        dimension.
    velocity_gradient
        ``L_ij = ∂u_i/∂x_j`` of the imposed flow, for the ``a4:D`` error; default: the
        run's ``velocity_gradient`` attribute/variable if present, else simple shear.

    Returns
    -------
    xarray.Dataset
        ``error_full(closure, time)`` and ``error_contracted(closure, time)``
        (dimensionless relative Frobenius errors), plus their time means.
    """
    a2 = _require(data, "a2", 3)
    a4 = _require(data, "a4", 5)
    dim = a2.shape[-1]
    names = list(closures) if closures is not None else list(available(dim))
    if velocity_gradient is None:
        velocity_gradient = np.zeros((dim, dim))
        velocity_gradient[0, 1] = 1.0
    L = np.asarray(velocity_gradient, dtype=np.float64)[:dim, :dim]
    D = np.asarray(rate_of_strain(jnp.asarray(L)))
    a4_D = np.einsum("tijkl,kl->tij", a4, D)
    norm_full = np.linalg.norm(a4.reshape(len(a4), -1), axis=1)
    norm_D = np.linalg.norm(a4_D.reshape(len(a4), -1), axis=1)

    full, contracted = [], []
    for name in names:
        closed = np.asarray(jax.jit(jax.vmap(get_closure(name, dim)))(jnp.asarray(a2)))
        diff = closed - a4
        full.append(np.linalg.norm(diff.reshape(len(a4), -1), axis=1) / norm_full)
        diff_D = np.einsum("tijkl,kl->tij", diff, D)
        contracted.append(np.linalg.norm(diff_D.reshape(len(a4), -1), axis=1) / np.maximum(norm_D, 1e-300))

    time = data["time"].values if "time" in data.coords or "time" in data else np.arange(len(a2))
    out = xr.Dataset(
        {
            "error_full": (("closure", "time"), np.array(full).reshape(len(names), len(a2))),
            "error_contracted": (("closure", "time"), np.array(contracted).reshape(len(names), len(a2))),
        },
        coords={"closure": names, "time": time},
    )
    out["error_full"].attrs.update(units="1", long_name="||f(a2) - a4||_F / ||a4||_F")
    out["error_contracted"].attrs.update(units="1", long_name="||(f(a2) - a4):D||_F / ||a4:D||_F")
    out["mean_error_full"] = out["error_full"].mean("time")
    out["mean_error_contracted"] = out["error_contracted"].mean("time")
    return out
