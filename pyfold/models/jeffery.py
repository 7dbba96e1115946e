"""Jeffery's equation: for the orientation tensor (with a closure) and exactly for vectors."""
from __future__ import annotations

import diffrax
import equinox as eqx
import numpy as np

from pyfold._jax import jax, jnp
from pyfold.errors import ConvergenceError, InputError
from pyfold.kinematics import ConstantGradient, velocity_gradient
from pyfold.models._base import ClosureModel, check_range
from pyfold.models._terms import flow_parts, rotation_term, stretching_term_contracted

__all__ = ["Jeffery", "jeffery_vectors"]


class Jeffery(ClosureModel):
    """Jeffery's equation for ``a2`` of non-interacting fibres (Jeffery 1922,
    Proc. R. Soc. A 102:161; tensor form Advani & Tucker 1987, J. Rheol. 31:751).

    ``Da/Dt = W.a - a.W + xi (D.a + a.D - 2 a4:D)``

    Only the closure approximates anything: with the exact ``a4`` (a
    ``TabulatedA4`` of a population) it is exact for a dilute suspension.

    Parameters
    ----------
    xi : float
        Shape factor in [-1, 1].
    closure : str | callable | TabulatedA4
    dim : int
        3 or 2.
    """


    def _rate(self, t, a2, L):
        D, W, _ = flow_parts(L)
        return rotation_term(a2, W) + stretching_term_contracted(a2, self.a4_contract(a2, D, t), D, self.xi)


@jax.jit
def _propagators_constant(A: jax.Array, t_rel: jax.Array) -> jax.Array:
    return jax.vmap(lambda s: jax.scipy.linalg.expm(s * A))(t_rel)


@eqx.filter_jit
def _propagators_ode(grad, xi, t_eval, rtol, atol, max_steps):
    d = grad.dim

    def field(t, B, args):
        L = grad(t)
        D = 0.5 * (L + L.T)
        W = 0.5 * (L - L.T)
        return (W + xi * D) @ B

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        diffrax.Tsit5(),
        t0=t_eval[0],
        t1=t_eval[-1],
        dt0=None,
        y0=jnp.eye(d),
        saveat=diffrax.SaveAt(ts=t_eval),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        max_steps=max_steps,
        throw=False,
    )
    return sol.ys, jnp.asarray(sol.result._value)


def jeffery_vectors(p0, L, t_eval, xi, *, rtol: float = 1e-10, atol: float = 1e-12, max_steps: int = 100_000):
    """Orientation of individual fibres under Jeffery's equation.

    ``dp/dt = W.p + xi (D.p - (p.D.p) p)`` (Jeffery 1922) is solved through its
    linear lift: ``q' = (W + xi D) q`` with ``p = q/|q|`` satisfies it exactly,
    so ``p(t) = B(t) p0 / |B(t) p0|`` with the propagator ``B' = (W + xi D) B``,
    ``B(t0) = I``.

    * constant ``L``: ``B(t) = expm((t - t0)(W + xi D))``, exact to round-off
      (scaling and squaring Pade, :func:`jax.scipy.linalg.expm`);
    * callable ``L(t)``: the ``d x d`` propagator ODE is integrated with diffrax
      Tsit5 at ``rtol``/``atol`` (the only error), then applied to every vector.

    Either way ``|p| = 1`` exactly (to round-off) and the cost of the ODE does not
    grow with the number of fibres.

    Parameters
    ----------
    p0 : array (N, d)
        Initial directions (normalised here; zero vectors are rejected).
    L : array (d, d) or callable ``L(t)``
        Velocity gradient [1/s].
    t_eval : array (nt,)
        Output times [s], strictly increasing; ``t_eval[0]`` is the initial time.
    xi : float
        Shape factor ``(beta^2-1)/(beta^2+1)``.

    Returns
    -------
    p : array (nt, N, d)

    Raises
    ------
    InputError
        Bad shapes, zero vectors, non-increasing times, ``|xi| > 1``.
    ConvergenceError
        The propagator ODE failed (time-dependent ``L`` only).
    """
    p0 = np.asarray(p0, dtype=np.float64)
    if p0.ndim != 2 or p0.shape[1] not in (2, 3):
        raise InputError(f"p0: expected shape (N, d) with d in {{2, 3}}, got {p0.shape}")
    norms = np.linalg.norm(p0, axis=1)
    if not np.all(np.isfinite(p0)) or np.any(norms == 0.0):
        raise InputError("p0: vectors must be finite and non-zero")
    p0 = jnp.asarray(p0 / norms[:, None])
    t = np.asarray(t_eval, dtype=np.float64)
    if t.ndim != 1 or t.size < 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
        raise InputError(f"t_eval: expected a 1-D strictly increasing array of finite times, got {t!r}")
    check_range("xi", xi, -1.0, 1.0)
    grad = velocity_gradient(L, dim=p0.shape[1])
    xi = jnp.asarray(xi, dtype=jnp.float64)
    t = jnp.asarray(t)
    if isinstance(grad, ConstantGradient):
        D, W, _ = flow_parts(grad.L)
        # pad the time axis to a power of two (at least 64): one compilation of the
        # vmapped expm (seconds) then serves every t_eval length up to that size
        n = t.shape[0]
        size = max(64, 1 << max(n - 1, 1).bit_length())
        t_rel = jnp.pad(t - t[0], (0, size - n))
        return _normalised_images(_propagators_constant(W + xi * D, t_rel)[:n], p0)
    else:
        if t.shape[0] < 2:
            return jnp.broadcast_to(p0, (1,) + p0.shape)
        B, status = _propagators_ode(grad, xi, t, float(rtol), float(atol), int(max_steps))
        if int(status) != 0:
            raise ConvergenceError(f"jeffery_vectors: propagator ODE failed with diffrax status {int(status)}")
    return _normalised_images(B, p0)


@jax.jit
def _normalised_images(B, p0):
    q = jnp.einsum("tij,nj->tni", B, p0)
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)
