"""Trajectory fit of Folgar–Tucker's ``C_I`` by fixed-step RK4 on fixed array shapes.

The one trajectory fit of the analysis chain (``pyfold analyse``, ``pyfold report``, the
main job, the studies); its integration, at a given ``C_I``, is :func:`predict_ft`.

The problem is the one of :func:`pyfold.fit.fit_parameters` with ``params=("ci",)``
and unit weights:

    min_{C_I >= 0}  sum_{k >= 1} sum_{i <= j} (a_ij(t_k; C_I) - a_ij^run(t_k))^2 ,

Folgar–Tucker started from the run's first record (symmetrised) and closed by a
registered closure or by the run's own ``a4`` (``"exact"``: the records interpolated
in time by the piecewise cubic Hermite of :class:`pyfold.closures.TabulatedA4`,
corrected to contract to the integrated a2: :func:`contracted_table`, see
Admissibility below). What
differs is how it is solved, so that a run of hundreds of records is fitted in
seconds and a new process re-uses the compiled programs:

* the orientation equation by classical RK4 with a fixed step: every record interval
  ``Δt_k`` is cut into ``ceil(γ̇ Δt_k / MAX_STEP)`` equal steps; ``∂a2/∂C_I`` by forward
  mode (``jax.jvp``) through the same steps;
* ``C_I`` by Newton's method on the gradient ``J·r`` of the loss in the variable
  ``v = ln(C_I + CI_SCALE)`` (curvature from the secant of the gradient, Gauss–Newton's
  ``J·J`` for the first step; a rejected step is shortened to at most a quarter),
  projected onto ``C_I >= 0`` (a projected step of zero at ``C_I = 0`` is the Karush–Kuhn–Tucker
  condition of the active bound), the whole loop inside one compiled program;
* the records padded to a power of two (at least :data:`MIN_RECORDS`) with
  zero-length intervals and zero weights, so that one program per closure and size
  class serves every run; the programs carry no host callbacks, so JAX's persistent
  cache (:mod:`pyfold._jax`) keeps them (a diffrax solve does carry callbacks and is
  compiled again in every process), and each is run through a serialised export
  (:func:`pyfold._jax.exported_call`), so a new process neither traces nor lowers it;
* the closure evaluated at one place in the program: the four RK4 stages are a loop,
  and the start, every Newton trial and the half-step pass of the step error (below)
  are passes of one loop around a single ``jvp`` of the integration. The code XLA
  compiles, and a new process loads from the cache, is then one closure and its
  derivative instead of twelve copies.

The step error of the fitted value. RK4's global error is ``O(h^4)``: at the optimum
the run is integrated again with half the step, and ``e = 16/15 (a_h - a_{h/2})``
estimates the error of ``a_h`` (Richardson). To first order the fit then sits off the
exact-ODE optimum by ``ΔC_I = -(J·e)/H``, ``J = ∂r/∂C_I``, ``H`` the curvature of half
the loss (the last secant of its gradient; ``J·J`` without one): the Newton step that
``e`` induces. If ``|ΔC_I|`` exceeds :data:`STEP_ERROR_SHARE` of the standard
error of ``C_I`` (or the optimiser's own tolerance, whichever is larger), the step is
halved and the fit repeated (the same compiled program: the step counts are data), at
most :data:`MAX_REFINEMENTS` times. ``|ΔC_I|`` is reported with the fit
(``ci_step_error``). A tenth of the standard error adds half a percent to the total
error in quadrature: the fixed step does not change what the fit says.

Admissibility. Every trajectory the loss sees is checked, in the program: finite,
symmetric, ``|tr a2 - 1|`` not beyond its start's by more than ``tol``, and the
eigenvalues in ``[-tol, 1 + tol]``; a trajectory that fails has an infinite loss, so the
optimiser never settles on one. The fitted trajectory is checked again in numpy
(:func:`admissibility`), which names the first record, RK4 step and cause; a fit that
leaves the set is retried at half the step (a discretisation artefact goes away, a
departure of the model does not) and, if it still leaves it, reported as failed with
``C_I`` NaN. The tolerance (:func:`admissible_tol`) is a round-off bound,
:data:`ADMISSIBLE_TOL_PER_STEP` per RK4 step times the steps taken, plus the drift a
closure's departure from ``a4_ijkk = a2_ij`` can cause (:data:`CONTRACTION_DEFECT`):
Folgar–Tucker keeps ``tr a2 = 1`` exactly when the
closure satisfies ``a4_ijkk = a2_ij`` (``tr`` of the rate is ``2 xi D:(a2 - a4_iikl)
- 2 d C_I γ̇ (tr a2 - 1)``), and RK4, a linear combination of rates, preserves that
linear invariant up to round-off. The eigenvalues of the exact flow stay in
``[0, 1]``; those of the computed states move by at most the 2-norm of the accumulated
round-off and closure defect (Weyl), bounded by the same sum.

The run's own a4 ("exact") is fed through :func:`contracted_table`: the recorded a4,
corrected by the smallest fully symmetric tensor that restores ``a4_ijkk = a2_ij`` for
the a2 being integrated. The recorded a4 alone contracts to the *run's* a2, not the
integrated one, and the trace then obeys ``d tr/dt = 2 xi D:(a2 - a2_run)``: the
difference is amplified at a rate ``2 xi D:a2`` and the trace runs away over a long run
(``tr a2 = 6`` at ``γ̇ t = 400`` on ``data/scenes/default.toml``). On the run's own
trajectory the correction is zero.

Standard error: ``s^2 / (J·J)``, ``s^2 = RSS / (n - 1)`` (Bard 1974, ch. 7), as in
:mod:`pyfold.fit`: independent residuals of equal variance assumed.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from pyfold._jax import exported_call, jax, jnp
from pyfold.errors import InputError

__all__ = ["FastFit", "fit_ci_rk4", "fit_flags", "predict_ft", "CI_STARTS", "padded_size", "admissibility", "contracted_table", "MAX_STEP", "MIN_RECORDS",
           "admissible_tol", "ADMISSIBLE_TOL_PER_STEP", "CONTRACTION_DEFECT"]

#: Largest RK4 step [1/γ̇] of the fits and of :func:`predict_ft`. Against the adaptive
#: diffrax solve at rtol 1e-10 over a strain of 400 from isotropy (beta = 10), the largest
#: a2 error was 6e-5 at C_I = 0 and 8e-6 at C_I = 1e-3 (IBOF and FEC alike; 1e-3 at a step
#: of 1; tests/cli/test_report.py checks it).
#: The step error estimate at the optimum decides whether it is small enough for each
#: fit, and halves it when not. The cost is in the closure evaluations (four per step;
#: FEC ~0.04 ms each with its derivative), so the step is no smaller than it needs to be.
MAX_STEP = 0.5
#: Smallest padded record count: below it, runs share one size class.
MIN_RECORDS = 64
#: Starting values of C_I of a fit: the loss can have two minima in C_I, and Newton's
#: method finds the one on its side. Measured on the default scene (strain 0-104): with
#: the quadratic closure minima near 1e-5 and 1.5e-2 (a2 RMS 0.072 and 0.091, the hump
#: near 1e-3), with the hybrid near 3e-5 and 2e-2 (0.064 and 0.075). One start on
#: either side of the hump and one at the end of the published range (1e-4 .. 3e-2,
#: pyfold.correlations.PUBLISHED_RANGE); the fit of least misfit is kept.
CI_STARTS = (1e-5, 1e-3, 3e-2)
#: Largest share of the standard error of C_I that the step error may take (see module notes).
STEP_ERROR_SHARE = 0.1
#: Halvings of the step at most (step 0.25 -> 0.03125 / γ̇).
MAX_REFINEMENTS = 3
#: Stop when the next step of C_I is below OPT_SHARE of its standard error (the
#: optimiser then leaves the value within about a hundredth of its statistical
#: uncertainty: the step not taken is Newton's estimate of the distance to the optimum;
#: 1e-3 takes one more pass over the run and moved the default run's fits by at most
#: 0.0025 standard errors), or
#: below FIT_RTOL |C_I| + FIT_ATOL (noise-free data, whose standard error is ~0): the
#: relative first-order test of pyfold.fit (_STEP_TOL = 1e-6), and an absolute floor
#: far below any resolvable C_I (published values >= 1e-4).
OPT_SHARE = 1e-2
FIT_RTOL = 1e-6
FIT_ATOL = 1e-10
#: The secant curvature is used only within this factor of Gauss-Newton's J.J.
SECANT_RANGE = 10.0
#: Scale of the fitted variable v = ln(C_I + CI_SCALE): the loss's Jacobian in C_I falls
#: roughly as 1/C_I over the published range (measured on the default run with IBOF:
#: J.J from 8e5 at C_I = 1e-3 to 9e7 at 2e-4), so in v it is nearly flat and Newton's
#: steps are good from far away; below CI_SCALE the variable is linear in C_I, so C_I = 0
#: is reached. The optimum does not depend on it. 1e-6 diffuses a2 by ~1e-3 over a
#: strain of 400 (2 d C_I γ̇ t), below what a run of a few hundred fibres resolves.
CI_SCALE = 1e-6
#: Largest step of v (a factor e^2 on C_I + CI_SCALE).
MAX_LOG_STEP = 2.0
#: Iterations at most (the secant converges superlinearly: about ten).
MAX_ITERATIONS = 60
#: Classical RK4: stage j is evaluated at a + h c_j k_(j-1), and the step is
#: a + h/6 sum_j w_j k_j.
#: Round-off allowed per RK4 step in the admissibility check (module notes): the update
#: ``a + h/6 sum_j w_j k_j`` rounds each entry by a few ε; the rate's entries are sums
#: of O(d^3) products of entries <= 1 and rates <= γ̇ (relative error ~d^3 ε = 27 ε,
#: times h γ̇ <= MAX_STEP); summed over the d diagonal entries and the four stages,
#: ~300 ε, rounded up to 1024 ε: 1.5e-9 over the 6400 steps of a strain of 400 at the
#: smallest step (MAX_STEP / 2**MAX_REFINEMENTS).
ADMISSIBLE_TOL_PER_STEP = 1024 * float(np.finfo(np.float64).eps)
#: Largest departure from ``a4_ijkk = a2_ij`` of a closure [1] on the states a fit
#: visits. It moves the trace at the rate 2 |xi| ||D|| CONTRACTION_DEFECT <= 2 |xi| γ̇
#: CONTRACTION_DEFECT, step size aside, so over a strain γ̇ T the tolerance grows by
#: 2 |xi| γ̇ T CONTRACTION_DEFECT (8e-7 over a strain of 400). The polynomial closures
#: (quadratic, hybrid, IBOF, ORW3) meet the identity algebraically, to ~100 ε; the run's
#: own a4 does by construction (ContractedTable); FEC (pyfold.closures.exact) meets it
#: to the residual of its inverse problem a2 -> C, which grows where two eigenvalues of
#: a2 approach 0 (ill-conditioned there): 2e-13 on random states, 5e-11 with eigenvalues
#: (3e-5, 5e-4), 9e-10 with (7e-6, 1e-5) (measured on 300 states each). 1e-9 covers
#: states down to eigenvalues ~1e-5; a trajectory more aligned than that is reported
#: (cause "trace") rather than passed. A blown-up trajectory departs by O(1e-3 .. 1).
CONTRACTION_DEFECT = 1e-9
_RK4_NODES = np.array([0.0, 0.5, 0.5, 1.0])
_RK4_WEIGHTS = np.array([1.0, 2.0, 2.0, 1.0])


def _contracted_table_class():
    """:class:`ContractedTable`, built on first use (so that importing this module
    does not import the closures)."""
    global ContractedTable
    if ContractedTable is not None:
        return ContractedTable
    from pyfold.closures import TabulatedA4

    class _ContractedTable(TabulatedA4):
        """The recorded ``a4(t)`` of :class:`pyfold.closures.TabulatedA4`, corrected for
        the a2 it is given so that ``a4_ijkk = a2_ij`` (module notes).

        The correction ``X`` is the fully symmetric tensor of least Frobenius norm with
        ``X_ijkk = delta_ij``, ``delta = a2 - a4_ijkk``: the contraction's adjoint on
        symmetric tensors is ``B -> S(B ⊗ I)`` (S the full symmetrisation), whose
        contraction is ``((d + 4) B + tr B I) / 6``; so ``X = S(B ⊗ I)`` with
        ``tr B = 3 tr delta / (d + 2)`` and ``B = (6 delta - tr B I) / (d + 4)``. It
        vanishes on the run's own trajectory (``delta = 0``) and is linear in
        ``delta``: an error of the fit in a2 changes a4 to first order only where the
        identity every a4 obeys requires it.
        """

        def __call__(self, a2, t):
            a4 = TabulatedA4.__call__(self, a2, t)
            d = a4.shape[-1]
            eye = jnp.eye(d, dtype=a4.dtype)
            delta = a2 - jnp.einsum("ijkk->ij", a4)
            trb = 3.0 * jnp.trace(delta) / (d + 2)
            B = (6.0 * delta - trb * eye) / (d + 4)
            x = jnp.einsum("ij,kl->ijkl", B, eye)
            sym = (x + x.transpose(0, 2, 1, 3) + x.transpose(0, 3, 2, 1)
                   + x.transpose(2, 3, 0, 1) + x.transpose(2, 1, 0, 3) + x.transpose(3, 1, 2, 0)) / 6.0
            return a4 + sym

    _ContractedTable.__name__ = _ContractedTable.__qualname__ = "ContractedTable"
    ContractedTable = _ContractedTable
    return ContractedTable


#: :func:`_contracted_table_class` (None until first used).
ContractedTable = None


def admissible_tol(steps, xi, strain):
    """Tolerance of the admissibility check after ``steps`` RK4 steps over ``strain`` =
    γ̇ (t_end - t_0): round-off and the closure's contraction defect
    (:data:`ADMISSIBLE_TOL_PER_STEP`, :data:`CONTRACTION_DEFECT`)."""
    return ADMISSIBLE_TOL_PER_STEP * steps + 2.0 * abs(xi) * CONTRACTION_DEFECT * strain


def contracted_table(times, a4_series):
    """The run's ``a4(t)`` as the closure the fits integrate with: a
    :class:`ContractedTable` (cubic Hermite in time, corrected so that
    ``a4_ijkk = a2_ij`` for the a2 it is given)."""
    return _contracted_table_class()(times, a4_series)


def admissibility(a2: np.ndarray, tol: float) -> tuple[int, str]:
    """First record of ``a2`` (nt, d, d) outside the orientation tensors, and why.

    Outside: not finite; not symmetric (``|a_ij - a_ji| > tol``); ``|tr a2 - 1|`` more
    than ``tol`` beyond its value at record 0; an eigenvalue below ``-tol`` or above
    ``1 + tol``. Returns ``(-1, "")`` when every record is admissible."""
    a2 = np.asarray(a2, dtype=np.float64)
    d = a2.shape[-1]
    finite = np.isfinite(a2).reshape(len(a2), -1).all(axis=1)
    safe = np.where(finite[:, None, None], a2, np.eye(d) / d)
    asym = np.abs(safe - np.swapaxes(safe, -1, -2)).max(axis=(-2, -1))
    trace_err = np.abs(np.trace(safe, axis1=-2, axis2=-1) - 1.0)
    ev = np.linalg.eigvalsh(0.5 * (safe + np.swapaxes(safe, -1, -2)))
    bad_sym = asym > tol
    bad_trace = trace_err > trace_err[0] + tol
    bad_low, bad_high = ev[:, 0] < -tol, ev[:, -1] > 1.0 + tol
    bad = ~finite | bad_sym | bad_trace | bad_low | bad_high
    if not bad.any():
        return -1, ""
    k = int(np.argmax(bad))
    if not finite[k]:
        return k, "non-finite a2"
    causes = []
    if bad_trace[k]:
        causes.append(f"trace: tr a2 = {np.trace(safe[k]):.10g} (|tr a2 - 1| > {trace_err[0] + tol:.1e})")
    if bad_low[k]:
        causes.append(f"negative eigenvalue {ev[k, 0]:.3e} (< -{tol:.1e})")
    if bad_high[k]:
        causes.append(f"eigenvalue {ev[k, -1]:.6g} above 1 + {tol:.1e}")
    if bad_sym[k]:
        causes.append(f"asymmetry {asym[k]:.1e} > {tol:.1e}")
    return k, ", ".join(causes)


@dataclasses.dataclass(frozen=True)
class FastFit:
    """Outcome of :func:`fit_ci_rk4`."""

    closure: str
    ci: float
    stderr: float
    residual_rms: float  # sqrt(RSS / n) [1]
    n_points: int  # residuals n: (records - 1) x d(d+1)/2
    success: bool
    at_bound: bool
    message: str
    a2: np.ndarray  # (records, d, d): Folgar-Tucker at the fitted C_I, on the record times
    step: float  # RK4 step used [1/γ̇] (largest over the record intervals)
    step_error: float  # |ΔC_I| estimated from the step (module notes)
    iterations: int  # Newton steps, summed over the passes at successively halved RK4 steps
    #: the fitted trajectory stays in the orientation tensors (module notes); when not,
    #: ``success`` is False, ``ci`` and ``stderr`` are NaN and the fields below say where
    admissible: bool = True
    inadmissible_time: float = math.nan  # first record time [s] outside the set
    inadmissible_step: int = -1  # RK4 steps taken up to that record
    inadmissible_cause: str = ""


def padded_size(n: int) -> int:
    """The size class of ``n`` records: the next power of two, at least :data:`MIN_RECORDS`."""
    return max(MIN_RECORDS, 1 << max(0, int(n) - 1).bit_length())


_PROGRAMS: dict[tuple[str, int], object] = {}


def _rate(closure: str, dim: int):
    """Folgar–Tucker's rate with ``closure`` (a table, given as the argument ``table``,
    replaces it), jitted on its own: the four RK4 stages, the jvp and the two
    integrations of a fit program trace the closure once."""
    from pyfold.models import FolgarTucker

    @jax.jit
    def rate(ci, xi, a, L, t, table):
        model = FolgarTucker(ci=ci, xi=xi, closure=closure if table is None else table, dim=dim)
        return model.rate(t, a, L)

    return rate


def _integrate(rate, ci, xi, a2_0, L, t, n_sub, table):
    """Classical RK4 of ``rate`` from ``a2_0`` at ``t[0]`` onto the times ``t``, with
    ``n_sub[k]`` equal steps over ``[t[k], t[k+1]]`` (0: a padded interval, no step).
    Returns the states at ``t`` (the first is ``a2_0``)."""
    def interval(a, k):
        h = jnp.where(n_sub[k] > 0, (t[k + 1] - t[k]) / jnp.maximum(n_sub[k], 1), 0.0)

        def step(i, a):
            s = t[k] + i * h

            # The four stages as a loop over _RK4_NODES / _RK4_WEIGHTS: the closure
            # appears once in the program, not four times (a quarter of the code to
            # compile and to load from the cache). The arithmetic is that of
            # k2 = rate(a + h/2 k1), ..., a + h/6 (k1 + 2 k2 + 2 k3 + k4), term by term.
            def stage(j, carry):
                k_prev, acc = carry
                c = jnp.asarray(_RK4_NODES)[j]
                k_j = rate(ci, xi, a + (h * c) * k_prev, L, s + h * c, table)
                return k_j, acc + jnp.asarray(_RK4_WEIGHTS)[j] * k_j

            zero = jnp.zeros_like(a)
            _, acc = jax.lax.fori_loop(0, 4, stage, (zero, zero))
            return a + h / 6 * acc

        a = jax.lax.fori_loop(0, n_sub[k], step, a)
        return a, a

    _, ys = jax.lax.scan(interval, a2_0, jnp.arange(t.shape[0] - 1))
    return jnp.concatenate([a2_0[None], ys])


def _substeps(t: np.ndarray, rate: float, h: float) -> np.ndarray:
    """RK4 steps per record interval: ``ceil(γ̇ Δt_k / h)``, at least one. (1 - 1e-12):
    an interval that is a whole number of steps up to the round-off of the division
    (0.5 / 0.5 = 1 + 2e-16) takes that number, not one more."""
    return np.maximum(1, np.ceil(np.diff(t) * rate / h * (1.0 - 1e-12))).astype(np.int32)


_PREDICTIONS: dict[tuple[str, int], object] = {}


def predict_ft(closure: str, ci: float, xi: float, a2_0: np.ndarray, L: np.ndarray, t: np.ndarray,
               max_step: float = MAX_STEP) -> np.ndarray:
    """Folgar–Tucker ``a2`` with ``closure`` at ``ci`` from ``a2_0`` at ``t[0]``, at the times
    ``t`` (Folgar & Tucker 1984; Advani & Tucker 1987 for the tensor form): the integration
    of the fits (classical RK4, every interval cut into steps no longer than ``max_step``
    / γ̇), at a given C_I. One jitted program per closure, kept by the persistent cache."""
    from pyfold.models import FolgarTucker

    a2_0 = np.asarray(a2_0, dtype=np.float64)
    d = a2_0.shape[-1]
    t = np.asarray(t, dtype=np.float64)
    L = np.asarray(L, dtype=np.float64)[:d, :d]
    D = 0.5 * (L + L.T)
    rate = math.sqrt(2.0 * float(np.sum(D * D))) or 1.0  # pyfold.kinematics.shear_rate, in numpy
    FolgarTucker(ci=float(ci), xi=float(xi), closure=closure, dim=d)  # checks C_I >= 0, xi and the closure name
    key = (closure, d)
    if key not in _PREDICTIONS:
        f = _rate(closure, d)
        _PREDICTIONS[key] = jax.jit(lambda ci, xi, a2_0, L, t, n_sub: _integrate(f, ci, xi, a2_0, L, t, n_sub, None))
    ys = _PREDICTIONS[key](np.float64(ci), np.float64(xi), a2_0, L, t, _substeps(t, rate, max_step))
    return np.asarray(ys)


def _program(closure: str, dim: int):
    """The jitted fit for ``closure`` (a registered name, or ``"exact"``: the table
    given as data, ``(times, a4, slopes)`` of :class:`pyfold.closures.TabulatedA4`) in
    ``dim`` dimensions. Traced only when no export of it is found
    (:func:`pyfold._jax.exported_call`); its compiled code is kept by the persistent
    cache across processes."""
    key = (closure, dim)
    if key in _PROGRAMS:
        return _PROGRAMS[key]
    import equinox as eqx

    iu, ju = np.triu_indices(dim)
    rate = _rate(closure, dim)

    def tabulated(arrays):
        # the run's a4 as a TabulatedA4 whose arrays are the program's inputs
        if not arrays:
            return None
        template = _contracted_table_class()(np.arange(2.0), np.zeros((2,) + (dim,) * 4))
        return eqx.tree_at(lambda m: (m.times, m.a4_series, m.slopes), template, tuple(arrays))

    def integrate(ci, xi, a2_0, L, t, n_sub, table):
        return _integrate(rate, ci, xi, a2_0, L, t, n_sub, table)

    @jax.jit
    def fit(ci0, xi, a2_0, L, t, n_sub, target, weight, table_arrays):
        table = tabulated(table_arrays)
        # The variable is v = ln(C_I + CI_SCALE) (module notes); v_min is C_I = 0.
        v_min = jnp.log(CI_SCALE)

        def ci_of(v):
            return jnp.where(v <= v_min, 0.0, jnp.exp(v) - CI_SCALE)

        def admissible(a2, steps):
            # the test of admissibility() (module notes), on every record (the padded
            # ones repeat the last); the eigenvalues of a non-finite state are not
            # looked at (its finiteness test fails anyway)
            tol = admissible_tol(jnp.sum(steps), xi, jnp.sqrt(2.0 * jnp.sum(Dsym * Dsym)) * (t[-1] - t[0]))
            finite = jnp.all(jnp.isfinite(a2))
            a = jnp.where(finite, a2, jnp.eye(dim) / dim)
            at = jnp.swapaxes(a, -1, -2)
            trace_err = jnp.abs(jnp.trace(a, axis1=-2, axis2=-1) - 1.0)
            ev = jnp.linalg.eigvalsh(0.5 * (a + at))
            return (finite & jnp.all(jnp.abs(a - at) <= tol) & jnp.all(trace_err <= trace_err[0] + tol)
                    & jnp.all(ev[:, 0] >= -tol) & jnp.all(ev[:, -1] <= 1.0 + tol))

        Dsym = 0.5 * (L + L.T)

        def evaluate(v, steps):
            ci = ci_of(v)
            a2, da2 = jax.jvp(lambda c: integrate(c, xi, a2_0, L, t, steps, table), (ci,), (jnp.ones_like(ci),))
            r = (a2[1:, iu, ju] - target) * weight
            J = da2[1:, iu, ju] * weight * (ci + CI_SCALE)  # dr/dv
            # (a far blown-up state has finite entries whose products overflow)
            finite = (jnp.all(jnp.isfinite(r)) & jnp.all(jnp.isfinite(J)) & jnp.isfinite(jnp.sum(J * r))
                      & jnp.isfinite(jnp.sum(J * J)) & jnp.isfinite(jnp.sum(r * r)))
            r, J = jnp.where(finite, r, 0.0), jnp.where(finite, J, 0.0)
            # an inadmissible trajectory has an infinite loss (never accepted), but its
            # gradient is kept: from an inadmissible start, Newton's step towards the
            # least squares is the best guess of where admissible ones are
            loss = jnp.where(finite & admissible(a2, steps), jnp.sum(r * r), jnp.inf)
            return a2, r, J, loss, jnp.sum(J * r), jnp.sum(J * J)

        def newton(v, g, jj, v_o, g_o):
            # the curvature of the loss / 2: the secant of its gradient g = J.r through the
            # other evaluated point (superlinear even when the residuals are large), else
            # Gauss-Newton's J.J; a secant beyond a factor SECANT_RANGE of J.J is not used
            # (between close points round-off in g makes it meaningless)
            dv = v - v_o
            secant = (g - g_o) / jnp.where(dv != 0.0, dv, 1.0)
            usable = (dv != 0.0) & jnp.isfinite(secant) & (secant > jj / SECANT_RANGE) & (secant < jj * SECANT_RANGE)
            curv = jnp.where(usable, secant, jj)
            step = jnp.where(curv > 0.0, -g / jnp.where(curv > 0.0, curv, 1.0), 0.0)
            step = jnp.clip(step, -MAX_LOG_STEP, MAX_LOG_STEP)
            return jnp.maximum(v + step, v_min) - v  # projected onto C_I >= 0

        n_res = jnp.sum(weight) * iu.size

        def small(v, step, loss, jj):
            # the change of C_I below OPT_SHARE of its standard error, or below the floor
            ci = ci_of(v)
            stderr = jnp.sqrt(loss / jnp.maximum(n_res - 1, 1) / jnp.where(jj > 0.0, jj, jnp.inf)) * (ci + CI_SCALE)
            return jnp.abs(ci_of(v + step) - ci) <= jnp.maximum(OPT_SHARE * stderr, FIT_RTOL * ci + FIT_ATOL)

        # One evaluation site in the program (the closure's jvp is the bulk of its code):
        # the first pass of the loop evaluates the start v0 and sets up the state, the
        # passes after it evaluate the trial v + step, and once the optimiser has stopped
        # a last pass integrates the optimum again with half the step, for the step error
        # (module notes; its derivative is not used).
        v0 = jnp.log(ci0 + CI_SCALE)
        n_r = target.shape
        zeros_a2 = jnp.zeros((t.shape[0],) + a2_0.shape, a2_0.dtype)
        false = jnp.asarray(False)
        state = (v0, zeros_a2, jnp.zeros(n_r), jnp.zeros(n_r), jnp.asarray(jnp.inf), jnp.asarray(0.0),
                 jnp.asarray(0.0), v0, jnp.asarray(0.0), jnp.asarray(0.0), jnp.asarray(0), false,
                 jnp.asarray(True), zeros_a2, false)

        def cond(s):
            return ~s[14]

        def start(v, evaluated):
            a2, r, J, loss, g, jj = evaluated
            step = newton(v, g, jj, v, g)
            return v, a2, r, J, loss, g, jj, v, g, step, jnp.asarray(0), small(v, step, loss, jj) & jnp.isfinite(loss)

        def advance(s, trial, evaluated):
            v, a2, r, J, loss, g, jj, _, _, step, it, _ = s
            a2_t, r_t, J_t, loss_t, g_t, jj_t = evaluated
            # from an inadmissible point (infinite loss) an inadmissible trial is taken
            # too: the search goes on along Newton's steps towards the least squares
            # instead of shrinking back onto a point that no step size rescues
            accept = (loss_t < loss) | (jnp.isinf(loss) & jnp.isinf(loss_t))
            # the other point of the secant: the one left behind, or the rejected trial
            v_o, g_o = jnp.where(accept, v, trial), jnp.where(accept, g, g_t)
            v, a2, r, J, loss, g, jj = jax.tree_util.tree_map(lambda new, old: jnp.where(accept, new, old),
                                                              (trial, a2_t, r_t, J_t, loss_t, g_t, jj_t),
                                                              (v, a2, r, J, loss, g, jj))
            proposal = newton(v, g, jj, v_o, g_o)
            # after a rejected step, at most a quarter of it: the loss is smooth in v, so a
            # short enough step descends
            shorter = jnp.where(jnp.abs(proposal) < jnp.abs(step) / 4, proposal,
                                jnp.maximum(v + step / 4, v_min) - v)
            step = jnp.where(accept, proposal, shorter)
            return v, a2, r, J, loss, g, jj, v_o, g_o, step, it + 1, small(v, step, loss, jj) & jnp.isfinite(loss)

        def body(s):
            first, a2_half = s[12], s[13]
            stopped = ~first & ((s[10] >= MAX_ITERATIONS) | s[11])
            point = jnp.where(first | stopped, s[0], s[0] + s[9])
            evaluated = evaluate(point, jnp.where(stopped, 2 * n_sub, n_sub))
            new = jax.tree_util.tree_map(lambda a, b, c: jnp.where(first, a, jnp.where(stopped, b, c)),
                                         start(point, evaluated), s[:12], advance(s[:12], point, evaluated))
            return (*new, false, jnp.where(stopped, evaluated[0], a2_half), stopped)

        v, a2, r, J, loss, g, _, v_o, g_o, _, it, done, _, a2_half, _ = jax.lax.while_loop(cond, body, state)
        ci = ci_of(v)
        scale = ci + CI_SCALE
        # curvature of the loss / 2 in C_I at the optimum, from the last secant in v (g = 0
        # at an interior optimum, so the chain rule's g d2v/dC_I2 term drops out)
        secant = (g - g_o) / jnp.where(v != v_o, v - v_o, jnp.nan) / scale**2
        return ci, a2, r, J / scale, loss, it, done, a2_half, secant

    _PROGRAMS[key] = fit
    return fit


def _table(t: np.ndarray, a4: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The run's a4 as the arrays ``(times, a4, slopes)`` of a
    :class:`pyfold.closures.TabulatedA4` of ``size`` rows: the real records, then rows
    past the end (times continuing at the last spacing, the last a4, zero slopes) that
    the integration never reaches. Its interpolation on ``[t[0], t[-1]]`` is that of the
    unpadded table (the slopes are the real table's). In numpy: no small programs to
    compile for a table built op by op in JAX."""
    from pyfold.closures.tabulated import _three_point_slopes

    slopes = _three_point_slopes(t, a4)
    extra = size - len(t)
    if extra == 0:
        return t, a4, slopes
    dt = t[-1] - t[-2]
    t_pad = np.concatenate([t, t[-1] + dt * np.arange(1, extra + 1)])
    a4_pad = np.concatenate([a4, np.repeat(a4[-1:], extra, axis=0)])
    slopes_pad = np.concatenate([slopes, np.zeros((extra,) + a4.shape[1:])])
    return t_pad, a4_pad, slopes_pad


def fit_ci_rk4(closure: str, t: np.ndarray, a2: np.ndarray, L: np.ndarray, xi: float, *,
               a4: np.ndarray | None = None, ci_start: float | Sequence[float] = CI_STARTS,
               max_step: float = MAX_STEP,
               t_end: float | None = None) -> FastFit:
    """Fit Folgar–Tucker's ``C_I`` with ``closure`` to ``a2(t)`` (see the module notes).

    The one trajectory fit of the analysis chain: ``pyfold analyse`` fits every record,
    ``pyfold report`` and the main job the records up to ``t_end``.

    Parameters
    ----------
    closure : str
        A registered closure name (:data:`pyfold.closures.CLOSURES`), or ``"exact"``
        with ``a4`` given: the run's own fourth-order tensor.
    t : array (nt,)
        Record times [s], strictly increasing, ``nt >= 2``.
    a2 : array (nt, d, d)
        Recorded second-order tensors; the fit starts from ``a2[0]`` (symmetrised).
    L : array (d, d)
        Constant velocity gradient ``L_ij = du_i/dx_j`` [1/s] (a deforming flow, or a
        rotation: the step is then measured against 1/s).
    xi : float
        Shape factor of the fibres.
    a4 : array (nt, d, d, d, d), optional
        Required for ``closure="exact"``.
    ci_start : float or sequence of float
        Starting value(s) of ``C_I`` (>= 0): from each the fit runs to its optimum, and
        the successful one of least misfit is returned (:data:`CI_STARTS`).
    max_step : float
        Largest RK4 step [1/γ̇] before refinement.
    t_end : float, optional
        Fit only the records at ``t <= t_end`` [s] (a window from the start of the run);
        None: every record.
    """
    t = np.asarray(t, dtype=np.float64)
    a2 = np.asarray(a2, dtype=np.float64)
    n, d = len(t), a2.shape[-1]
    if t.ndim != 1 or n < 2 or np.any(np.diff(t) <= 0.0) or not np.all(np.isfinite(t)):
        raise InputError(f"time: expected at least 2 strictly increasing finite record times, got shape {t.shape}")
    if a2.shape != (n, d, d) or d not in (2, 3):
        raise InputError(f"a2: expected shape ({n}, d, d) with d in {{2, 3}}, got {a2.shape}")
    if t_end is not None:
        # a window from the start: the records up to t_end (one computed from the record
        # times, t0 + k dt, keeps its last record)
        keep = t <= float(t_end) + 1e-12 * max(abs(float(t_end)), 1.0)
        if not (math.isfinite(t_end) and int(np.sum(keep)) >= 2):
            raise InputError(f"t_end: must be finite and keep at least 2 records (t >= {t[1]:.6g} s), got {t_end!r}")
        n = int(np.sum(keep))
        t, a2 = t[:n], a2[:n]
        if a4 is not None:
            a4 = np.asarray(a4)[:n]
    starts = tuple(float(c) for c in np.atleast_1d(np.asarray(ci_start, dtype=np.float64)))
    if not starts or not all(c >= 0.0 and math.isfinite(c) for c in starts):
        raise InputError(f"ci_start: must be one or more finite values >= 0, got {ci_start!r}")
    L = np.asarray(L, dtype=np.float64)[:d, :d]
    size = padded_size(n)
    table = ()
    if closure == "exact":
        if a4 is None:
            raise InputError("a4: closure 'exact' fits with the run's own a4, none given")
        a4 = np.asarray(a4, dtype=np.float64)
        if a4.shape != (n,) + (d,) * 4:
            raise InputError(f"a4: expected shape ({n}, {d}, {d}, {d}, {d}), got {a4.shape}")
        if not np.all(np.isfinite(a4)):
            raise InputError("a4: contains NaN or infinity")
        table = _table(t, a4, size)
    else:
        from pyfold.closures import get_closure

        get_closure(closure, d)  # the name, checked with the allowed ones

    D = 0.5 * (L + L.T)
    rate = math.sqrt(2.0 * float(np.sum(D * D))) or 1.0  # pyfold.kinematics.shear_rate, in numpy
    iu, ju = np.triu_indices(d)
    t_pad = np.concatenate([t, np.full(size - n, t[-1])])
    target = np.zeros((size - 1, iu.size))
    target[: n - 1] = a2[1:, iu, ju]
    weight = np.zeros((size - 1, 1))
    weight[: n - 1] = 1.0
    a2_0 = 0.5 * (a2[0] + a2[0].T)
    name = f"fast_fit_{closure}_{d}d"

    def from_start(start: float) -> FastFit:
        ci, step_error, refinements, total_iterations = start, math.nan, 0, 0
        while True:
            h = max_step / 2**refinements
            n_sub = np.zeros(size - 1, dtype=np.int32)
            n_sub[: n - 1] = _substeps(t, rate, h)
            # numpy arguments: jnp.asarray would compile a small program per shape
            args = (np.float64(ci), np.float64(xi), a2_0, L, t_pad, n_sub, target, weight, table)
            out = exported_call(name, lambda: _program(closure, d), args)
            ci_j, a2_fit, r, J, loss, iterations, done, a2_half, secant = out
            total_iterations += int(iterations)
            ci = float(ci_j)
            r, J = np.asarray(r).ravel(), np.asarray(J).ravel()
            rss = float(loss)
            n_points = (n - 1) * iu.size
            jj = float(J @ J)
            stderr = (math.sqrt(rss / (n_points - 1) / jj) if n_points > 1 and jj > 0.0 and math.isfinite(rss)
                      else math.nan)
            e = 16.0 / 15.0 * (np.asarray(a2_fit) - np.asarray(a2_half))[1:, iu, ju] * np.asarray(weight)
            # curvature of the loss / 2 at the optimum: the last secant of its gradient, else J.J
            curv = float(secant) if math.isfinite(float(secant)) and float(secant) > 0.0 else jj
            step_error = abs(float(J @ e.ravel()) / curv) if curv > 0.0 else math.nan
            at_bound = ci == 0.0 and float(J @ r) >= 0.0
            if at_bound and float(J @ e.ravel()) >= 0.0:
                step_error = 0.0  # the step error pushes C_I further into the bound: the fit stays on it
            allowed = max(STEP_ERROR_SHARE * stderr if math.isfinite(stderr) else 0.0, FIT_RTOL * ci + FIT_ATOL)
            tol = admissible_tol(float(np.sum(n_sub)), xi, math.sqrt(2.0 * float(np.sum(D * D))) * float(t[-1] - t[0]))
            bad_record, cause = admissibility(np.asarray(a2_fit)[:n], tol)
            if refinements == MAX_REFINEMENTS:
                break
            # a trajectory outside the set: half the step (module notes); else the step error
            if bad_record < 0 and (not (step_error > allowed) or not math.isfinite(rss)):
                break
            refinements += 1
        h_used = float(np.max(np.diff(t) * rate / np.maximum(n_sub[: n - 1], 1)))
        converged, finite = bool(done), math.isfinite(rss)
        if bad_record >= 0:
            # the loss of every inadmissible trajectory is infinite, so this is the
            # start's, every trial having left the set too (or the check of the program
            # and the one here disagree by round-off at the tolerance)
            step = int(np.sum(n_sub[:bad_record]))
            message = (f"closure {closure}: a2 leaves the orientation tensors at t = {t[bad_record]:.6g} s "
                       f"(record {bad_record}, RK4 step {step} of {h_used:.3g}/γ̇): {cause}; "
                       f"at every C_I tried (C_I = {ci:.3g} last) and down to that step: no C_I reported")
            return FastFit(closure=closure, ci=math.nan, stderr=math.nan, residual_rms=math.nan, n_points=n_points,
                           success=False, at_bound=False, message=message, a2=np.asarray(a2_fit)[:n], step=h_used,
                           step_error=math.nan, iterations=total_iterations, admissible=False,
                           inadmissible_time=float(t[bad_record]), inadmissible_step=step, inadmissible_cause=cause)
        if not finite:
            message = "Folgar-Tucker blew up for every C_I tried (non-finite a2)"
        elif not converged:
            message = f"the fit stopped after {total_iterations} iterations without converging"
        else:
            message = f"converged in {total_iterations} steps"
            if at_bound:
                message += " (C_I held on its bound 0: the loss increases into C_I > 0)"
        if finite and step_error > allowed:
            message += f"; RK4 step error of C_I {step_error:.2g} above {allowed:.2g} at the smallest step {h_used:.3g}"
        return FastFit(closure=closure, ci=ci, stderr=stderr, residual_rms=math.sqrt(rss / n_points) if finite else math.nan,
                       n_points=n_points, success=converged and finite, at_bound=at_bound, message=message,
                       a2=np.asarray(a2_fit)[:n], step=h_used, step_error=step_error, iterations=total_iterations)


    fits = [from_start(start) for start in starts]
    ok = [f for f in fits if f.success]
    if len(fits) == 1 or not ok:
        return fits[0]
    best = min(ok, key=lambda f: f.residual_rms)
    # other optima: starts that ended elsewhere than the best (beyond 3 standard errors)
    apart = max(3.0 * best.stderr if math.isfinite(best.stderr) else 0.0, FIT_RTOL * best.ci + FIT_ATOL)
    others = [f for f in ok if abs(f.ci - best.ci) > apart]
    if not others:
        return best
    text = ", ".join(dict.fromkeys(f"{f.ci:.3g} (a2 RMS {f.residual_rms:.4g})" for f in others))
    return dataclasses.replace(best, message=f"{best.message}; the least misfit of the starts C_I = "
                               f"{', '.join(f'{c:g}' for c in starts)}: other optima at {text}")


def fit_flags(fits):
    """:func:`pyfold.seed_checks.flag_fits` for per-seed :class:`FastFit` results of
    :func:`fit_ci_rk4`: its steps are projected onto ``C_I >= 0``, so a fit on the bound
    returns exactly ``C_I = 0`` (any positive value is a measured one); there is no upper
    bound; a fit that did not succeed (not converged, or left the orientation tensors:
    ``C_I`` NaN) is flagged failed."""
    from pyfold.seed_checks import flag_fits

    return flag_fits([f.ci if f.success else math.nan for f in fits], 0.0, math.inf, 0.0, 0.0)
