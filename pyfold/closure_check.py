"""Closures tested against a direct simulation's own fourth-order tensor.

A direct simulation gives both ``a2(t)`` and the exact ``a4(t)`` of its fibre
population, so a closure ``f`` can be judged without any orientation model:

    e_F(t) = ||f(a2(t)) − a4(t)||_F / ||a4(t)||_F                (whole tensor)
    e_D(t) = ||(f(a2) − a4):D||_F / ||a4:D||_F                    (what enters the
                                                                    Folgar–Tucker rate)

The second error is the one that matters for orientation prediction: the
Folgar–Tucker equation only sees ``a4`` through ``a4:D`` (Advani & Tucker 1987;
Cintra & Tucker 1995 fit their closures by exactly this contraction).

Beyond the two norms, :func:`closure_errors` also returns the signed components of
``(f(a2) − a4):D / γ̇`` (which components a closure gets wrong, and in which
direction), :func:`window_means` averages any of them over a time window with a
blocking standard error (the stationary part of a run), and
:func:`exact_closure_sampling_floor` gives the error that even the exact closure
shows against a *finite* population of fibres, so that a closure's error can be told
apart from the sampling noise of the population it is judged against.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import xarray as xr

from pyfold._jax import exported_call, jax, jnp
from pyfold.closures import available, get_closure
from pyfold.errors import InputError
from pyfold.kinematics import rate_of_strain
from pyfold.steady_state import blocking_stderr

#: Components of a symmetric 3x3 (2x2) tensor in the order used for ``component``.
COMPONENTS = {3: ("xx", "yy", "zz", "xy", "xz", "yz"), 2: ("xx", "yy", "xy")}
_INDEX = {"x": 0, "y": 1, "z": 2}


def _require(data: xr.Dataset, name: str, ndim: int) -> np.ndarray:
    if name not in data:
        raise InputError(f"data: variable {name!r} is required for a closure test (have {list(data.data_vars)})")
    values = np.asarray(data[name].values, dtype=np.float64)
    if values.ndim != ndim:
        raise InputError(f"data[{name!r}]: expected {ndim} dimensions (time first), got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise InputError(f"data[{name!r}]: contains NaN or infinity")
    return values


def closure_a4(name: str, a2: np.ndarray) -> np.ndarray:
    """``f(a2)`` of the registered closure ``name`` at every record of ``a2`` (nt, d, d).

    One jit-compiled, vmapped evaluation (JAX caches the compiled program per shape).
    """
    values = np.asarray(a2, dtype=np.float64)
    if values.ndim != 3 or values.shape[1] != values.shape[2] or values.shape[1] not in (2, 3):
        raise InputError(f"a2: expected shape (nt, d, d) with d in {{2, 3}}, got {values.shape}")
    fn = get_closure(name, values.shape[-1])
    # through a serialised export in the per-user cache: a new process skips the trace
    return np.asarray(exported_call(f"closure_a4_{name}_{values.shape[-1]}d", lambda: jax.jit(jax.vmap(fn)),
                                    (values,)))


def _shear_rate(D: np.ndarray) -> float:
    return math.sqrt(2.0 * float(np.sum(D * D)))


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
        (dimensionless relative Frobenius errors), plus their time means;
        ``error_components(closure, time, component)``, the signed components
        ``xx, yy, zz, xy, xz, yz`` of ``(f(a2) − a4):D / γ̇`` (``γ̇ = sqrt(2 D:D)``, so
        dimensionless), and ``a4_D(time, component)``, those of ``a4:D / γ̇`` for scale.
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

    gamma_dot = _shear_rate(D)
    scale = gamma_dot if gamma_dot > 0.0 else 1.0  # a rigid rotation: components unscaled
    comps = COMPONENTS[dim]
    ci = [_INDEX[c[0]] for c in comps]
    cj = [_INDEX[c[1]] for c in comps]

    full, contracted, components = [], [], []
    for name in names:
        diff = closure_a4(name, a2) - a4
        # an a4 of zero norm is no orientation tensor (its trace a4_iijj is 1): the relative
        # error is undefined there, NaN rather than a division warning
        full.append(np.divide(np.linalg.norm(diff.reshape(len(a4), -1), axis=1), norm_full,
                              out=np.full(len(a4), np.nan), where=norm_full > 0.0))
        diff_D = np.einsum("tijkl,kl->tij", diff, D)
        contracted.append(np.linalg.norm(diff_D.reshape(len(a4), -1), axis=1) / np.maximum(norm_D, 1e-300))
        components.append(diff_D[:, ci, cj] / scale)

    time = data["time"].values if "time" in data.coords or "time" in data else np.arange(len(a2))
    out = xr.Dataset(
        {
            "error_full": (("closure", "time"), np.array(full).reshape(len(names), len(a2))),
            "error_contracted": (("closure", "time"), np.array(contracted).reshape(len(names), len(a2))),
        },
        coords={"closure": names, "time": time},
    )
    out["error_components"] = (("closure", "time", "component"),
                               np.array(components).reshape(len(names), len(a2), len(comps)))
    out["a4_D"] = (("time", "component"), a4_D[:, ci, cj] / scale)
    out = out.assign_coords(component=list(comps))
    out["error_components"].attrs.update(units="1", long_name="(f(a2) - a4):D / gamma_dot, signed components")
    out["a4_D"].attrs.update(units="1", long_name="a4:D / gamma_dot of the data")
    out["error_full"].attrs.update(units="1", long_name="||f(a2) - a4||_F / ||a4||_F")
    out["error_contracted"].attrs.update(units="1", long_name="||(f(a2) - a4):D||_F / ||a4:D||_F")
    out["mean_error_full"] = out["error_full"].mean("time")
    out["mean_error_contracted"] = out["error_contracted"].mean("time")
    return out


def window_means(errors: xr.Dataset, t_start: float = -math.inf, t_end: float = math.inf,
                 stderr: bool = True) -> xr.Dataset:
    """Time means of :func:`closure_errors` over ``t_start <= t <= t_end``.

    Every variable with a ``time`` dimension (``error_full``, ``error_contracted``,
    ``error_components``, ``a4_D``) is averaged over the records inside the window
    (equal weights: a run records at a fixed interval). With ``stderr``, the
    standard error of each mean is added as ``<name>_stderr``, by blocking
    (Flyvbjerg & Petersen 1989, level by Jonsson 2018:
    :func:`pyfold.steady_state.blocking_stderr`), which accounts for the serial
    correlation of the records. It is meaningful only on a *stationary* part (e.g.
    from the onset of :func:`pyfold.steady_state.detect_steady_state` on); over a
    transient it would measure the trend, so ask for ``stderr=False`` there.

    Returns
    -------
    xarray.Dataset
        The means (dims without ``time``), ``<name>_stderr`` when asked, and the
        attributes ``t_start``, ``t_end`` (first and last record used) and
        ``n_records``.

    Raises
    ------
    InputError
        No ``time`` coordinate, or fewer than 1 record (4 with ``stderr``) in the window.
    """
    if "time" not in errors.coords:
        raise InputError("errors: needs a 'time' coordinate (the output of closure_errors)")
    t = np.asarray(errors["time"].values, dtype=np.float64)
    keep = (t >= t_start) & (t <= t_end)
    n = int(keep.sum())
    need = 4 if stderr else 1
    if n < need:
        raise InputError(f"window [{t_start}, {t_end}]: {n} records, need at least {need}")
    part = errors.isel(time=np.flatnonzero(keep))
    out = xr.Dataset()
    for name, var in part.data_vars.items():
        if "time" not in var.dims:
            continue
        out[name] = var.mean("time")
        out[name].attrs.update(var.attrs)
        out[name].attrs["long_name"] = "time mean of " + var.attrs.get("long_name", name)
        if stderr:
            moved = var.transpose("time", ...)
            flat = np.asarray(moved.values).reshape(n, -1)
            se = np.array([blocking_stderr(flat[:, c])[0] for c in range(flat.shape[1])])
            out[name + "_stderr"] = (moved.dims[1:], se.reshape(moved.shape[1:]))
            out[name + "_stderr"].attrs.update(units=var.attrs.get("units", "1"),
                                              long_name="blocking standard error of the time mean")
    out.attrs.update(t_start=float(t[keep][0]), t_end=float(t[keep][-1]), n_records=n)
    return out


@jax.jit
def _acg_principal_jit(c):
    from pyfold.closures.exact import acg_a2

    return jnp.diagonal(acg_a2(jnp.diag(c)))


def _acg_principal(c: np.ndarray) -> np.ndarray:
    """Principal values of the second moment of the angular central Gaussian with
    covariance ``diag(c)``, from :func:`pyfold.closures.exact.acg_a2` (the module's
    quadrature), compiled once: the least squares below calls it a few dozen times
    per state."""
    return np.asarray(_acg_principal_jit(jnp.asarray(c, dtype=jnp.float64)))


def acg_covariance(a2: np.ndarray) -> np.ndarray:
    """A covariance ``C`` of the angular central Gaussian whose second moment is ``a2``.

    The exact closure (docs/physics.md#closure-approximations, ``fec``) is the fourth
    moment of this distribution; sampling it gives populations for which ``fec`` is
    exact in expectation. ``C`` is coaxial with ``a2``; its principal values (scaled
    so that the largest is 1: the distribution does not depend on the scale of
    ``C``) solve ``acg_a2(diag c) = diag(a2 principal)`` by least squares in
    ``log c``. Principal values of ``a2`` below 1e-12 are raised to it (an exactly
    planar or aligned state has a singular ``C``).
    """
    from scipy.optimize import least_squares

    a = np.asarray(a2, dtype=np.float64)
    a = 0.5 * (a + a.T)
    lam, vec = np.linalg.eigh(a)
    lam = np.clip(lam, 1e-12, None)
    lam = lam / lam.sum()
    order = np.argsort(lam)[::-1]
    target = lam[order]
    d = target.size

    # ACG principal values are ~ sqrt(c_i) / sum sqrt(c_j) (exact in 2-D): start there.
    x0 = 2.0 * np.log(target[1:] / target[0])

    def residual(x):
        c = np.concatenate([[1.0], np.exp(x)])
        return _acg_principal(c)[1:] / target[1:] - 1.0

    res = least_squares(residual, x0, method="lm", xtol=1e-14, ftol=1e-14) if d > 1 else None
    c_sorted = np.concatenate([[1.0], np.exp(res.x)]) if d > 1 else np.ones(1)
    c = np.empty(d)
    c[order] = c_sorted
    return (vec * c) @ vec.T


def exact_closure_sampling_floor(a2: np.ndarray, n_particles: int, velocity_gradient: np.ndarray,
                                 draws: int = 32, seed: int = 0) -> np.ndarray:
    """The ``a4:D`` error of the exact closure against a finite population of fibres.

    A population of ``N`` fibres drawn independently from the angular central
    Gaussian whose second moment is ``a2`` (the state of fibres that start isotropic
    and move by Jeffery's equation: Montgomery-Smith, Jack & Smith 2011) has sample
    moments ``a2_N``, ``a4_N``; ``fec(a2_N)`` differs from ``a4_N`` by sampling noise
    of order ``N^(-1/2)`` only. The mean of

        ||(fec(a2_N) - a4_N):D||_F / ||a4_N:D||_F

    over ``draws`` populations is the error floor of *any* closure judged against a
    population of ``N`` fibres in that state: a closure error at this level is not
    distinguishable from the finite population. (A population of a direct simulation
    without contacts is exactly such a sample, up to the time step.)

    Parameters
    ----------
    a2 : array (nt, d, d) or (d, d)
        States at which to evaluate the floor.
    n_particles : int
        Population size ``N``.
    velocity_gradient : array (d, d)
        ``L_ij`` of the flow (``D`` is its symmetric part).
    draws : int
        Independent populations per state.
    seed : int
        Seed of the random generator (numpy PCG64).

    Returns
    -------
    numpy.ndarray (nt, draws)
        The relative ``a4:D`` error per state and population.
    """
    states = np.asarray(a2, dtype=np.float64)
    if states.ndim == 2:
        states = states[None]
    if states.ndim != 3 or states.shape[1] != states.shape[2] or states.shape[1] not in (2, 3):
        raise InputError(f"a2: expected shape (nt, d, d) or (d, d) with d in {{2, 3}}, got {np.shape(a2)}")
    if int(n_particles) < 2:
        raise InputError(f"n_particles: need at least 2, got {n_particles}")
    if int(draws) < 1:
        raise InputError(f"draws: need at least 1, got {draws}")
    d = states.shape[-1]
    L = np.asarray(velocity_gradient, dtype=np.float64)[:d, :d]
    D = 0.5 * (L + L.T)
    rng = np.random.default_rng(seed)
    a2_samples, a4_samples = [], []
    for state in states:
        root = np.linalg.cholesky(acg_covariance(state))
        x = rng.standard_normal((int(draws), int(n_particles), d)) @ root.T
        p = x / np.linalg.norm(x, axis=-1, keepdims=True)
        a2_samples.append(np.einsum("sni,snj->sij", p, p) / n_particles)
        a4_samples.append(np.einsum("sni,snj,snk,snl->sijkl", p, p, p, p) / n_particles)
    a2_n = np.concatenate(a2_samples)
    a4_n = np.concatenate(a4_samples)
    diff_D = np.einsum("sijkl,kl->sij", closure_a4("fec", a2_n) - a4_n, D)
    a4_D = np.einsum("sijkl,kl->sij", a4_n, D)
    err = np.linalg.norm(diff_D.reshape(len(a2_n), -1), axis=1) / np.maximum(
        np.linalg.norm(a4_D.reshape(len(a2_n), -1), axis=1), 1e-300)
    return err.reshape(states.shape[0], int(draws))
