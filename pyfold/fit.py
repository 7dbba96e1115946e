"""Fitting orientation-model parameters (C_I, ...) to a measured ``a2(t)``.

The question a direct simulation answers for a moulding code is: which value of
the interaction coefficient ``C_I`` (and of the other parameters of an
orientation model) makes the macroscopic equation reproduce the ``a2(t)`` the
fibres actually produced? :func:`fit_parameters` answers it by weighted
non-linear least squares

    min_theta  sum_k sum_{i<=j} w_kij (a_ij^model(t_k; theta) - a_ij^data(t_k))^2 ,

where ``a^model`` is the solution of the model's orientation equation from the
measured initial state (``pyfold.models.solve_orientation``, diffrax), and the
Jacobian with respect to ``theta`` is obtained by forward-mode automatic
differentiation *through* the ODE solve (``diffrax.ForwardMode``). The optimiser
is optimistix' Levenberg--Marquardt (Levenberg 1944; Marquardt 1963).

Bounds (``C_I >= 0``, ``0 < kappa <= 1``, ...) are imposed by the variable
transforms of MINUIT (James & Roos 1975, Comput. Phys. Commun. 10:343):

* lower bound only:  ``x = lo - 1 + sqrt(u^2 + 1)``
* upper bound only:  ``x = hi + 1 - sqrt(u^2 + 1)``
* both bounds:       ``x = lo + (hi - lo) (sin u + 1) / 2``

so the optimiser works on an unconstrained ``u``. Near a bound ``x - lo ~ u^2/2``
is flat in ``u``: when the unconstrained optimum lies beyond the bound (e.g.
``C_I = 0`` for a dilute, purely Jeffery population) the iterates creep towards
it. A value that ends within 1e-6 (relative) of its bound with the loss
gradient pointing out of the feasible set (the Karush--Kuhn--Tucker condition of
an active bound) is then placed exactly on the bound, and the fit counts as
converged if the free parameters pass a first-order test. Standard errors are computed in the
physical variables from the Jacobian at the optimum (Bard 1974, *Nonlinear
Parameter Estimation*, ch. 7):

    cov = s^2 (J^T J)^{-1},   s^2 = RSS / (n - p),

which assumes independent residuals of equal variance (after weighting); for a
parameter sitting on its bound the linearised error is only indicative.

The steady-state fit of Tucker's *Fiber Orientation Tools* (``fitCI.m``; Tucker
2022, *Fundamentals of Fiber Orientation*, Hanser, sec. 5.3) is
:func:`fit_ci_to_steady_a11`.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, Mapping, Sequence

import diffrax
import equinox as eqx
import numpy as np
import optimistix as optx
import scipy.optimize
import xarray as xr

from pyfold._jax import jax, jnp
from pyfold.closures import TabulatedA4
from pyfold.errors import InputError
from pyfold.kinematics import velocity_gradient
from pyfold.models import FolgarTucker, solve_orientation
from pyfold.models.solve import _integrate
from pyfold.tensors import check_orientation_tensor

__all__ = [
    "FitResult",
    "DEFAULT_BOUNDS",
    "fit_parameters",
    "synthetic_dataset",
    "validate_dataset",
    "steady_state_a2",
    "fit_ci_to_steady_a11",
]

#: Physical ranges used when ``bounds`` does not name a parameter. ``C_I`` is a
#: diffusivity (>= 0); RSC's ``kappa`` a slow-down factor in (0, 1] (Wang,
#: O'Gara & Tucker 2008, J. Rheol. 52:1179); iARD's ``cm`` in [0, 1] and pARD's
#: ``omega`` in [0, 1] (Tseng, Chang & Hsu 2016-2017); ``xi`` = lambda in [-1, 1].
DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "ci": (0.0, math.inf),
    "kappa": (0.0, 1.0),
    "cm": (0.0, 1.0),
    "omega": (0.0, 1.0),
    "xi": (-1.0, 1.0),
}

#: Residual assigned to every component when the ODE solve fails for a trial
#: parameter (e.g. a negative diffusivity blowing up): large enough for the
#: trust region to reject the step, finite so that the optimiser carries on.
_FAILED_RESIDUAL = 1.0e3

#: Relative distance from a bound at which an initial value sitting exactly on it
#: is placed: the transforms have a zero derivative on the bound itself.
_NUDGE = 1.0e-2

#: A value this close (relative) to a bound is a candidate for the active set.
_PIN_TOL = 1.0e-6

#: First-order optimality of the free parameters when the optimiser stopped on
#: max_steps with a bound active: Gauss-Newton step below this, relative.
_STEP_TOL = 1.0e-6

_SECONDS = {"s", "second", "seconds", "sec"}


# --------------------------------------------------------------------------- result


@dataclasses.dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_parameters`.

    Attributes
    ----------
    values : dict
        Best-fit value of each fitted parameter.
    stderr : dict
        Linearised standard error of each value, ``sqrt(diag(s^2 (J^T J)^-1))``.
    residual_rms : float
        ``sqrt(RSS / n)`` of the (weighted) residuals [dimensionless].
    n_points : int
        Number of residuals ``n`` (independent components times sample times,
        the initial time excluded).
    success : bool
        Optimiser converged, the ODE solve succeeded at the optimum and its a2 stays
        in the orientation tensors (else ``values`` and ``stderr`` are NaN and
        ``message`` says where a2 left them and why).
    message : str
        Human-readable outcome.
    closure : str
        Closure used (a name, ``"exact"`` for the tabulated a4, or a callable's name).
    covariance : numpy.ndarray
        ``(p, p)`` covariance in the order of ``params``.
    at_bound : dict
        Whether each parameter was put on an active bound (see module notes).
    n_steps : int
        Levenberg--Marquardt iterations.
    model : object
        The model with the fitted values substituted.
    """

    values: dict[str, float]
    stderr: dict[str, float]
    residual_rms: float
    n_points: int
    success: bool
    message: str
    closure: str
    covariance: np.ndarray
    at_bound: dict[str, bool]
    n_steps: int
    model: Any = dataclasses.field(repr=False)


# --------------------------------------------------------------------------- data


def validate_dataset(
    data: xr.Dataset, dim: int | None = None, need_a4: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Check a measured orientation history and return ``(t, a2, a4)`` as numpy arrays.

    Parameters
    ----------
    data : xarray.Dataset
        Variable ``a2`` with dims ``(time, i, j)``; optional ``a4`` with dims
        ``(time, i, j, k, l)``; coordinate ``time`` in seconds, strictly increasing.
    dim : int, optional
        Spatial dimension the model expects (2 or 3).
    need_a4 : bool
        Require ``a4`` (for ``closure="exact"``).

    Raises
    ------
    InputError
        Naming the variable at fault: missing ``a2``/``a4``/``time``, wrong dims or
        sizes, non-seconds time units, non-monotonic time, NaN or infinity, or an
        initial ``a2`` that is not an orientation tensor.
    """
    if not isinstance(data, xr.Dataset):
        raise InputError(
            f"data: expected an xarray.Dataset with variable a2(time, i, j), got {type(data).__name__}"
        )
    if "a2" not in data.data_vars:
        raise InputError(
            f"data: missing variable 'a2' with dims (time, i, j); found {sorted(map(str, data.data_vars))}"
        )
    a2 = data["a2"]
    if a2.dims != ("time", "i", "j"):
        raise InputError(f"data['a2']: dims must be ('time', 'i', 'j'), got {a2.dims}")
    d = a2.sizes["i"]
    if a2.sizes["j"] != d or d not in (2, 3):
        raise InputError(f"data['a2']: spatial sizes must be equal and in {{2, 3}}, got {a2.shape[1:]}")
    if dim is not None and d != dim:
        raise InputError(f"data['a2']: spatial size {d} does not match the model's dim = {dim}")
    if "time" not in data.coords:
        raise InputError("data: missing coordinate 'time' [s]")
    time = data["time"]
    if not np.issubdtype(time.dtype, np.number):
        raise InputError(f"data['time']: must be numeric seconds, got dtype {time.dtype}")
    units = str(time.attrs.get("units", "s")).strip().lower()
    if units not in _SECONDS:
        raise InputError(f"data['time']: units must be seconds ('s'), got {time.attrs['units']!r}")
    t = np.asarray(time.values, dtype=np.float64)
    if t.size < 2:
        raise InputError(f"data['time']: need at least 2 samples, got {t.size}")
    if not np.all(np.isfinite(t)):
        raise InputError("data['time']: contains NaN or infinity")
    if np.any(np.diff(t) <= 0.0):
        k = int(np.argmax(np.diff(t) <= 0.0))
        raise InputError(
            f"data['time']: must be strictly increasing; time[{k + 1}] = {t[k + 1]!r} <= time[{k}] = {t[k]!r}"
        )
    a2v = np.asarray(a2.values, dtype=np.float64)
    bad = ~np.isfinite(a2v).reshape(t.size, -1).all(axis=1)
    if bad.any():
        raise InputError(f"data['a2']: contains NaN or infinity (first at time index {int(np.argmax(bad))})")
    check_orientation_tensor(a2v[0], name="data['a2'] at the initial time", tol=1e-6)
    a4v = None
    if need_a4:
        if "a4" not in data.data_vars:
            raise InputError("data: closure='exact' needs variable 'a4' with dims (time, i, j, k, l)")
        a4 = data["a4"]
        if a4.dims != ("time", "i", "j", "k", "l") or a4.shape[1:] != (d,) * 4:
            raise InputError(
                f"data['a4']: expected dims ('time', 'i', 'j', 'k', 'l') and shape (nt, {d}, {d}, {d}, {d}), "
                f"got dims {a4.dims} and shape {a4.shape}"
            )
        a4v = np.asarray(a4.values, dtype=np.float64)
        if not np.all(np.isfinite(a4v)):
            raise InputError("data['a4']: contains NaN or infinity")
    return t, a2v, a4v


def _velocity_gradient(L, data: xr.Dataset, d: int):
    if L is None:
        if "velocity_gradient" not in data.attrs:
            raise InputError(
                "L: velocity gradient required (a (d, d) array or a callable L(t)); "
                "data has no 'velocity_gradient' attribute to default to"
            )
        L = np.asarray(data.attrs["velocity_gradient"], dtype=np.float64).reshape(d, d)
    return velocity_gradient(L, dim=d)


def _weights(weights, nt: int, d: int) -> np.ndarray:
    if weights is None:
        return np.ones((nt, d, d))
    w = np.asarray(getattr(weights, "values", weights), dtype=np.float64)
    if w.ndim == 1 and w.shape[0] == nt:
        w = w[:, None, None]
    try:
        w = np.broadcast_to(w, (nt, d, d)).copy()
    except ValueError:
        raise InputError(
            f"weights: must broadcast to (time={nt}, {d}, {d}) or be one weight per time, got shape {w.shape}"
        ) from None
    if not np.all(np.isfinite(w)) or np.any(w < 0.0):
        raise InputError("weights: must be finite and >= 0")
    if not np.any(w[1:] > 0.0):
        raise InputError("weights: all zero after the initial time; nothing to fit")
    return w


# --------------------------------------------------------------------------- transforms


def _to_internal(x: float, lo: float, hi: float) -> float:
    if math.isinf(lo) and math.isinf(hi):
        return x
    if math.isinf(hi):
        return math.sqrt((x - lo + 1.0) ** 2 - 1.0)
    if math.isinf(lo):
        return math.sqrt((hi - x + 1.0) ** 2 - 1.0)
    return math.asin(min(1.0, max(-1.0, 2.0 * (x - lo) / (hi - lo) - 1.0)))


def _to_external(u, lo: float, hi: float):
    if math.isinf(lo) and math.isinf(hi):
        return u
    if math.isinf(hi):
        return lo - 1.0 + jnp.sqrt(u * u + 1.0)
    if math.isinf(lo):
        return hi + 1.0 - jnp.sqrt(u * u + 1.0)
    return lo + 0.5 * (hi - lo) * (jnp.sin(u) + 1.0)


def _nudged_inside(x: float, lo: float, hi: float) -> float:
    """Move a start value off a bound (the transforms are flat there)."""
    if math.isfinite(lo) and math.isfinite(hi):
        width = hi - lo
        return min(max(x, lo + _NUDGE * width), hi - _NUDGE * width)
    if math.isfinite(lo) and x <= lo:
        return lo + _NUDGE * max(1.0, abs(lo))
    if math.isfinite(hi) and x >= hi:
        return hi - _NUDGE * max(1.0, abs(hi))
    return x


# --------------------------------------------------------------------------- problem


def _forward_mode_solve(model, a2_0, L, t, rtol: float, atol: float, max_steps: int):
    """The solve of :func:`pyfold.models.solve_orientation` (Tsit5, PID controller,
    output at ``t``) in forward mode.

    Why forward mode: a fit has 1-3 parameters and hundreds of residuals, so the
    Jacobian wants p JVPs rather than n VJPs: measured on FT/IBOF, 41 samples,
    9 s to compile and 8 ms per Jacobian, against ~60 s and ~1.7 s in reverse mode.
    """
    ys, status, stats = _integrate(model, a2_0, L, t, rtol, atol, diffrax.Tsit5(), max_steps,
                                   adjoint=diffrax.ForwardMode())
    return ys, status, stats["num_accepted_steps"]


class _Problem(eqx.Module):
    """Residual of one fit; a pytree so that one compiled solve serves every call
    with the same model structure, closure and array shapes."""

    model: Any
    a2_0: jax.Array
    target: jax.Array  # (nt - 1, m) observed independent components
    sqrt_w: jax.Array  # (nt - 1, m)
    L: Any  # a pyfold.kinematics gradient Module (validated outside jit)
    t: jax.Array
    names: tuple[str, ...] = eqx.field(static=True)
    lower: tuple[float, ...] = eqx.field(static=True)
    upper: tuple[float, ...] = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    atol: float = eqx.field(static=True)
    max_ode_steps: int = eqx.field(static=True)

    def external(self, u: jax.Array) -> jax.Array:
        return jnp.stack([_to_external(u[k], lo, hi) for k, (lo, hi) in enumerate(zip(self.lower, self.upper))])

    def model_at(self, values: jax.Array):
        names = self.names
        return eqx.tree_at(lambda m: [getattr(m, n) for n in names], self.model, [values[k] for k in range(len(names))])

    def solve(self, values: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``(a2(t), status, accepted steps)`` for the parameter values, forward-mode differentiable."""
        return _forward_mode_solve(
            self.model_at(values), self.a2_0, self.L, self.t, self.rtol, self.atol, self.max_ode_steps
        )

    def residuals(self, values: jax.Array) -> jax.Array:
        return self.residuals_from(*self.solve(values)[:2])

    def residuals_from(self, a2: jax.Array, status: jax.Array) -> jax.Array:
        d = self.a2_0.shape[-1]
        iu, ju = np.triu_indices(d)
        r = (a2[1:, iu, ju] - self.target) * self.sqrt_w
        ok = (status == 0) & jnp.all(jnp.isfinite(r))
        return jnp.where(ok, r, _FAILED_RESIDUAL).ravel()


@eqx.filter_jit
def _least_squares(problem: _Problem, u0: jax.Array, rtol: float, atol: float, max_steps: int):
    """Levenberg--Marquardt in the internal variables, then residuals, Jacobian (in the
    physical variables, for the covariance) and ODE status at the optimum: one
    compiled program per problem structure."""
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(
        lambda u, p: p.residuals(p.external(u)),
        solver,
        u0,
        args=problem,
        max_steps=max_steps,
        throw=False,
        options={"jac": "fwd"},
    )
    values = problem.external(sol.value)

    def with_status(v):
        a2, status, accepted = problem.solve(v)
        r = problem.residuals_from(a2, status)
        return r, (r, status, a2, accepted)

    J, (r, status, a2, accepted) = jax.jacfwd(with_status, has_aux=True)(values)
    return values, sol.result, sol.stats["num_steps"], r, J, status, a2, accepted


def _scalar_parameters(model) -> list[str]:
    """Names of a model's scalar float parameters (static fields such as ``dim``
    and the closure excluded)."""
    names = []
    for f in dataclasses.fields(model):
        v = getattr(model, f.name)
        if f.metadata.get("static", False) or isinstance(v, (bool, int, str)):
            continue
        if isinstance(v, float) or (hasattr(v, "shape") and hasattr(v, "dtype") and np.shape(v) == ()):
            names.append(f.name)
    return sorted(names)


def _closure_label(closure) -> str:
    if isinstance(closure, TabulatedA4):
        return "exact"
    if isinstance(closure, str):
        return closure.strip().lower()
    inner = getattr(closure, "name", None) or getattr(getattr(closure, "fn", None), "__name__", None)
    return str(inner or getattr(closure, "__name__", type(closure).__name__))


def fit_parameters(
    data: xr.Dataset,
    model,
    params: Sequence[str] = ("ci",),
    L=None,
    *,
    closure=None,
    bounds: Mapping[str, tuple[float | None, float | None]] | None = None,
    weights=None,
    initial: Mapping[str, float] | None = None,
    a2_0=None,
    rtol: float = 1e-9,
    atol: float = 1e-11,
    fit_rtol: float = 1e-10,
    fit_atol: float = 1e-9,
    max_steps: int = 100,
    max_ode_steps: int = 100_000,
) -> FitResult:
    """Least-squares fit of orientation-model parameters to a measured ``a2(t)``.

    Minimises ``sum_k sum_{i<=j} w_kij (a_ij(t_k; theta) - a_ij^data(t_k))^2`` over
    the sample times after the first, ``a(t; theta)`` being the solution of the
    model's orientation equation started from the measured initial state. See the
    module docstring for the method, bounds and standard errors.

    Parameters
    ----------
    data : xarray.Dataset
        ``a2(time, i, j)`` (and ``a4(time, i, j, k, l)`` for ``closure="exact"``),
        ``time`` in seconds, strictly increasing (see :func:`validate_dataset`).
    model : equinox.Module
        An orientation model of :mod:`pyfold.models` (e.g. ``FolgarTucker``); its
        current field values are the starting point and the fixed values of the
        parameters that are not fitted.
    params : sequence of str
        Names of the float fields to fit, e.g. ``("ci",)`` or ``("ci", "kappa")``.
    L : array (d, d) or callable, optional
        Velocity gradient ``L_ij = du_i/dx_j`` [1/s], constant or ``L(t)``. Defaults
        to ``data.attrs["velocity_gradient"]`` (written by :func:`synthetic_dataset`).
    closure : str, callable or "exact", optional
        Replaces the model's closure; ``"exact"`` feeds the dataset's own ``a4``
        through :func:`pyfold.fast_fit.contracted_table` (a
        :class:`pyfold.closures.TabulatedA4`, cubic Hermite in time, corrected so that
        it contracts to the integrated a2).
    bounds : mapping, optional
        ``name -> (lo, hi)``, ``None`` meaning unbounded; merged over
        :data:`DEFAULT_BOUNDS` (``C_I >= 0``, ``0 <= kappa <= 1``, ...).
    weights : array, optional
        Non-negative weights broadcastable to ``(time, d, d)`` or one per time.
    initial : mapping, optional
        Starting values ``name -> value`` overriding the model's fields.
    a2_0 : array (d, d), optional
        Initial state; defaults to the data at the first time (symmetrised).
    rtol, atol : float
        Tolerances of the ODE solve.
    fit_rtol, fit_atol : float
        Levenberg--Marquardt termination tolerances: stop when both the step in
        the internal variables and the change of every residual are below
        ``fit_atol + fit_rtol * |value|``. ``fit_atol`` must sit above the ODE
        error floor of the residuals (~``rtol``), or steps near a bound, where the
        model is flat, never terminate.
    max_steps : int
        Maximum number of Levenberg--Marquardt iterations.
    max_ode_steps : int
        Maximum number of ODE steps per solve.

    Returns
    -------
    FitResult

    Raises
    ------
    InputError
        Invalid data (see :func:`validate_dataset`), unknown parameter names, a
        start value outside its bounds, inconsistent bounds or weights.
    """
    fields = {f.name for f in dataclasses.fields(model)} if dataclasses.is_dataclass(model) else set()
    if not fields:
        raise InputError(f"model: expected an orientation model (equinox Module), got {type(model).__name__}")
    params = tuple(params) if not isinstance(params, str) else (params,)
    if not params:
        raise InputError("params: name at least one parameter to fit")
    scalar_fields = _scalar_parameters(model)
    for name in params:
        if name not in scalar_fields:
            raise InputError(f"params: {name!r} is not a scalar parameter of {type(model).__name__}; allowed: {scalar_fields}")
    if len(set(params)) != len(params):
        raise InputError(f"params: repeated names in {params}")

    if closure is not None:
        if isinstance(closure, str) and closure.strip().lower() == "exact":
            closure = "exact"
        elif not isinstance(closure, TabulatedA4):
            from pyfold.closures import resolve

            resolve(closure)  # validates the name now, with the list of allowed names
    dim = int(getattr(model, "dim", 3))
    t, a2v, a4v = validate_dataset(data, dim=dim, need_a4=closure == "exact")
    d = a2v.shape[-1]
    if closure == "exact":
        # corrected to contract to the integrated a2, so that tr a2 stays 1
        # (pyfold.fast_fit, module notes)
        from pyfold.fast_fit import contracted_table

        closure = contracted_table(t, a4v)
    if closure is not None:
        model = dataclasses.replace(model, closure=closure)
    Lv = _velocity_gradient(L, data, d)
    w = _weights(weights, t.size, d)

    if a2_0 is None:
        a2_0 = 0.5 * (a2v[0] + a2v[0].T)
    a2_0 = check_orientation_tensor(a2_0, name="a2_0", tol=1e-6)
    if a2_0.shape != (d, d):
        raise InputError(f"a2_0: expected shape ({d}, {d}), got {a2_0.shape}")

    merged = dict(DEFAULT_BOUNDS)
    for name, pair in (bounds or {}).items():
        if name not in params:
            raise InputError(f"bounds: {name!r} is not among the fitted params {params}")
        try:
            lo, hi = pair
        except (TypeError, ValueError):
            raise InputError(f"bounds[{name!r}]: expected a pair (lo, hi), got {pair!r}") from None
        merged[name] = (-math.inf if lo is None else float(lo), math.inf if hi is None else float(hi))
    lower = tuple(merged.get(n, (-math.inf, math.inf))[0] for n in params)
    upper = tuple(merged.get(n, (-math.inf, math.inf))[1] for n in params)
    start = []
    for n, lo, hi in zip(params, lower, upper):
        if not lo < hi:
            raise InputError(f"bounds[{n!r}]: need lo < hi, got ({lo}, {hi})")
        x0 = float((initial or {}).get(n, getattr(model, n)))
        if not (lo <= x0 <= hi) or not math.isfinite(x0):
            raise InputError(f"initial value of {n!r} = {x0!r} lies outside its bounds [{lo}, {hi}]")
        start.append(_nudged_inside(x0, lo, hi))
    unknown_initial = set(initial or {}) - set(params)
    if unknown_initial:
        raise InputError(f"initial: {sorted(unknown_initial)} are not among the fitted params {params}")

    iu, ju = np.triu_indices(d)
    # Fitted fields become 0-d arrays so that they are traced (not baked into the
    # compiled code): one compilation serves any start value.
    model = eqx.tree_at(lambda m: [getattr(m, n) for n in params], model, [jnp.asarray(x) for x in start])
    problem = _Problem(
        model=model,
        t=jnp.asarray(t),
        a2_0=jnp.asarray(a2_0),
        target=jnp.asarray(a2v[1:, iu, ju]),
        sqrt_w=jnp.asarray(np.sqrt(w[1:, iu, ju])),
        L=Lv,
        names=params,
        lower=lower,
        upper=upper,
        rtol=float(rtol),
        atol=float(atol),
        max_ode_steps=int(max_ode_steps),
    )
    u0 = jnp.asarray([_to_internal(x, lo, hi) for x, lo, hi in zip(start, lower, upper)])
    values, result, n_steps, r, J, status, a2_fit, accepted = _least_squares(
        problem, u0, float(fit_rtol), float(fit_atol), int(max_steps)
    )
    r, J, values = np.asarray(r), np.asarray(J), np.array(values)
    n, p = r.size, len(params)
    rss = float(r @ r)
    dof = n - p
    jtj = J.T @ J
    if dof > 0 and np.linalg.matrix_rank(jtj) == p:
        cov = rss / dof * np.linalg.inv(jtj)
    else:
        cov = np.full((p, p), np.nan)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if np.all(np.isfinite(cov)) else np.full(p, np.nan)

    # Bounds as an active set (Karush-Kuhn-Tucker). Near a bound the transform is
    # flat, so Levenberg-Marquardt creeps towards it (its damping dominates J^T J
    # ~ u^2) and may stop on max_steps a hair inside. A value within _PIN_TOL of
    # its bound whose loss gradient points out of the feasible set is put on the
    # bound exactly; the remaining (free) parameters must then pass a first-order
    # test: their Gauss-Newton step is below _STEP_TOL relative.
    grad = J.T @ r
    active = np.zeros(p, dtype=bool)
    for k, (v, lo, hi) in enumerate(zip(values, lower, upper)):
        if math.isfinite(lo) and v - lo <= _PIN_TOL * max(1.0, abs(lo)) and grad[k] >= 0.0:
            values[k], active[k] = lo, True
        elif math.isfinite(hi) and hi - v <= _PIN_TOL * max(1.0, abs(hi)) and grad[k] <= 0.0:
            values[k], active[k] = hi, True
    free = ~active
    if free.any():
        step = np.linalg.lstsq(J[:, free], -r, rcond=None)[0]
        free_ok = bool(np.all(np.abs(step) <= _STEP_TOL * np.maximum(np.abs(values[free]), _STEP_TOL)))
    else:
        free_ok = True

    lm_ok = bool(result == optx.RESULTS.successful)
    ode_ok = int(status) == 0
    bounded = ", ".join(f"{name} held on its bound {values[k]:g}" for k, name in enumerate(params) if active[k])
    if not ode_ok:
        message = f"ODE solve failed at the optimum (status {int(status)})"
    elif lm_ok:
        message = f"converged in {int(n_steps)} Levenberg-Marquardt steps"
    elif active.any() and free_ok:
        message = f"converged onto the bound after {int(n_steps)} Levenberg-Marquardt steps"
    else:
        message = f"Levenberg-Marquardt stopped after {int(n_steps)} steps: {optx.RESULTS[result]}"
    if bounded:
        message += f" ({bounded}: the loss increases into the feasible set)"
    if not np.all(np.isfinite(cov)):
        message += "; J^T J singular or n <= p: standard errors undefined"
    success = ode_ok and (lm_ok or (bool(active.any()) and free_ok))
    at_bound = {name: bool(active[k]) for k, name in enumerate(params)}
    fitted = eqx.tree_at(lambda m: [getattr(m, n_) for n_ in params], model, [float(v) for v in values])
    # The trajectory at the optimum must stay in the orientation tensors (the check of
    # pyfold.models.solve_orientation, tolerances from rtol, atol and the accepted
    # steps): else no values are reported (NaN), success is False and the message
    # names the closure, the first sample time and the cause.
    if ode_ok:
        from pyfold.models.solve import _admissibility, _tolerances

        tol_trace, tol_eig = _tolerances(np.asarray(accepted)[None], rtol, atol, d)
        a2_np = np.asarray(a2_fit)[None]
        admissible, _, why = _admissibility(t, a2_np, np.ones(a2_np.shape[:2], dtype=bool), tol_trace, tol_eig)
        if not admissible[0]:
            message = f"closure {_closure_label(fitted.closure)}: {why[0]}; no values reported ({message})"
            success = False
            values = np.full(p, np.nan)
            stderr = np.full(p, np.nan)
    return FitResult(
        values={name: float(v) for name, v in zip(params, values)},
        stderr={name: float(s) for name, s in zip(params, stderr)},
        residual_rms=math.sqrt(rss / n),
        n_points=int(n),
        success=success,
        message=message,
        closure=_closure_label(fitted.closure),
        covariance=cov,
        at_bound=at_bound,
        n_steps=int(n_steps),
        model=fitted,
    )


# --------------------------------------------------------------------------- synthetic data


def _model_description(model) -> str:
    parts = [f"{name}={float(getattr(model, name))!r}" for name in _scalar_parameters(model)]
    return f"{type(model).__name__}({', '.join(parts)}, closure={_closure_label(model.closure)!r})"


def synthetic_dataset(
    model,
    a2_0,
    L,
    times,
    noise: float = 0.0,
    seed: int | None = None,
    *,
    with_a4: bool = False,
    rtol: float = 1e-11,
    atol: float = 1e-13,
) -> xr.Dataset:
    """Orientation history of a model, optionally with Gaussian noise, as a Dataset.

    The clean history is ``pyfold.models.solve_orientation(model, a2_0, L, times)``
    at tight tolerances (so that it can serve as the truth in fitting tests). With
    ``noise > 0``, independent normal errors of standard deviation ``noise`` are
    added to every independent component ``a_ij, i <= j`` (mirrored to keep ``a2``
    symmetric) at every time *after the first*: the initial state of a direct
    simulation is the imposed one, known exactly. The trace is then only 1 on
    average, as for any noisy measurement.

    Parameters
    ----------
    model : orientation model of :mod:`pyfold.models`
    a2_0 : array (d, d)
        Initial orientation tensor.
    L : array (d, d)
        Constant velocity gradient [1/s] (stored in ``attrs["velocity_gradient"]``
        so that :func:`fit_parameters` can default to it); callables are accepted
        and not stored.
    times : array (nt,)
        Sample times [s], strictly increasing; ``times[0]`` is the initial time.
    noise : float
        Standard deviation of the added noise (>= 0).
    seed : int
        Seed of ``numpy.random.default_rng``; required when ``noise > 0``.
    with_a4 : bool
        Also store ``a4(time, i, j, k, l)``, the model's closure evaluated on the
        clean ``a2`` (a consistent "exact" a4 for ``closure="exact"`` fits).

    Returns
    -------
    xarray.Dataset
        ``a2(time, i, j)`` [dimensionless] (and ``a4``), coordinate ``time`` [s],
        with ``units``/``long_name`` attributes and the generating model in ``attrs``.
    """
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError(f"times: expected a finite, strictly increasing 1-D array of >= 2 samples, got shape {t.shape}")
    if not (noise >= 0.0 and math.isfinite(noise)):
        raise InputError(f"noise: must be a finite standard deviation >= 0, got {noise!r}")
    if noise > 0.0 and seed is None:
        raise InputError("seed: an explicit seed is required when noise > 0")
    a2_0 = check_orientation_tensor(a2_0, name="a2_0")
    d = a2_0.shape[-1]
    L_attr = None
    if not callable(L):
        L = np.asarray(L, dtype=np.float64)
        if L.shape != (d, d):
            raise InputError(f"L: expected shape ({d}, {d}), got {L.shape}")
        L_attr = L.ravel().tolist()
        L = jnp.asarray(L)
    sol = solve_orientation(model, jnp.asarray(a2_0), L, jnp.asarray(t), rtol=rtol, atol=atol)
    clean = np.asarray(sol.a2)
    a2 = clean.copy()
    if noise > 0.0:
        rng = np.random.default_rng(seed)
        iu, ju = np.triu_indices(d)
        eps = np.zeros_like(a2)
        eps[1:, iu, ju] = rng.normal(0.0, noise, size=(t.size - 1, iu.size))
        eps[1:, ju, iu] = eps[1:, iu, ju]
        a2 = a2 + eps
    coords = {
        "time": ("time", t, {"units": "s", "long_name": "time"}),
        "i": ("i", np.arange(d), {"long_name": "tensor index i (0 = x, flow direction)"}),
        "j": ("j", np.arange(d), {"long_name": "tensor index j"}),
    }
    data_vars = {
        "a2": (("time", "i", "j"), a2, {"units": "1", "long_name": "second-order orientation tensor a_ij"}),
    }
    if with_a4:
        from pyfold.closures import resolve

        close = resolve(model.closure)
        a4 = np.asarray(jax.vmap(lambda a, s: close(a, s))(jnp.asarray(clean), jnp.asarray(t)))
        coords["k"] = ("k", np.arange(d), {"long_name": "tensor index k"})
        coords["l"] = ("l", np.arange(d), {"long_name": "tensor index l"})
        data_vars["a4"] = (
            ("time", "i", "j", "k", "l"),
            a4,
            {"units": "1", "long_name": "fourth-order orientation tensor a_ijkl (model closure on clean a2)"},
        )
    attrs = {
        "title": "synthetic orientation history",
        "generating_model": _model_description(model),
        "noise_std": float(noise),
        "noise_seed": -1 if seed is None else int(seed),
        "ode_rtol": float(rtol),
        "ode_atol": float(atol),
    }
    if L_attr is not None:
        attrs["velocity_gradient"] = L_attr
    return xr.Dataset(data_vars=data_vars, coords=coords, attrs=attrs)


# --------------------------------------------------------------------------- steady state

#: Margin [dimensionless; eigenvalues of a2 lie in [0, 1]] by which a steady state may
#: leave the orientation tensors before it is reported: the eigenvalues must be
#: >= -_STEADY_MARGIN (else ConvergenceError, as always) and |tr a2 - 1| <=
#: _STEADY_MARGIN (else InadmissibleOrientationWarning: a closure that breaks
#: a4_iikl = a2_kl, such as SQC, has a stationary point off the unit trace). At the
#: default residual tol = 1e-13 the state error is |J^-1| tol, at most ~1e-10 for
#: the slowest relaxation rate considered (C_I gamma_dot ~ 1e-3 gamma_dot), so the
#: margin separates a converged admissible state from a real violation.
_STEADY_MARGIN = 1e-10


def _reduced_indices(d: int) -> tuple[np.ndarray, np.ndarray]:
    # Independent unknowns of a symmetric, unit-trace tensor: the upper triangle
    # without the last diagonal entry (a_dd = 1 - sum of the other diagonals).
    iu, ju = np.triu_indices(d)
    keep = ~((iu == d - 1) & (ju == d - 1))
    return iu[keep], ju[keep]


def _from_reduced(x: jax.Array, d: int) -> jax.Array:
    iu, ju = _reduced_indices(d)
    a = jnp.zeros((d, d), dtype=x.dtype).at[iu, ju].set(x).at[ju, iu].set(x)
    return a.at[d - 1, d - 1].set(1.0 - jnp.trace(a))


def _from_full(x: jax.Array, d: int) -> jax.Array:
    # Independent unknowns of a symmetric tensor of free trace: the upper triangle.
    iu, ju = np.triu_indices(d)
    return jnp.zeros((d, d), dtype=x.dtype).at[iu, ju].set(x).at[ju, iu].set(x)


@eqx.filter_jit
def _steady_state(model, a2_start: jax.Array, L, dt0, tol: float, max_iter: int, unit_trace: bool):
    """Pseudo-transient continuation on the unit-trace components (``unit_trace``,
    d(d+1)/2 - 1 unknowns) or on every independent component (d(d+1)/2 unknowns).

    Returns the state, the *full* residual ``max_ij |da_ij/dt|`` there, and the
    number of steps. ``tol`` is absolute [1/s] (the caller scales it by gamma_dot).
    """
    d = a2_start.shape[-1]
    if unit_trace:
        iu, ju = _reduced_indices(d)
        to_a2 = _from_reduced
    else:
        iu, ju = np.triu_indices(d)
        to_a2 = _from_full
    Lc = L(0.0)

    def residual(x):
        return model.rate(0.0, to_a2(x, d), Lc)[iu, ju]

    eye = jnp.eye(iu.size)
    f0 = jnp.max(jnp.abs(residual(a2_start[iu, ju])))

    def body(carry):
        x, k, _ = carry
        F = residual(x)
        J = jax.jacfwd(residual)(x)
        err = jnp.max(jnp.abs(F))
        # Switched evolution relaxation: the pseudo time step grows as the
        # residual falls, so backward Euler turns into Newton near the state.
        dt = jnp.minimum(dt0 * f0 / jnp.maximum(err, 1e-300), 1e12 * dt0)
        return x + jnp.linalg.solve(eye / dt - J, F), k + 1, err

    def cond(carry):
        _, k, err = carry
        return (k < max_iter) & (err > tol)

    x, k, _ = jax.lax.while_loop(cond, body, (a2_start[iu, ju], 0, jnp.inf))
    a2 = to_a2(x, d)
    full_err = jnp.max(jnp.abs(model.rate(0.0, a2, Lc)))
    return a2, full_err, k


def steady_state_a2(
    model,
    L,
    a2_start=None,
    *,
    tol: float = 1e-13,
    max_iter: int = 500,
) -> np.ndarray:
    """Steady orientation ``a2`` of a model under a constant velocity gradient.

    Solves ``da2/dt = F(a2) = 0`` (``F = model.rate``) by pseudo-transient
    continuation (Kelley & Keyes 1998, SIAM J. Numer. Anal. 35:508):
    backward-Euler steps of the orientation equation from ``a2_start``
    (isotropic by default), ``(I/dt_k - J) dx = F(x_k)``, with the step grown by
    switched evolution relaxation ``dt_k = dt_0 |F_0| / |F_k|`` (``dt_0`` = one
    strain unit). Far from the solution it follows the flow (so it reaches the
    *attracting* state, as the integrate-then-Newton approach of Tucker's
    ``Asteady.m`` does); near it, it is Newton's method.

    **Which components are solved.** The trace obeys ``d(tr a)/dt = tr F(a)``;
    for Folgar--Tucker ``tr F = 2 xi (D:a - a4_iikl D_kl) + 2 d C_I gamma_dot
    (1 - tr a)``. A closure with ``a4_iikl = a_kl`` on the unit-trace tensors
    (every registered closure but SQC, whose contraction is
    ``(a + 2 a.a)/(1 + 2 a:a)``) makes ``tr a = 1`` an invariant manifold, and its
    steady state lies on it. There the trace equation is implied by the others,
    and how the full ``d(d+1)/2``-component Jacobian behaves across the manifold
    depends on how the closure is extended off it: its trace-direction entry is
    ``-2 d C_I gamma_dot`` plus the closure's ``2 xi d(D:a - a4_iikl D_kl)/d(tr a)``,
    which is zero for ``C_I = 0`` and a closure whose contraction is ``a_kl`` at
    any trace, and small for small ``C_I``: Newton on all components would be
    singular or ill-conditioned exactly where it is not needed. pyfold therefore

    1. solves first the ``d(d+1)/2 - 1`` components of a unit-trace tensor
       (``a_dd = 1 - sum`` of the other diagonals: 5 unknowns in 3-D, 2 in 2-D);
    2. checks the *full* residual ``max_ij |F_ij| / gamma_dot`` at that state,
       ``a_dd`` rate and trace rate included. If it is within ``tol``, the trace
       equation was implied and this state is returned (trace-preserving
       closures: the result of step 1, unchanged);
    3. otherwise the trace equation is *not* implied (the closure moves the trace),
       and the continuation is rerun from ``a2_start`` on all ``d(d+1)/2``
       independent components (6 in 3-D, 3 in 2-D). Then the trace is whatever
       the model's stationary point has (SQC: not 1), the one the long-time
       integration (:func:`pyfold.models.solve_orientation`) reaches.

    The returned state always satisfies ``max |da2/dt| <= tol * gamma_dot`` in
    every component.

    Parameters
    ----------
    model : orientation model of :mod:`pyfold.models`
    L : array (d, d)
        Constant velocity gradient [1/s] with shear rate ``gamma_dot =
        sqrt(2 D:D) > 0``.
    a2_start : array (d, d), optional
        Initial orientation tensor of the continuation (default ``I/d``).
    tol : float
        Tolerance on ``max_ij |da_ij/dt| / gamma_dot`` [dimensionless].
    max_iter : int
        Maximum number of pseudo-transient steps (per stage).

    Returns
    -------
    numpy.ndarray (d, d)

    Raises
    ------
    pyfold.errors.ConvergenceError
        No state with full residual ``max |da2/dt| / gamma_dot <= tol`` was
        found in ``max_iter`` steps (the message names the model, its closure and
        ``C_I``, and the residual reached), or the result is not positive
        semi-definite (eigenvalue below ``-1e-10``).

    Warns
    -----
    pyfold.errors.InadmissibleOrientationWarning
        The steady state is the model's fixed point but not an orientation tensor:
        ``|tr a2 - 1| > 1e-10`` (a closure that does not conserve the trace).
    """
    from pyfold.errors import InadmissibleOrientationWarning

    a2, off_trace = _steady_state_checked(model, L, a2_start, tol, max_iter)
    if off_trace:
        warnings.warn(off_trace, InadmissibleOrientationWarning, stacklevel=2)
    return a2


def _steady_state_checked(model, L, a2_start, tol: float, max_iter: int) -> tuple[np.ndarray, str]:
    """:func:`steady_state_a2` without the warning: ``(a2, message)``, the message
    non-empty when the stationary point is off the unit trace."""
    from pyfold.errors import ConvergenceError
    from pyfold.kinematics import shear_rate

    dim = int(getattr(model, "dim", 3))
    if callable(L):
        raise InputError("L: steady_state_a2 needs a constant (d, d) velocity gradient, got a callable")
    L = velocity_gradient(L, dim=dim)
    rate = float(shear_rate(L(0.0)))
    if rate <= 0.0:
        raise InputError("L: steady_state_a2 needs a deforming flow (shear rate > 0)")
    a2_start = jnp.eye(dim) / dim if a2_start is None else jnp.asarray(check_orientation_tensor(a2_start, "a2_start"))
    dt0 = jnp.asarray(1.0 / rate)
    # tol is relative to the rate scale gamma_dot; the loop compares absolute rates.
    tol_abs = float(tol) * rate
    a2, err, k = _steady_state(model, a2_start, L, dt0, tol_abs, int(max_iter), True)
    a2, err = np.asarray(a2), float(err) / rate
    stages = f"{int(k)} steps on the {dim * (dim + 1) // 2 - 1} unit-trace components"
    if not (err <= tol):
        # The trace equation is not implied: solve for every independent component.
        a2, err, k = _steady_state(model, a2_start, L, dt0, tol_abs, int(max_iter), False)
        a2, err = np.asarray(a2), float(err) / rate
        stages += f", then {int(k)} steps on all {dim * (dim + 1) // 2} components (free trace)"
    finite = bool(np.all(np.isfinite(a2)))
    eig = np.linalg.eigvalsh(a2) if finite else np.array([np.nan])
    trace = float(np.trace(a2)) if finite else math.nan
    if not (err <= tol) or not (eig.min() >= -_STEADY_MARGIN):
        why = (
            f"max |da2/dt| / gamma_dot = {err:.3e} > tol {tol:.1e}"
            if not (err <= tol)
            else f"the state is not positive semi-definite (smallest eigenvalue {eig.min():.3e} < -{_STEADY_MARGIN:.0e})"
        )
        raise ConvergenceError(
            f"steady_state_a2: {_model_description(model)}, gamma_dot = {rate:g} 1/s: {why} "
            f"after {stages}; eigenvalues {eig}, tr a2 = {trace:.6g}"
        )
    off_trace = ""
    if abs(trace - 1.0) > _STEADY_MARGIN:
        off_trace = (
            f"steady_state_a2: the stationary point of {_model_description(model)} is not an orientation "
            f"tensor: tr a2 = {trace:.10g} (|tr a2 - 1| > {_STEADY_MARGIN:.0e}); the closure does not "
            "conserve the trace (a4_iikl != a2_kl)"
        )
    return a2, off_trace


def fit_ci_to_steady_a11(
    a11_target: float,
    closure: str = "ibof",
    xi: float = 1.0,
    *,
    bracket: tuple[float, float] = (1e-3, 0.5),
    xtol: float = 1e-12,
) -> float:
    """Interaction coefficient ``C_I`` giving a target steady ``a11`` in simple shear.

    Solves ``a11_ss(C_I) = a11_target`` for the Folgar--Tucker model in simple
    shear ``u = (gamma_dot y, 0, 0)`` (Brent's method on the bracket; ``a11_ss``
    from :func:`steady_state_a2`). This is Tucker's ``fitCI.m`` (Fiber
    Orientation Tools, companion to Tucker 2022, *Fundamentals of Fiber
    Orientation*, Hanser), whose FitCI example uses ``xi = 1``; the 1-3 shear
    plane used there gives the same steady ``a11`` by symmetry.

    Parameters
    ----------
    a11_target : float
        Target steady flow-direction component, in (0.34, 0.99) as in Tucker's tool.
    closure : str
        Closure name (see :func:`pyfold.closures.available`).
    xi : float
        Shape factor ``lambda = (beta^2 - 1)/(beta^2 + 1)``.

    Raises
    ------
    InputError
        Target outside (0.34, 0.99) or not reachable within ``bracket``.
    """
    from pyfold.kinematics import simple_shear

    if not (0.34 < a11_target < 0.99):
        raise InputError(f"a11_target: must lie in (0.34, 0.99) as in Tucker's fitCI, got {a11_target!r}")
    from pyfold.errors import InadmissibleOrientationWarning

    L = np.asarray(simple_shear(1.0, dim=3))
    base = FolgarTucker(ci=0.01, xi=float(xi), closure=closure, dim=3)
    off_trace: list[str] = []

    def a11(ci: float) -> float:
        model = eqx.tree_at(lambda m: m.ci, base, jnp.asarray(ci))
        a2, message = _steady_state_checked(model, L, None, 1e-13, 500)
        if message:
            off_trace.append(message)
        return float(a2[0, 0])

    def warn_once() -> None:
        # One warning per fit rather than one per evaluation of the bracket search.
        if off_trace:
            warnings.warn(
                f"fit_ci_to_steady_a11: closure {closure!r}: steady states off the unit trace "
                f"({len(off_trace)} of the evaluations); last: {off_trace[-1]}",
                InadmissibleOrientationWarning,
                stacklevel=3,
            )

    lo, hi = bracket
    f_lo, f_hi = a11(lo) - a11_target, a11(hi) - a11_target
    if f_lo * f_hi > 0:
        warn_once()
        raise InputError(
            f"a11_target: {a11_target} not reachable with C_I in {bracket} for closure {closure!r} "
            f"(steady a11 spans [{f_hi + a11_target:.4f}, {f_lo + a11_target:.4f}])"
        )
    ci = float(scipy.optimize.brentq(lambda c: a11(c) - a11_target, lo, hi, xtol=xtol, rtol=1e-14))
    warn_once()
    return ci
