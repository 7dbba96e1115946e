"""Time integration of orientation models with diffrax (single runs and vmapped batches).

The state is the full ``(d, d)`` matrix ``a2``; every model returns a symmetrised
rate, so symmetry is kept to round-off without a reduced parametrisation.
Default integrator: Tsit5 (5th-order explicit Runge-Kutta, Tsitouras 2011) with a
PID step-size controller at ``rtol = 1e-8``, ``atol = 1e-10`` and output at the
requested times (``SaveAt(ts=t_eval)``, dense interpolation of the 5th-order step).

After every (concrete, not traced) solve the saved states are checked: a2 leaving
the orientation tensors (trace not 1, negative eigenvalue) beyond what the
integration error allows, and, for models built on the principal axes of a2
(``uses_eigenvectors``), eigenvalue crossings. Findings are recorded on the
:class:`OrientationSolution` and reported by
:class:`pyfold.errors.InadmissibleOrientationWarning` /
:class:`pyfold.errors.EigenvalueCrossingWarning`.
"""
from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import diffrax
import equinox as eqx
import numpy as np

from pyfold._jax import jax, jnp
from pyfold.errors import (
    ConvergenceError,
    EigenvalueCrossingWarning,
    InadmissibleOrientationWarning,
    InputError,
)
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
    admissible : bool, or bool array (n,) for a batch
        Every saved ``a2`` is an orientation tensor to within the integration
        error: ``|tr a2 - 1| <= tol_trace`` and smallest eigenvalue ``>= -tol_eig``
        (both measured from the initial state's own departure), with
        ``tol_eig = 2 N d (atol + rtol)``, ``tol_trace = sqrt(d) tol_eig``, ``N``
        the accepted steps: the bound on the accumulated local error that the
        step-size controller allows (derivation in the source). A closure outside
        its domain (linear: negative eigenvalues; SQC: trace not conserved) makes
        it False, and a :class:`pyfold.errors.InadmissibleOrientationWarning` is
        emitted naming the member, the time and the cause. States after a solver
        failure (``status != 0``) are not checked.
    first_inadmissible_time : float, or array (n,)
        First saved time [s] at which ``a2`` is not admissible; NaN if none.
    admissibility_message : str, or tuple of str (one per member)
        What went wrong, when: the time, the trace and the smallest eigenvalue
        (empty when admissible).
    crossing_time : float, array (n,) or None
        For models built on the principal axes of ``a2`` (``uses_eigenvectors``:
        RSC, ARD-RSC, iARD-RPR, pARD, pARD-RPR, MRD), the first time [s] two
        eigenvalues cross (interpolated between saves), NaN if none; a
        :class:`pyfold.errors.EigenvalueCrossingWarning` is emitted then. ``None``
        for the other models.
    crossing_message : str, tuple of str or None
        Which eigenvalues cross and when (empty when none).

    The diagnostic fields are ``None`` when the solve ran under a JAX
    transformation (``jax.jit``, ``jax.grad``, ...): the check needs concrete
    values (call the solver outside the transformation to get them).
    """

    t: jax.Array
    a2: jax.Array
    status: jax.Array
    stats: dict
    admissible: Any = None
    first_inadmissible_time: Any = None
    admissibility_message: Any = eqx.field(default=None, static=True)
    crossing_time: Any = None
    crossing_message: Any = eqx.field(default=None, static=True)

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


# --------------------------------------------------------------------------- diagnostics
#
# After a solve, the saved states are checked (outside jit, in numpy: a few
# eigen-decompositions of d x d matrices per save) for two things a user must not
# miss: a2 leaving the set of orientation tensors, and, for models built on the
# principal axes of a2, two eigenvalues crossing.
#
# Tolerances, derived from the solver's rtol/atol (never from observed output):
# * diffrax' PID controller accepts a step when the RMS over the d^2 entries of
#   e_ij / (atol + rtol max(|y0_ij|, |y1_ij|)) is below 1, e_ij the embedded error
#   estimate. Entries of an orientation tensor satisfy |a_ij| <= 1, so each scale
#   is <= atol + rtol and the accepted local error has Frobenius norm
#   ||E||_F < sqrt(d^2) (atol + rtol) = d (atol + rtol).
# * By Weyl's inequality an eigenvalue moves by at most ||E||_2 <= ||E||_F; the
#   trace by |tr E| <= sqrt(d) ||E||_F (Cauchy-Schwarz on the diagonal).
# * The global error is at most the sum of the local errors carried by the flow.
#   Orientation dynamics do not amplify perturbations exponentially (Jeffery orbits
#   are neutral, the diffusion terms contract), so it is bounded by N times the
#   local error, N the number of accepted steps; a factor 2 covers the dense
#   interpolation that produces the saved values (an error of the order of the
#   step's own).
# Hence tol_eig = 2 N d (atol + rtol) and tol_trace = 2 N d^(3/2) (atol + rtol):
# beyond them the departure is the model's (its closure's), not the integrator's.
# Both are measured from the initial state's own departure (validation admits
# |tr - 1| and -lambda_min up to 1e-8), which the integrator cannot be blamed for.
# Two eigenvalues, each uncertain by tol_eig, are ordered reliably when their
# difference exceeds 2 tol_eig: that is the gap tolerance of the crossing test.


def _tolerances(num_accepted: np.ndarray, rtol: float, atol: float, d: int) -> tuple[np.ndarray, np.ndarray]:
    """``(tol_trace, tol_eig)`` per member from the accepted steps (see the notes above)."""
    local = d * (float(atol) + float(rtol))
    n = np.maximum(np.asarray(num_accepted, dtype=np.float64), 1.0)
    return 2.0 * n * np.sqrt(d) * local, 2.0 * n * local


def _model_label(model: OrientationModel) -> str:
    closure = getattr(model, "closure", None)
    if isinstance(closure, str):
        label = closure
    else:
        label = getattr(closure, "name", None) or getattr(closure, "__name__", None) or type(closure).__name__
    return f"{type(model).__name__} (closure {label})"


def _admissibility(
    t: np.ndarray, a2: np.ndarray, valid: np.ndarray, tol_trace: np.ndarray, tol_eig: np.ndarray
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """First saved time at which each member leaves the orientation tensors.

    ``a2`` (n, nt, d, d); ``valid`` (n, nt) marks the states to check (finite, or
    non-finite with a solver status of 0). Returns ``(admissible (n,), t_first (n,),
    messages)``.
    """
    n, nt, d = a2.shape[0], a2.shape[1], a2.shape[-1]
    finite = np.isfinite(a2).reshape(n, nt, -1).all(axis=-1)
    safe = np.where(finite[..., None, None], a2, np.eye(d) / d)
    sym = 0.5 * (safe + np.swapaxes(safe, -1, -2))
    trace = np.trace(sym, axis1=-2, axis2=-1)
    lowest = np.linalg.eigvalsh(sym)[..., 0]
    trace_err = np.abs(trace - 1.0)
    base_trace = trace_err[:, :1]
    base_low = np.minimum(lowest[:, :1], 0.0)
    bad_trace = finite & (trace_err > base_trace + tol_trace[:, None])
    bad_psd = finite & (lowest < base_low - tol_eig[:, None])
    bad = valid & (~finite | bad_trace | bad_psd)
    admissible = ~bad.any(axis=1)
    t_first = np.full(n, np.nan)
    messages = []
    for m in range(n):
        if admissible[m]:
            messages.append("")
            continue
        k = int(np.argmax(bad[m]))
        t_first[m] = t[k]
        if not finite[m, k]:
            cause = "the state is not finite (NaN or infinity) although the solver reported success"
        else:
            causes = []
            if bad_trace[m, k]:
                allowed = base_trace[m, 0] + tol_trace[m]
                causes.append(f"trace not conserved (|tr a2 - 1| = {trace_err[m, k]:.3e} > {allowed:.1e})")
            if bad_psd[m, k]:
                allowed = base_low[m, 0] - tol_eig[m]
                causes.append(f"not positive semi-definite (smallest eigenvalue {lowest[m, k]:.3e} < {allowed:.1e})")
            cause = " and ".join(causes) + f"; tr a2 = {trace[m, k]:.10g}, smallest eigenvalue {lowest[m, k]:.3e}"
        messages.append(f"a2 leaves the orientation tensors at t = {t[k]:.6g} s (first saved time): {cause}")
    return admissible, t_first, messages


def _crossings(
    t: np.ndarray, a2: np.ndarray, valid: np.ndarray, tol_gap: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First eigenvalue crossing of each member, from the saved states.

    Each adjacent pair (p, p+1) of eigenvalues (descending order) is followed by
    continuity: its two eigenvectors ``u, v`` at the last save where the pair was
    resolved (gap > ``tol_gap``) are the reference; at every later save the
    eigenvalues of those branches are estimated by the Rayleigh quotients
    ``u.a.u`` and ``v.a.v`` (first-order perturbation theory, exact when the axes
    do not turn). A branch order reversed by more than ``tol_gap`` is a crossing;
    its time is interpolated linearly in the branch difference between the two
    saves. A pair never resolved (a degeneracy, e.g. an isotropic start) has no
    reference, so a degeneracy present at ``t[0]`` that only splits is not a
    crossing. Assumes the saves resolve the rotation of the principal axes (less
    than 45 degrees between saves); a faster rotation aliases as a swap.

    Returns ``(t_cross (n,), pair (n,), count (n,))``, NaN / -1 / 0 where none.
    """
    n, nt, d = a2.shape[0], a2.shape[1], a2.shape[-1]
    finite = np.isfinite(a2).reshape(n, nt, -1).all(axis=-1)
    ok = valid & finite
    safe = np.where(ok[..., None, None], a2, np.eye(d) / d)
    sym = 0.5 * (safe + np.swapaxes(safe, -1, -2))
    lam, vec = np.linalg.eigh(sym)
    lam, vec = lam[..., ::-1], vec[..., ::-1]  # descending, eigenvectors as columns
    t_cross = np.full(n, np.nan)
    pair = np.full(n, -1)
    count = np.zeros(n, dtype=int)
    for p in range(d - 1):
        has_ref = np.zeros(n, dtype=bool)
        ref_t = np.zeros(n)
        ref_gap = np.ones(n)
        ref_u = np.zeros((n, d))
        ref_v = np.zeros((n, d))
        for k in range(nt):
            a = sym[:, k]
            s = np.einsum("ni,nij,nj->n", ref_u, a, ref_u) - np.einsum("ni,nij,nj->n", ref_v, a, ref_v)
            crossed = has_ref & ok[:, k] & (s < -tol_gap)
            if crossed.any():
                # ref_gap > tol_gap > 0 > -tol_gap > s where crossed: no zero division
                tc = ref_t + (t[k] - ref_t) * ref_gap / np.where(crossed, ref_gap - s, 1.0)
                earlier = crossed & ~(tc >= t_cross)  # also true where t_cross is NaN
                t_cross = np.where(earlier, tc, t_cross)
                pair = np.where(earlier, p, pair)
                count += crossed
            gap = lam[:, k, p] - lam[:, k, p + 1]
            resolved = ok[:, k] & (gap > tol_gap)
            # After a crossing the reference is dropped until the pair is resolved
            # again, so that one crossing is not counted twice.
            has_ref = np.where(resolved, True, has_ref & ~crossed)
            ref_t = np.where(resolved, t[k], ref_t)
            ref_gap = np.where(resolved, gap, ref_gap)
            ref_u = np.where(resolved[:, None], vec[:, k, :, p], ref_u)
            ref_v = np.where(resolved[:, None], vec[:, k, :, p + 1], ref_v)
    return t_cross, pair, count


def _diagnose(
    model: OrientationModel,
    t: Any,
    ys: Any,
    status: Any,
    num_accepted: Any,
    rtol: float,
    atol: float,
    batched: bool,
    where: str,
) -> dict[str, Any]:
    """Admissibility and eigenvalue-crossing checks of a finished solve; warns.

    Returns the :class:`OrientationSolution` diagnostic fields (scalars for a single
    solve, arrays over members for a batch). Nothing is checked for traced values
    (a solve under ``jax.jit``/``grad``): the fields are then ``None``.
    """
    if any(isinstance(x, jax.core.Tracer) for x in (ys, status, num_accepted)):
        return {}
    t = np.asarray(t, dtype=np.float64)
    a2 = np.asarray(ys, dtype=np.float64)
    status = np.atleast_1d(np.asarray(status))
    if not batched:
        a2 = a2[None]
    n, nt, d = a2.shape[0], a2.shape[1], a2.shape[-1]
    num_accepted = np.broadcast_to(np.asarray(num_accepted), (n,))
    tol_trace, tol_eig = _tolerances(num_accepted, rtol, atol, d)
    # States after a solver failure are not meaningful (diffrax fills them with
    # inf); the status reports the failure, so only the finite ones are checked.
    finite = np.isfinite(a2).reshape(n, nt, -1).all(axis=-1)
    valid = finite | (status[:, None] == 0)
    admissible, t_bad, adm_msgs = _admissibility(t, a2, valid, tol_trace, tol_eig)
    label = _model_label(model)
    who = (lambda m: f"member {m}: ") if batched else (lambda m: "")
    if not admissible.all():
        bad = np.flatnonzero(~admissible)
        shown = "; ".join(who(m) + adm_msgs[m] for m in bad[:5])
        more = f"; and {bad.size - 5} more members" if bad.size > 5 else ""
        members = f"{bad.size} of {n} members: " if batched else ""
        warnings.warn(
            f"{where}: {label}: {members}{shown}{more}. The model (usually its closure) is outside its domain "
            "of validity there; see OrientationSolution.admissible / first_inadmissible_time.",
            InadmissibleOrientationWarning,
            stacklevel=3,
        )
    out = {
        "admissible": admissible if batched else bool(admissible[0]),
        "first_inadmissible_time": t_bad if batched else float(t_bad[0]),
        "admissibility_message": tuple(adm_msgs) if batched else adm_msgs[0],
    }
    if getattr(model, "uses_eigenvectors", False):
        t_cross, pair, count = _crossings(t, a2, valid, 2.0 * tol_eig)
        cross_msgs = []
        for m in range(n):
            if np.isnan(t_cross[m]):
                cross_msgs.append("")
                continue
            p = int(pair[m])
            cross_msgs.append(
                f"eigenvalues {p + 1} and {p + 2} of a2 (descending order) cross at t = {t_cross[m]:.6g} s "
                f"(interpolated between saves; {int(count[m])} crossing(s) in all)"
            )
        crossed = np.flatnonzero(~np.isnan(t_cross))
        if crossed.size:
            shown = "; ".join(who(m) + cross_msgs[m] for m in crossed[:5])
            more = f"; and {crossed.size - 5} more members" if crossed.size > 5 else ""
            members = f"{crossed.size} of {n} members: " if batched else ""
            warnings.warn(
                f"{where}: {label}: {members}{shown}{more}. This model is built on the principal axes of a2 and "
                "is ill-posed where two eigenvalues cross: a perturbation of the axes grows without bound as the "
                "gap closes, so round-off decides the path beyond this time (or, if the principal axes turned by "
                "more than 45 degrees between two saves, the rotation aliased as a crossing: save more often).",
                EigenvalueCrossingWarning,
                stacklevel=3,
            )
        out["crossing_time"] = t_cross if batched else float(t_cross[0])
        out["crossing_message"] = tuple(cross_msgs) if batched else cross_msgs[0]
    return out


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
        With the admissibility (and, for eigenvector-based models, crossing)
        diagnostics of the saved states.

    Raises
    ------
    InputError
        Invalid ``a2_0``, ``L``, ``t_eval`` or tolerances.
    ConvergenceError
        ``throw=True`` and the solver failed (e.g. ``max_steps`` reached).

    Warns
    -----
    pyfold.errors.InadmissibleOrientationWarning
        A saved ``a2`` is not an orientation tensor to within the integration
        error (``|tr a2 - 1|`` or a negative eigenvalue beyond the bound
        ``2 N d (atol + rtol)`` on the accumulated local error, ``N`` accepted
        steps): names the first such time and the cause.
    pyfold.errors.EigenvalueCrossingWarning
        ``model.uses_eigenvectors`` and two eigenvalues of ``a2`` cross: states
        the (interpolated) time. A degeneracy present at ``t_eval[0]`` that only
        splits (isotropic start) is not a crossing.
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
    diagnostics = _diagnose(
        model, t, ys, status, stats["num_accepted_steps"], rtol, atol, batched=False, where="solve_orientation"
    )
    return OrientationSolution(t=t, a2=ys, status=status, stats=stats, **diagnostics)


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
        ``a2`` (n, nt, d, d), ``status`` (n,), ``stats`` values (n,), and the
        diagnostics per member (``admissible`` (n,), ``first_inadmissible_time``
        (n,), ...). Solver failures are reported per member and never raise
        (``throw=False`` semantics); ``max_steps`` applies to each member.

    Warns
    -----
    pyfold.errors.InadmissibleOrientationWarning, pyfold.errors.EigenvalueCrossingWarning
        As in :func:`solve_orientation`; one warning per call, naming the
        offending members (their index), times and causes.

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
    diagnostics = _diagnose(
        model, t, ys, status, stats["num_accepted_steps"], rtol, atol, batched=True, where="solve_batch"
    )
    return OrientationSolution(t=t, a2=ys, status=status, stats=stats, **diagnostics)


@eqx.filter_jit
def _batch_jit(model, model_axes, a2_0, a2_axis, L, t_eval, rtol, atol, solver, max_steps):
    def one(m, a0):
        return _integrate(m, a0, L, t_eval, rtol, atol, solver, max_steps)

    return eqx.filter_vmap(one, in_axes=(model_axes, a2_axis))(model, a2_0)
