"""Estimators of the Folgar-Tucker interaction coefficient ``C_I`` from a direct simulation.

Folgar-Tucker (Folgar & Tucker 1984; tensor form Advani & Tucker 1987), ``d = 3``
in space, ``d = 2`` in the plane:

    Da2/Dt = W.a2 - a2.W + xi (D.a2 + a2.D - 2 a4:D) + 2 C_I gamma_dot (I - d a2)

with ``gamma_dot = sqrt(2 D:D)``. Three ways to get ``C_I`` from a simulation:

(a) :func:`pyfold.fit.fit_parameters`: integrate the model and fit its ``a2(t)`` to the
    simulated one (per closure, or with the simulation's own ``a4`` prescribed in
    time: open loop, errors accumulate).
(b) :func:`ci_steady_state_match`: the ``C_I`` whose steady state with a closure
    (:func:`pyfold.fit.steady_state_a2`) reproduces the simulation's steady ``a2``.
(c) :func:`ci_rate_regression`: no ODE. At every record the simulation gives
    ``a2``, ``a4`` and (by finite differences) ``da2/dt``; the equation is *linear* in
    ``C_I``, so with

        R = da2/dt - J,   J = W.a2 - a2.W + xi (D.a2 + a2.D - 2 a4:D),
        X = 2 gamma_dot (I - d a2),

    ``C_I`` is the least-squares slope of ``R`` on ``X`` over all records and
    independent components: ``C_I = sum X R / sum X^2``.

References
----------
* Folgar, F. & Tucker, C. L. (1984). Orientation behavior of fibers in concentrated
  suspensions. *J. Reinf. Plast. Compos.* 3:98-119.
* Advani, S. G. & Tucker, C. L. (1987). The use of tensors to describe and predict
  fiber orientation in short fiber composites. *J. Rheol.* 31:751-784.
* Flyvbjerg, H. & Petersen, H. G. (1989). *J. Chem. Phys.* 91:461; Jonsson, M. (2018).
  *Phys. Rev. E* 98:043304 (blocking, used for the serial correlation of the
  regression scores; see :mod:`pyfold.steady_state`).
* Fornberg, B. (1988). Generation of finite difference formulas on arbitrarily
  spaced grids. *Math. Comput.* 51:699-706 (the three-point derivative).
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Sequence

import numpy as np

from pyfold.errors import InputError
from pyfold.steady_state import blocking_stderr

__all__ = [
    "RateRegression",
    "SteadyMatch",
    "ci_rate_regression",
    "ci_steady_state_match",
    "three_point_derivative",
    "independent_components",
]


def independent_components(d: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the independent components of a symmetric unit-trace tensor:
    the upper triangle without ``(d-1, d-1)`` (5 in 3-D, 2 in 2-D)."""
    iu, ju = np.triu_indices(d)
    keep = ~((iu == d - 1) & (ju == d - 1))
    return iu[keep], ju[keep]


def three_point_derivative(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``dy/dt`` at the interior samples ``1 .. n-2``, second order on any grid.

    The derivative of the parabola through three neighbours (Fornberg 1988),
    with ``h- = t_k - t_{k-1}``, ``h+ = t_{k+1} - t_k``:

        y'_k = [h-^2 y_{k+1} - h+^2 y_{k-1} + (h+^2 - h-^2) y_k] / (h- h+ (h- + h+)),

    which is the centred difference ``(y_{k+1} - y_{k-1}) / 2h`` on a uniform grid.
    Its error is ``-(h- h+ / 6) y'''`` plus higher order: O(h^2).
    """
    h = np.diff(t)
    shape = (-1,) + (1,) * (y.ndim - 1)
    hm, hp = h[:-1].reshape(shape), h[1:].reshape(shape)
    return (hm**2 * y[2:] - hp**2 * y[:-2] + (hp**2 - hm**2) * y[1:-1]) / (hm * hp * (hm + hp))


@dataclasses.dataclass(frozen=True)
class RateRegression:
    """Outcome of :func:`ci_rate_regression`.

    Attributes
    ----------
    ci : float
        Least-squares ``C_I``.
    stderr : float
        Its standard error, corrected for the serial correlation of the residuals
        (blocking of the per-record scores, see :func:`ci_rate_regression`).
    stderr_iid : float
        The naive standard error assuming independent residuals (for comparison).
    residual_rms : float
        RMS of ``R - C_I X`` over the components and records used [1/s].
    n_records : int
        Records used (interior records inside the window).
    block_size : int
        Block size of the score series at which the error was read.
    t_start, t_end : float
        Time span of the records used.
    """

    ci: float
    stderr: float
    stderr_iid: float
    residual_rms: float
    n_records: int
    block_size: int
    t_start: float
    t_end: float


def _check_series(t, a2, a4):
    tv = np.asarray(t, dtype=np.float64)
    if tv.ndim != 1 or tv.size < 3 or not np.all(np.isfinite(tv)) or np.any(np.diff(tv) <= 0.0):
        raise InputError(f"t: expected a finite, strictly increasing 1-D array of >= 3 samples, got shape {tv.shape}")
    a2v = np.asarray(getattr(a2, "values", a2), dtype=np.float64)
    if a2v.ndim != 3 or a2v.shape[0] != tv.size or a2v.shape[1] != a2v.shape[2] or a2v.shape[1] not in (2, 3):
        raise InputError(f"a2: expected shape (nt={tv.size}, d, d) with d in {{2, 3}}, got {a2v.shape}")
    d = a2v.shape[1]
    a4v = np.asarray(getattr(a4, "values", a4), dtype=np.float64)
    if a4v.shape != (tv.size,) + (d,) * 4:
        raise InputError(f"a4: expected shape ({tv.size}, {d}, {d}, {d}, {d}), got {a4v.shape}")
    if not np.all(np.isfinite(a2v)):
        raise InputError("a2: contains NaN or infinity")
    if not np.all(np.isfinite(a4v)):
        raise InputError("a4: contains NaN or infinity")
    return tv, a2v, a4v, d


def _check_L(L, d: int) -> np.ndarray:
    Lv = np.asarray(L, dtype=np.float64)
    if Lv.shape != (d, d) or not np.all(np.isfinite(Lv)):
        raise InputError(f"L: expected a finite constant velocity gradient of shape ({d}, {d}), got {Lv.shape}")
    D = 0.5 * (Lv + Lv.T)
    if not math.sqrt(2.0 * float(np.sum(D * D))) > 0.0:
        raise InputError("L: needs a deforming flow (shear rate sqrt(2 D:D) > 0)")
    return Lv


def _check_xi(xi) -> float:
    x = float(xi)
    if not (-1.0 <= x <= 1.0):
        raise InputError(f"xi: shape factor must lie in [-1, 1], got {xi!r}")
    return x


def ci_rate_regression(
    t,
    a2,
    a4,
    L,
    xi: float,
    *,
    window: tuple[float, float] | None = None,
) -> RateRegression:
    """``C_I`` by linear regression of the Folgar-Tucker rate on its diffusion term.

    No ODE is integrated. At each interior record ``k`` (inside ``window``):

    * ``da2/dt`` by the three-point (centred, second-order) derivative of the
      records, :func:`three_point_derivative`;
    * ``J = W.a2 - a2.W + xi (D.a2 + a2.D - 2 a4:D)`` with the record's own ``a4``;
    * ``R = da2/dt - J``, ``X = 2 gamma_dot (I - d a2)``.

    Folgar-Tucker says ``R = C_I X`` (Folgar & Tucker 1984; Advani & Tucker 1987);
    the least-squares solution over the independent components of a symmetric
    unit-trace tensor (upper triangle without ``a_dd``: 5 in 3-D) and all records is

        C_I = sum_k s_k / sum_kc X_kc^2,   s_k = sum_c X_kc R_kc .

    **Accuracy on exact data.** The derivative error is ``-(h- h+ / 6) a2'''``, so
    ``C_I`` on a trajectory of the model itself is off by
    ``sum X (h^2/6) a2''' / sum X^2 = O(h^2)`` in the record spacing ``h``.

    **Standard error.** The residuals ``e_kc = R_kc - C_I X_kc`` are serially
    correlated (fluctuations of a simulation last some strain; differencing noisy
    records adds a lag-2 anticorrelation). Writing ``C_I - C_true =
    sum_k u_k / sum X^2`` with the score ``u_k = sum_c X_kc e_kc`` (mean zero at the
    estimate), ``Var C_I = n^2 Var(mean u) / (sum X^2)^2``, and ``Var(mean u)`` is
    estimated by blocking (batch means with the block size chosen by Jonsson's
    2018 test, :func:`pyfold.steady_state.blocking_stderr`), i.e. a batch-means
    estimate of the long-run variance, which is what a HAC estimator targets.
    When the residuals are dominated by the differencing noise of noisy records,
    the centred differences telescope (their sum depends on the end records only)
    and this estimate is conservative: on four seeds of a concentrated
    contacts-only simulation the per-seed s.e. (1.4e-4 ... 2.2e-4) was about four
    times the seed-to-seed standard deviation (3.6e-5). Quote the spread over
    independent runs when there are several.

    Parameters
    ----------
    t : array (nt,)
        Record times [s], strictly increasing (non-uniform allowed).
    a2 : array (nt, d, d)
        Second-order orientation tensor at the records.
    a4 : array (nt, d, d, d, d)
        Fourth-order tensor at the records (the simulation's own, or a closure's).
    L : array (d, d)
        Constant velocity gradient ``L_ij = du_i/dx_j`` [1/s].
    xi : float
        Shape factor ``(beta^2 - 1)/(beta^2 + 1)``.
    window : (float, float), optional
        Use only interior records with ``window[0] <= t <= window[1]`` (e.g. the
        stationary part, or the transient). The neighbours used by the derivative
        may lie outside.

    Returns
    -------
    RateRegression

    Raises
    ------
    InputError
        Naming the argument: bad shapes, non-finite values, non-increasing ``t``,
        a velocity gradient that does not deform, ``xi`` outside [-1, 1], a window
        holding fewer than 8 records, or ``X = 0`` at every record.
    """
    tv, a2v, a4v, d = _check_series(t, a2, a4)
    Lv = _check_L(L, d)
    xi = _check_xi(xi)
    D, W = 0.5 * (Lv + Lv.T), 0.5 * (Lv - Lv.T)
    gamma_dot = math.sqrt(2.0 * float(np.sum(D * D)))
    rate = three_point_derivative(tv, a2v)  # records 1 .. nt-2
    a = a2v[1:-1]
    a4D = np.einsum("nijkl,kl->nij", a4v[1:-1], D)
    J = W @ a - a @ W + xi * (D @ a + a @ D - 2.0 * a4D)
    R = rate - J
    X = 2.0 * gamma_dot * (np.eye(d) - d * a)
    tk = tv[1:-1]
    keep = np.ones(tk.size, dtype=bool)
    if window is not None:
        try:
            lo, hi = (float(w) for w in window)
        except (TypeError, ValueError):
            raise InputError(f"window: expected (t_start, t_end), got {window!r}") from None
        if not lo < hi:
            raise InputError(f"window: need t_start < t_end, got {window!r}")
        keep = (tk >= lo) & (tk <= hi)
    n = int(keep.sum())
    if n < 8:
        raise InputError(f"window: {n} interior records inside {window!r}; need at least 8")
    iu, ju = independent_components(d)
    Xc, Rc = X[keep][:, iu, ju], R[keep][:, iu, ju]
    sxx = float(np.sum(Xc * Xc))
    if not sxx > 0.0:
        raise InputError("a2: X = 2 gamma_dot (I - d a2) vanishes at every record (isotropic); C_I undetermined")
    ci = float(np.sum(Xc * Rc)) / sxx
    e = Rc - ci * Xc
    scores = np.sum(Xc * e, axis=1)
    m = e.size
    stderr_iid = math.sqrt(float(np.sum(e * e)) / max(m - 1, 1) / sxx)
    se_mean, block = blocking_stderr(scores) if n >= 4 else (math.nan, 1)
    return RateRegression(
        ci=ci,
        stderr=n * se_mean / sxx,
        stderr_iid=stderr_iid,
        residual_rms=math.sqrt(float(np.mean(e * e))),
        n_records=n,
        block_size=int(block),
        t_start=float(tk[keep][0]),
        t_end=float(tk[keep][-1]),
    )


@dataclasses.dataclass(frozen=True)
class SteadyMatch:
    """Outcome of :func:`ci_steady_state_match`.

    Attributes
    ----------
    ci : float
        The matching ``C_I``.
    stderr : float
        Its standard error propagated from the standard error of the steady ``a2``
        (``nan`` when none was given).
    a2_model : numpy.ndarray (d, d)
        Steady state of Folgar-Tucker with the closure at ``ci``.
    residual_rms : float
        RMS over the independent components of ``a2_model - a2_steady``: what one
        ``C_I`` cannot match (the closure's and the model's misfit).
    gradient : numpy.ndarray (m,)
        ``d a2_ss / d C_I`` on the independent components at ``ci``.
    sensitivity : numpy.ndarray (m,)
        ``d C_I / d a2_steady`` on the independent components.
    closure : str
        Closure used.
    method : str
        ``"least_squares"``, ``"least_squares a_ij a_kl"`` (a subset of components)
        or ``"root a_ij"``.
    on_bound : bool
        The least-squares optimum lies on a search bound: no interior ``C_I``
        matches better, usually because the target lies outside the set of
        Folgar-Tucker steady states (see the notes of :func:`ci_steady_state_match`).
    span : numpy.ndarray (2, m), optional
        Steady state on the independent components at the two search bounds
        (row 0: ``bounds[0]``, row 1: ``bounds[1]``), to compare with the target.
    """

    ci: float
    stderr: float
    a2_model: np.ndarray
    residual_rms: float
    gradient: np.ndarray
    sensitivity: np.ndarray
    closure: str
    method: str
    on_bound: bool = False
    span: np.ndarray | None = None


def ci_steady_state_match(
    a2_steady,
    closure,
    xi: float,
    L,
    *,
    a2_stderr=None,
    component: tuple[int, int] | None = None,
    bounds: tuple[float, float] = (1e-6, 0.5),
    xtol: float = 1e-10,
    components: "Sequence[tuple[int, int]] | None" = None,
) -> SteadyMatch:
    """``C_I`` whose Folgar-Tucker steady state with ``closure`` matches a steady ``a2``.

    The steady state ``a_ss(C_I)`` of ``Da2/Dt = W.a2 - a2.W + xi (D.a2 + a2.D -
    2 a4:D) + 2 C_I gamma_dot (I - d a2)`` (Folgar & Tucker 1984; Advani & Tucker
    1987) with ``a4 = closure(a2)`` is computed by :func:`pyfold.fit.steady_state_a2`.

    * ``component=None`` (default): least squares over the independent components
      (upper triangle without ``a_dd``), ``min sum_c (a_ss,c(C_I) - a_c)^2``, by a
      bounded 1-D minimisation over ``log C_I`` (Brent, ``scipy.optimize.
      minimize_scalar``);
    * ``component=(i, j)``: the root of ``a_ss,ij(C_I) = a_ij`` (Brent's method on
      ``bounds``), as in Tucker's ``fitCI`` for ``a11``;
    * ``components=[(i, j), ...]``: least squares over those components only (e.g.
      ``[(0, 0), (1, 1)]``, the in-plane diagonal that moulding codes are judged on).

    **When the optimum lies on a bound.** One ``C_I`` moves every component along
    one curve ``a_ss(C_I)``. In simple shear that curve starts, as ``C_I -> 0+``,
    at the closure's fixed point of Jeffery's equation (``a_xy -> 0``, ``a_xx``
    at its largest: about 0.785 with IBOF and 0.777 with FEC at ``xi = 0.97``) and
    loses alignment as ``C_I`` grows. A target more aligned than that fixed point,
    or with ``a_xy <= 0``, is reached by no ``C_I > 0``: the least-squares optimum
    is then the lower bound (``on_bound``; a ``RuntimeWarning`` says so) and the
    root of ``a_xx`` is not bracketed (``InputError``). ``span`` gives the steady
    states at both bounds so the caller can say which components are out of reach.

    **Error.** At the optimum ``g = a_ss'(C_I)`` (central differences in
    ``log C_I``, relative step 1e-3 on a state converged to 1e-13). The implicit
    function theorem on the normal equation ``(a_ss - a).g = 0``, to first
    (Gauss-Newton) order, gives ``dC_I/da = g / (g.g)`` (root: ``1 / g_ij`` on the
    chosen component); with the standard errors ``s_c`` of the steady ``a2``
    (independent across components) ``se(C_I) = sqrt(sum_c (dC_I/da_c)^2 s_c^2)``.
    A full covariance ``(m, m)`` of the independent components may be given instead.

    Parameters
    ----------
    a2_steady : array (d, d)
        Steady orientation tensor (e.g. :func:`pyfold.steady_state.
        detect_steady_state` ``.mean`` of a simulation's ``a2``).
    closure : str or callable
        Closure name (:func:`pyfold.closures.available`) or ``f(a2)``.
    xi : float
        Shape factor in [-1, 1].
    L : array (d, d)
        Constant velocity gradient [1/s].
    a2_stderr : array (d, d) or (m, m), optional
        Standard errors of ``a2_steady`` per component, or the covariance of its
        independent components.
    component : (int, int), optional
        Match one component by root finding instead of least squares.
    components : sequence of (int, int), optional
        Least squares over these components only (each ``i <= j`` or its mirror;
        ``(d-1, d-1)`` allowed: ``a_dd = 1 - `` the other diagonals). Not together
        with ``component``.
    bounds : (float, float)
        Search interval for ``C_I`` (> 0).
    xtol : float
        Tolerance on ``log C_I`` (least squares) or ``C_I`` (root).

    Returns
    -------
    SteadyMatch

    Raises
    ------
    InputError
        Bad shapes or values (named), a root not bracketed by ``bounds``.
    """
    import equinox as eqx
    import scipy.optimize

    from pyfold._jax import jnp
    from pyfold.errors import InadmissibleOrientationWarning
    from pyfold.fit import steady_state_a2
    from pyfold.models import FolgarTucker
    from pyfold.tensors import check_orientation_tensor

    a = np.asarray(getattr(a2_steady, "values", a2_steady), dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] not in (2, 3):
        raise InputError(f"a2_steady: expected shape (d, d) with d in {{2, 3}}, got {a.shape}")
    a = check_orientation_tensor(0.5 * (a + a.T), name="a2_steady", tol=1e-6)
    d = a.shape[0]
    Lv = _check_L(L, d)
    xi = _check_xi(xi)
    lo, hi = (float(b) for b in bounds)
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise InputError(f"bounds: need 0 < lo < hi < inf, got {bounds!r}")
    iu, ju = independent_components(d)
    m = iu.size
    cov = None
    if a2_stderr is not None:
        s = np.asarray(getattr(a2_stderr, "values", a2_stderr), dtype=np.float64)
        if s.shape == (d, d):
            cov = np.diag(s[iu, ju] ** 2)
        elif s.shape == (m, m):
            cov = 0.5 * (s + s.T)
        else:
            raise InputError(f"a2_stderr: expected shape ({d}, {d}) or ({m}, {m}), got {s.shape}")
        if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) < 0):
            raise InputError("a2_stderr: must be finite and >= 0")
    if component is not None:
        try:
            ci_, cj_ = (int(c) for c in component)
        except (TypeError, ValueError):
            raise InputError(f"component: expected a pair (i, j), got {component!r}") from None
        if not (0 <= ci_ < d and 0 <= cj_ < d):
            raise InputError(f"component: indices must lie in [0, {d}), got {component!r}")
        ci_, cj_ = min(ci_, cj_), max(ci_, cj_)
    else:
        ci_ = cj_ = -1
    if components is not None:
        if component is not None:
            raise InputError("components: give either component (root) or components (least squares), not both")
        try:
            pairs = sorted({(min(int(p), int(q)), max(int(p), int(q))) for p, q in components})
        except (TypeError, ValueError):
            raise InputError(f"components: expected pairs (i, j), got {components!r}") from None
        if not pairs or any(not (0 <= p < d and 0 <= q < d) for p, q in pairs):
            raise InputError(f"components: need >= 1 pair with indices in [0, {d}), got {components!r}")
        sel_i = np.array([p for p, _ in pairs])
        sel_j = np.array([q for _, q in pairs])
        sel_label = " ".join(f"a_{p}{q}" for p, q in pairs)
    else:
        sel_i, sel_j, sel_label = iu, ju, ""
    if isinstance(closure, str):
        from pyfold.closures import resolve

        resolve(closure)  # validates the name
        label = closure.strip().lower()
    else:
        label = getattr(closure, "__name__", type(closure).__name__)
    base = FolgarTucker(ci=0.01, xi=xi, closure=closure, dim=d)
    cache: dict[float, np.ndarray] = {}

    def a_ss(c: float) -> np.ndarray:
        if c not in cache:
            model = eqx.tree_at(lambda mm: mm.ci, base, jnp.asarray(c))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", InadmissibleOrientationWarning)
                cache[c] = np.asarray(steady_state_a2(model, Lv))
        return cache[c]

    target = a[iu, ju]
    if component is None:
        sel_target = a[sel_i, sel_j]

        def loss_at(c: float) -> float:
            r = a_ss(c)[sel_i, sel_j] - sel_target
            return float(r @ r)

        res = scipy.optimize.minimize_scalar(
            lambda u: loss_at(math.exp(u)), bounds=(math.log(lo), math.log(hi)), method="bounded",
            options={"xatol": xtol},
        )
        ci = float(math.exp(res.x))
        # Brent's bounded search never evaluates the bounds themselves; it stops within
        # a few times its tolerance sqrt(eps) |u| + xtol of an optimum on a bound
        # (scipy's fminbound rule), where the loss is flat to round-off (measured:
        # |u - u_bound| = 3e-6 with OPENBLAS_CORETYPE=Prescott, beyond that tolerance).
        # A C_I within a relative 1e-4 of a bound, or a bound that is better, is the bound.
        for edge in (lo, hi):
            ue = math.log(edge)
            near = abs(res.x - ue) <= max(10.0 * (math.sqrt(np.finfo(np.float64).eps) * abs(ue) + xtol), 1e-4)
            if near or loss_at(edge) < loss_at(ci):
                ci = edge
        method = "least_squares" + (f" {sel_label}" if sel_label else "")
    else:
        f = lambda c: float(a_ss(c)[ci_, cj_] - a[ci_, cj_])  # noqa: E731
        f_lo, f_hi = f(lo), f(hi)
        if f_lo * f_hi > 0:
            raise InputError(
                f"a2_steady: a_{ci_}{cj_} = {a[ci_, cj_]:.6g} is not reached for C_I in {bounds} with closure "
                f"{label!r} (steady a_{ci_}{cj_} spans [{f_lo + a[ci_, cj_]:.6g}, {f_hi + a[ci_, cj_]:.6g}])"
            )
        ci = float(scipy.optimize.brentq(f, lo, hi, xtol=xtol * lo, rtol=1e-12))
        method = f"root a_{ci_}{cj_}"
    step = 1e-3
    g = (a_ss(ci * math.exp(step))[iu, ju] - a_ss(ci * math.exp(-step))[iu, ju]) / (
        ci * (math.exp(step) - math.exp(-step))
    )
    if component is None:
        # Gauss-Newton on the selected components only; zero on the others.
        sel = np.array([int(np.flatnonzero((iu == p) & (ju == q))[0]) if not (p == q == d - 1) else -1
                        for p, q in zip(sel_i, sel_j)])
        gs = np.zeros(m)
        if components is None:
            gs = g.copy()
        else:
            diag = np.flatnonzero(iu == ju)
            for k in sel:
                if k >= 0:
                    gs[k] += g[k]
            if np.any(sel < 0):  # a_dd = 1 - sum of the other diagonals: d a_dd / d a_kk = -1
                g_dd = -float(np.sum(g[diag]))
                gs[diag] += -g_dd
        sens = gs / float(g @ gs) if float(g @ gs) != 0.0 else np.zeros(m)
    else:
        k = int(np.flatnonzero((iu == ci_) & (ju == cj_))[0]) if not (ci_ == cj_ == d - 1) else None
        sens = np.zeros(m)
        if k is not None:
            sens[k] = 1.0 / g[k]
        else:  # a_dd = 1 - sum of the other diagonals
            diag = np.flatnonzero(iu == ju)
            g_dd = -float(np.sum(g[diag]))
            sens[diag] = -1.0 / g_dd
    stderr = math.sqrt(float(sens @ cov @ sens)) if cov is not None else math.nan
    model_a = a_ss(ci)
    resid = model_a[iu, ju] - target
    on_bound = bool(ci <= lo * (1 + 1e-6) or ci >= hi * (1 - 1e-6)) if component is not None else ci in (lo, hi)
    span = np.stack([a_ss(lo)[iu, ju], a_ss(hi)[iu, ju]])
    if on_bound:
        warnings.warn(f"ci_steady_state_match: C_I = {ci:.3e} on the search bound {bounds} (closure {label!r}): "
                      "the target is outside the Folgar-Tucker steady states reached in between "
                      "(see SteadyMatch.span)", RuntimeWarning, stacklevel=2)
    return SteadyMatch(
        ci=ci,
        stderr=stderr,
        a2_model=model_a,
        residual_rms=math.sqrt(float(np.mean(resid**2))),
        gradient=g,
        sensitivity=sens,
        closure=label,
        method=method,
        on_bound=on_bound,
        span=span,
    )
