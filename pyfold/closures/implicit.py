"""Fully symmetric implicit closures SIQ and SIHYB (Karl, Schneider & Böhlke 2023,
J. Non-Newtonian Fluid Mech. 318:105049).

Both write ``a4`` through an auxiliary symmetric tensor ``B`` coaxial with ``a2`` and
choose ``B`` *implicitly* so that the trace identity ``a4_ijkk = a2_ij`` holds exactly:

    SIQ:    a4 = S(B B)
    SIHYB:  a4 = (1 - k) L(B) + k S(B B),   k = hybrid weight (1 - 27 det a in 3-D)

with ``S`` the full symmetrisation and ``L(B)`` the linear closure applied to ``B``
(``-3 c1 S(d d) + 6 c2 S(d B)``, ``c1 = 1/((d+2)(d+4))``, ``c2 = 1/(d+4)``).
Contracting gives, per principal value ``mu`` of ``B`` and ``l`` of ``a2``, with
``T = tr B``, the quadratic

    (2k/3) mu^2 + ((1 - k) + k T/3) mu + (1 - k)(T - 1)/(d + 4) - l = 0,

and ``T`` is fixed by the scalar consistency condition ``sum_i mu_i(T) = T``, solved
here by a fixed number of Newton steps (the paper uses Newton too).

Near isotropy ``k -> 0`` and the published explicit root divides by ``k`` (the
"near-isotropic failure" of implicit hybrid closures; fiberoripy patches it with
``nan_to_num`` and a special case). Here the root is evaluated in the cancellation-free
form ``mu = -2c / (b + sqrt(b^2 - 4ac))``, which tends smoothly to the linear-closure
root ``mu = -c/b`` as ``k -> 0``: no division by ``k`` and no special case.

The paper treats 3-D; the derivation above is dimension-free and is also registered
in 2-D with the planar hybrid weight ``k = 1 - 4 det a`` (our extension, exact at
isotropy and for aligned fibres like the 3-D version).
"""
from __future__ import annotations

from pyfold._jax import jax, jnp
from pyfold.closures._basis import identity_like, sym_product
from pyfold.closures._spectral import spectral_function
from pyfold.closures.hybrid import hybrid_weight

#: Newton steps for the scalar T; the iteration converges quadratically from T = 1
#: (the exact value at isotropy for SIHYB), 12 steps reach round-off on valid a2.
NEWTON_STEPS = 12


def _roots(lam, params):
    """Principal values ``mu`` of ``B`` for eigenvalues ``lam`` (elementwise)."""
    trace_b, k, d = params
    k = k[..., None]
    trace_b = trace_b[..., None]
    qa = 2.0 * k / 3.0
    qb = (1.0 - k) + k * trace_b / 3.0
    qc = (1.0 - k) * (trace_b - 1.0) / (d + 4.0) - lam
    disc = jnp.maximum(qb**2 - 4.0 * qa * qc, 0.0)
    return -2.0 * qc / (qb + jnp.sqrt(disc))


def _solve_trace(lam: jax.Array, k: jax.Array, d: int) -> jax.Array:
    """``T = tr B`` with ``sum_i mu_i(T) = T``; Newton on the converged value is
    replaced by one differentiable step (implicit-function derivative)."""
    dd = jnp.asarray(float(d))

    def residual(t, lam_, k_):
        return jnp.sum(_roots(lam_, (t, k_, dd)), axis=-1) - t

    def newton(t, lam_, k_):
        r, dr = jax.jvp(lambda x: residual(x, lam_, k_), (t,), (jnp.ones_like(t),))
        return t - r / dr

    lam_c, k_c = jax.lax.stop_gradient(lam), jax.lax.stop_gradient(k)
    t = jnp.ones_like(k_c) * jnp.where(k_c > 0.5, 1.3, 1.0)
    t = jax.lax.fori_loop(0, NEWTON_STEPS, lambda _, x: newton(x, lam_c, k_c), t)
    t = jax.lax.stop_gradient(t)
    # One more Newton step with live inputs: at the root its derivative is exactly
    # dT = -(dR/dT)^-1 dR/d(inputs), the implicit-function theorem.
    r = residual(t, lam, k)
    dr = jax.lax.stop_gradient(jax.jvp(lambda x: residual(x, lam_c, k_c), (t,), (jnp.ones_like(t),))[1])
    return t - r / dr


def _implicit(a2: jax.Array, k: jax.Array) -> jax.Array:
    d = a2.shape[-1]
    a2 = 0.5 * (a2 + jnp.swapaxes(a2, -1, -2))
    # Eigenvalues only enter through symmetric functions (T) and through the
    # matrix function B, whose derivative is exact at repeated eigenvalues.
    lam = jnp.linalg.eigvalsh(a2)
    trace_b = _solve_trace(lam, k, d)
    b = spectral_function(_roots, a2, (trace_b, k, jnp.asarray(float(d))))
    eye = identity_like(a2)
    c1 = 1.0 / ((d + 2) * (d + 4))
    c2 = 1.0 / (d + 4)
    lin = -3.0 * c1 * sym_product(eye, eye) + 6.0 * c2 * sym_product(eye, b)
    kk = k[..., None, None, None, None]
    return (1.0 - kk) * lin + kk * sym_product(b, b)


def siq(a2: jax.Array) -> jax.Array:
    """Symmetric implicit quadratic closure SIQ: ``a4 = S(B B)`` with ``B`` coaxial with
    ``a2`` such that ``a4_ijkk = a2_ij`` (Karl, Schneider & Böhlke 2023, JNNFM 318:105049).

    Per principal value: ``mu_i = -T/4 + sqrt(T^2/16 + 3 l_i / 2)``, ``sum mu_i = T``.
    Fully symmetric, trace-exact, exact for aligned fibres and at isotropy. No fitted
    coefficients.
    """
    return _implicit(a2, jnp.ones(a2.shape[:-2], dtype=a2.dtype))


def sihyb(a2: jax.Array) -> jax.Array:
    """Symmetric implicit hybrid closure SIHYB:
    ``a4 = (1 - k) L(B) + k S(B B)``, ``k = 1 - 27 det a`` (3-D) / ``1 - 4 det a`` (2-D),
    ``B`` implicit so that ``a4_ijkk = a2_ij`` (Karl, Schneider & Böhlke 2023,
    JNNFM 318:105049). Reduces to the linear closure at isotropy (k = 0) and to SIQ
    for k = 1; robust at isotropy (see module notes). No fitted coefficients.
    """
    return _implicit(a2, hybrid_weight(a2))
