"""Time integration of orientation models with diffrax (single runs and vmapped batches).

The state is the full ``(d, d)`` matrix ``a2``; every model returns a symmetrised
rate, so symmetry is kept to round-off without a reduced parametrisation.
Default integrator: Tsit5 (5th-order explicit Runge-Kutta, Tsitouras 2011) with a
PID step-size controller at ``rtol = 1e-8``, ``atol = 1e-10`` and output at the
requested times (``SaveAt(ts=t_eval)``, dense interpolation of the 5th-order step).
"""
from __future__ import annotations

from typing import Any

import dataclasses

import diffrax
import equinox as eqx
import numpy as np

from pyfold._jax import jax, jnp
from pyfold.errors import ConvergenceError, InputError
from pyfold.kinematics import velocity_gradient
from pyfold.models._base import OrientationModel
from pyfold.tensors import check_orientation_tensor

__all__ = ["OrientationSolution", "solve_orientation", "solve_batch", "status_message", "DEFAULT_MAX_STEPS"]

#: Default cap on solver steps per integration. A shear run to gamma t = 1000 at
#: rtol 1e-8 takes a few thousand Tsit5 steps; the cap only catches runaways.
DEFAULT_MAX_STEPS = 100_000


class OrientationSolution(eqx.Module):
    """Result of :func:`solve_orientation` / :func:`solve_batch`.

    Attributes
    ----------
    t : array (nt,)
        Output times [s] (``t_eval``).
    a2 : array (nt, d, d), or (n, nt, d, d) for a batch
        Orientation tensor at ``t``. After a failure the entries past the failure
        time are not meaningful (diffrax fills them with ``inf``).
    status : int array, () or (n,)
        0 on success, otherwise the diffrax ``RESULTS`` index (e.g. 1 = maximum
        number of steps reached); :func:`status_message` explains it.
    stats : dict
        diffrax statistics: ``num_steps``, ``num_accepted_steps``,
        ``num_rejected_steps``, ``max_steps`` (per member for a batch).
    """

    t: jax.Array
    a2: jax.Array
    status: jax.Array
    stats: dict

    @property
    def success(self) -> jax.Array:
        return self.status == 0


def status_message(status: int) -> str:
    """Human-readable meaning of a status code (diffrax ``RESULTS`` index)."""
    status = int(status)
    if status == 0:
        return "success"
    for item in _RESULT_ITEMS:
        if int(item._value) == status:
            return diffrax.RESULTS[item]
    return f"unknown diffrax status {status}"


_RESULT_ITEMS = tuple(
    getattr(diffrax.RESULTS, name)
    for name in ("successful", "max_steps_reached", "singular", "breakdown", "diverged")
    if hasattr(diffrax.RESULTS, name)
)


def _check_times(t_eval) -> jax.Array:
    if isinstance(t_eval, jax.core.Tracer):  # under jit/grad: only the shape can be checked
        if t_eval.ndim != 1 or t_eval.shape[0] < 2:
            raise InputError(f"t_eval: expected a 1-D array of at least 2 times, got shape {t_eval.shape}")
        return t_eval
    t = np.asarray(t_eval, dtype=np.float64)
    if t.ndim != 1 or t.size < 2:
        raise InputError(f"t_eval: expected a 1-D array of at least 2 times (t_eval[0] = initial time), got shape {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
        raise InputError("t_eval: times must be finite and strictly increasing")
    return jnp.asarray(t)


def _check_tolerances(rtol, atol, max_steps) -> None:
    if not (0.0 < float(rtol) < 1.0) or not (0.0 < float(atol) < 1.0):
        raise InputError(f"rtol, atol: must be in (0, 1), got rtol={rtol!r}, atol={atol!r}")
    if int(max_steps) < 1:
        raise InputError(f"max_steps: must be a positive integer, got {max_steps!r}")


def _integrate(model, a2_0, L, t_eval, rtol, atol, solver, max_steps, adjoint=None):
    """One diffrax solve (traceable; never throws): the only place pyfold calls
    ``diffeqsolve`` for orientation models. ``adjoint=None`` is diffrax' default
    checkpointed adjoint (reverse mode); fitting passes ``diffrax.ForwardMode()``,
    because a Jacobian with few parameters and many residuals wants JVPs."""

    def vector_field(t, a2, args):
        return model.rate(t, a2, L(t))

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(vector_field),
        solver,
        t0=t_eval[0],
        t1=t_eval[-1],
        dt0=None,
        y0=a2_0,
        saveat=diffrax.SaveAt(ts=t_eval),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        max_steps=max_steps,
        adjoint=diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint,
        throw=False,
    )
    status = jnp.asarray(sol.result._value, dtype=jnp.int32)
    stats = {k: jnp.asarray(sol.stats[k]) for k in ("num_steps", "num_accepted_steps", "num_rejected_steps", "max_steps")}
    return sol.ys, status, stats


@eqx.filter_jit
def _integrate_jit(model, a2_0, L, t_eval, rtol, atol, solver, max_steps):
    return _integrate(model, a2_0, L, t_eval, rtol, atol, solver, max_steps)


def _initial_state(a2_0, dim: int, name: str = "a2_0") -> jax.Array:
    if isinstance(a2_0, jax.core.Tracer):
        if a2_0.shape[-2:] != (dim, dim):
            raise InputError(f"{name}: expected shape (..., {dim}, {dim}), got {a2_0.shape}")
        return a2_0
    arr = check_orientation_tensor(a2_0, name=name, tol=1e-8)
    if arr.shape[-1] != dim:
        raise InputError(f"{name}: the model has dim = {dim}, got a2 of shape {arr.shape}")
    return jnp.asarray(arr)


def _check_model(model) -> None:
    if not isinstance(model, OrientationModel):
        raise InputError(f"model: expected a pyfold.models orientation model, got {type(model).__name__}")


def solve_orientation(
    model: OrientationModel,
    a2_0,
    L,
    t_eval,
    *,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    solver: Any = None,
    max_steps: int = DEFAULT_MAX_STEPS,
    throw: bool = True,
) -> OrientationSolution:
    """Integrate ``da2/dt = model.rate(t, a2, L(t))`` from ``t_eval[0]``.

    Parameters
    ----------
    model : OrientationModel
        E.g. ``FolgarTucker(ci=0.01, closure="ibof")``.
    a2_0 : array (d, d)
        Initial orientation tensor (validated: symmetric, unit trace, PSD).
    L : array (d, d) or callable ``L(t)``
        Velocity gradient ``du_i/dx_j`` [1/s] (see :func:`pyfold.kinematics.velocity_gradient`).
    t_eval : array (nt,)
        Output times [s], strictly increasing; ``t_eval[0]`` is the initial time.
    rtol, atol : float
        Tolerances of the PID step-size controller.
    solver : diffrax solver, optional
        Default ``diffrax.Tsit5()``; ``diffrax.Dopri8()`` for very tight tolerances.
    max_steps : int
        Cap on the number of steps.
    throw : bool
        If True, a failed integration raises :class:`pyfold.errors.ConvergenceError`
        (a runtime error from ``equinox.error_if`` when called under a JAX
        transformation); if False, inspect ``status``.

    Returns
    -------
    OrientationSolution

    Raises
    ------
    InputError
        Invalid ``a2_0``, ``L``, ``t_eval`` or tolerances.
    ConvergenceError
        ``throw=True`` and the solver failed (e.g. ``max_steps`` reached).
    """
    _check_model(model)
    _check_tolerances(rtol, atol, max_steps)
    t = _check_times(t_eval)
    a2_0 = _initial_state(a2_0, model.dim)
    grad = velocity_gradient(L, dim=model.dim)
    solver = diffrax.Tsit5() if solver is None else solver
    ys, status, stats = _integrate_jit(model, a2_0, grad, t, float(rtol), float(atol), solver, int(max_steps))
    if throw:
        if isinstance(status, jax.core.Tracer):
            ys = eqx.error_if(ys, status != 0, "solve_orientation: the ODE solver failed (status != 0)")
        elif int(status) != 0:
            raise ConvergenceError(
                f"solve_orientation: {status_message(int(status))} (status {int(status)}, "
                f"{int(stats['num_steps'])} steps, max_steps={int(max_steps)}, rtol={rtol}, atol={atol})"
            )
    return OrientationSolution(t=t, a2=ys, status=status, stats=stats)


def _batched_axes(model) -> Any:
    return jax.tree_util.tree_map(lambda x: 0 if (eqx.is_array(x) and x.ndim > 0) else None, model)


def solve_batch(
    model_batch_or_params,
    a2_0_batch,
    L,
    t_eval,
    *,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    solver: Any = None,
    max_steps: int = DEFAULT_MAX_STEPS,
) -> OrientationSolution:
    """Integrate a batch of models and/or initial states in one vmapped solve.

    Parameters
    ----------
    model_batch_or_params : OrientationModel or (OrientationModel, dict)
        Either a model whose parameter fields carry a leading batch axis
        (e.g. ``FolgarTucker(ci=jnp.array([0.01, 0.02]))``), or a pair
        ``(model, {"ci": values, ...})`` whose values (1-D, one per member)
        replace the named parameters.
    a2_0_batch : array (n, d, d) or (d, d)
        Initial states, one per member, or one shared by all.
    L, t_eval, rtol, atol, solver, max_steps
        As in :func:`solve_orientation`; ``L`` and ``t_eval`` are shared.

    Returns
    -------
    OrientationSolution
        ``a2`` (n, nt, d, d), ``status`` (n,), ``stats`` values (n,). Solver
        failures are reported per member and never raise (``throw=False``
        semantics); ``max_steps`` applies to each member.

    Raises
    ------
    InputError
        Inconsistent batch sizes, unknown parameter names, invalid inputs.
    """
    if isinstance(model_batch_or_params, tuple):
        if len(model_batch_or_params) != 2 or not isinstance(model_batch_or_params[1], dict):
            raise InputError("model_batch_or_params: expected a model or a pair (model, {name: values})")
        base, params = model_batch_or_params
        _check_model(base)
        names = {f.name for f in dataclasses.fields(base)}
        for key, values in params.items():
            if key not in names or key in ("closure", "dim"):
                raise InputError(f"params: {key!r} is not a parameter of {type(base).__name__}; allowed: "
                                 f"{', '.join(sorted(names - {'closure', 'dim'}))}")
            if np.ndim(values) != 1:
                raise InputError(f"params[{key!r}]: expected a 1-D array (one value per member), got shape {np.shape(values)}")
        model = dataclasses.replace(base, **{k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()})
    else:
        model = model_batch_or_params
        _check_model(model)
    _check_tolerances(rtol, atol, max_steps)
    t = _check_times(t_eval)

    model_axes = _batched_axes(model)
    sizes = {int(x.shape[0]) for x in jax.tree_util.tree_leaves(model) if eqx.is_array(x) and x.ndim > 0}
    a2_0 = np.asarray(a2_0_batch, dtype=np.float64)
    d = model.dim
    if a2_0.ndim == 3:
        sizes.add(a2_0.shape[0])
        a2_axis = 0
    elif a2_0.ndim == 2:
        a2_axis = None
    else:
        raise InputError(f"a2_0_batch: expected shape (n, {d}, {d}) or ({d}, {d}), got {a2_0.shape}")
    if len(sizes) != 1:
        raise InputError(
            "solve_batch: need exactly one batch size across batched parameters and initial states, "
            f"got sizes {sorted(sizes) or 'none (nothing is batched)'}"
        )
    a2_0 = _initial_state(a2_0, d, name="a2_0_batch")
    grad = velocity_gradient(L, dim=d)
    solver = diffrax.Tsit5() if solver is None else solver
    ys, status, stats = _batch_jit(model, model_axes, a2_0, a2_axis, grad, t, float(rtol), float(atol), solver, int(max_steps))
    return OrientationSolution(t=t, a2=ys, status=status, stats=stats)


@eqx.filter_jit
def _batch_jit(model, model_axes, a2_0, a2_axis, L, t_eval, rtol, atol, solver, max_steps):
    def one(m, a0):
        return _integrate(m, a0, L, t_eval, rtol, atol, solver, max_steps)

    return eqx.filter_vmap(one, in_axes=(model_axes, a2_axis))(model, a2_0)
