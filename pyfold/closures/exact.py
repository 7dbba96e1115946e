"""Exact closure for Jeffery's equation (Montgomery-Smith, Jack & Smith 2011), the
closure behind the fast exact closure FEC.

Physics. Without diffusion, fibres that start isotropic and follow Jeffery's
equation stay distributed as an *angular central Gaussian*: ``p = x/|x|`` with
``x ~ N(0, C)``, ``C = B B^T``, ``B = exp(t (W + lambda D))`` for a constant gradient
(Montgomery-Smith, Jack & Smith 2011, J. Fluid Mech. 680:321, "Exact tensor closures
for the three-dimensional Jeffery's equation"). Both a2 and a4 are then functions
of ``C`` alone, so a4 is an exact function of a2: the *exact closure*. The fast exact
closure (Montgomery-Smith, Jack & Smith 2011, J. Non-Newtonian Fluid Mech.
166:343, "The Fast Exact Closure for Jeffery's equation with diffusion") evolves
``C`` (or its inverse) together with a2 instead of inverting a2 -> C at each step,
and keeps the same a2 -> a4 map when diffusion is added. Through the contract
``a4 = f(a2)`` this module provides that map.

Formulation used here (eigenvector-free, so it is differentiable everywhere,
including isotropy). From ``1/|x|^2 = int_0^inf exp(-s|x|^2) ds`` and the Gaussian
moments, with ``K(s) = C (I + 2 s C)^-1`` and ``g(s) = det(I + 2 s C)^(-1/2)``,

    a2 = int_0^inf g(s) K(s) ds,
    a4 = 3 int_0^inf s g(s) S(K(s) K(s)) ds,

where ``S`` is the full symmetrisation. These are the matrix forms of the Carlson
``R_D`` expressions of the paper (in the principal frame
``a_i = (1/3) sqrt(det C^-1) R_D(1/c_j, 1/c_k, 1/c_i)`` and
``A_iijj = (c_i a_j - c_j a_i) / (2 (c_i - c_j))``); they are evaluated by a
double-exponential (sinh) quadrature in ``log s`` (129 nodes), accurate to ~1e-14 for
valid a2 and exact for singular ``C`` (aligned or planar states). The inverse
problem a2 -> C is solved with ``C = M^2`` (``M`` coaxial with a2, ``tr M = 1``). In
2-D ``M = a2`` exactly (planar ACG: ``a_i = sqrt(c_i) / (sqrt(c_1) + sqrt(c_2))``) and
is used directly; in 3-D ``M ~ a2`` starts a fixed number of Gauss-Newton steps on
the principal values in the (derivative-free) principal frame of a2, followed by
one implicit-function step on all components that carries the exact derivative
(rotation equivariance makes the fixed frame harmless, also at repeated
eigenvalues). The same formulas hold in 2-D, where the result reduces to the planar
natural closure (``A_1122 = a1 a2 / 2``).

Derivative on the boundary. Where a2 has a zero eigenvalue (aligned fibres, planar
states in 3-D) only one-sided derivatives exist, ``a2`` being ~ ``sqrt(c)`` there. The
values stay exact, and the derivative finite, but it is *not* that one-sided
derivative: in 3-D it comes out of the damped normal equations below, in 2-D out of
the quadrature at singular ``C``, and in both it changes by O(1) under round-off
perturbations of a2 (measured). Elsewhere it is exact (checked against central
differences in the tests).
"""
from __future__ import annotations

import numpy as np

from pyfold._jax import jax, jnp
from pyfold.closures._basis import sym_product
from pyfold.tensors import det

# Double-exponential nodes: s = exp(A sinh t), t in [-T, T] with step H.
_T, _H, _A = 4.0, 1.0 / 16.0, 3.0
_t = np.arange(-_T, _T + 0.5 * _H, _H)
_S = np.exp(_A * np.sinh(_t))
_W = _H * _A * np.cosh(_t) * _S

#: Gauss-Newton steps for a2 -> C; converged to round-off after ~6 on valid a2.
NEWTON_STEPS = 10
#: Relative Levenberg-Marquardt damping of the Gauss-Newton normal matrix. It only
#: matters where J^T J is singular (a zero eigenvalue of a2): there the value of the
#: closure is still exact, but its derivative is finite and not meaningful (see the
#: module notes on the boundary).
DAMPING = 1e-12


def _adjugate(m: jax.Array) -> jax.Array:
    """Adjugate of (..., 2, 2) / (..., 3, 3) symmetric matrices, written out: far cheaper
    to compile and differentiate than a batched LU solve."""
    if m.shape[-1] == 2:
        return jnp.stack(
            [jnp.stack([m[..., 1, 1], -m[..., 0, 1]], -1), jnp.stack([-m[..., 1, 0], m[..., 0, 0]], -1)], -2
        )
    rows = []
    for i in range(3):
        row = []
        for j in range(3):
            # cofactor of (j, i): transpose of the cofactor matrix
            r = [k for k in range(3) if k != j]
            c = [k for k in range(3) if k != i]
            minor = m[..., r[0], c[0]] * m[..., r[1], c[1]] - m[..., r[0], c[1]] * m[..., r[1], c[0]]
            row.append((-1.0) ** (i + j) * minor)
        rows.append(jnp.stack(row, -1))
    return jnp.stack(rows, -2)


def _kernel(c: jax.Array):
    d = c.shape[-1]
    s = jnp.asarray(_S)[:, None, None]
    m = jnp.eye(d) + 2.0 * s * c
    det_m = det(m)
    # K = C (I + 2sC)^-1 = C adj(m) / det(m); det(m) >= 1 for PSD C.
    k = jnp.einsum("ik,nkj->nij", c, _adjugate(m)) / det_m[:, None, None]
    return k, det_m**-0.5


def acg_a2(c: jax.Array) -> jax.Array:
    """Second moment of the angular central Gaussian with covariance ``c`` (d, d)."""
    k, g = _kernel(c)
    return jnp.einsum("n,nij->ij", jnp.asarray(_W) * g, k)


def acg_a4(c: jax.Array) -> jax.Array:
    """Fourth moment of the angular central Gaussian with covariance ``c`` (d, d)."""
    k, g = _kernel(c)
    return 3.0 * jnp.einsum("n,nijkl->ijkl", jnp.asarray(_W * _S) * g, sym_product(k, k))


def _acg_a2_principal(c: jax.Array) -> jax.Array:
    """Principal values of :func:`acg_a2` for a *diagonal* covariance ``diag(c)``:
    ``a_i = int g(s) c_i / (1 + 2 s c_i) ds``, ``g = prod_j (1 + 2 s c_j)^(-1/2)``.
    Elementwise, so the Gauss-Newton iteration below is cheap to compile and run."""
    q = 1.0 + 2.0 * jnp.asarray(_S)[:, None] * c[None, :]
    g = jnp.prod(q, axis=-1) ** -0.5
    return jnp.einsum("n,nd->d", jnp.asarray(_W) * g, c / q)


def _unpack(x: jax.Array, d: int) -> jax.Array:
    iu = np.triu_indices(d)
    m = jnp.zeros((d, d), dtype=x.dtype).at[iu].set(x)
    return m + m.T - jnp.diag(jnp.diag(m))


def _residual(x: jax.Array, target: jax.Array) -> jax.Array:
    d = target.shape[-1]
    iu = np.triu_indices(d)
    m = _unpack(x, d)
    a2 = acg_a2(m @ m)
    return jnp.concatenate([(a2 - target)[iu], jnp.trace(m)[None] - 1.0])


def _zero_value(x: jax.Array) -> jax.Array:
    """``x`` with forward value exactly 0 but the derivative of ``x``."""
    return x - jax.lax.stop_gradient(x)


def _normal_matrix(j: jax.Array) -> jax.Array:
    # Levenberg-Marquardt damping: a2(M^2) is even in an eigenvalue of M that
    # vanishes (aligned or planar a2), so J^T J is singular exactly there.
    jtj = j.T @ j
    return jtj + DAMPING * jnp.trace(jtj) / jtj.shape[0] * jnp.eye(jtj.shape[0])


def _solve_m(target: jax.Array, diag_t: jax.Array) -> jax.Array:
    """``M`` (C = M^2, tr M = 1) with ``acg_a2(M^2) = target``, in the principal frame of
    ``target`` (forward value diagonal); its derivative is the implicit-function one."""
    d = target.shape[-1]
    iu = np.triu_indices(d)
    # Gauss-Newton for the principal values m of M, sum(m) = 1.
    fixed = jax.lax.stop_gradient(diag_t)

    def residual_diag(m):
        return jnp.concatenate([_acg_a2_principal(m * m) - fixed, jnp.sum(m)[None] - 1.0])

    def step(_, m):
        j = jax.jacfwd(residual_diag)(m)
        return m - jnp.linalg.solve(_normal_matrix(j), j.T @ residual_diag(m))

    m = jax.lax.stop_gradient(jax.lax.fori_loop(0, NEWTON_STEPS, step, fixed))
    # Implicit-function step on the full symmetric system: zero at the root, derivative
    # -(J^T J)^-1 J^T dR/d(target).
    x = jnp.diag(m)[iu]
    j = jax.lax.stop_gradient(jax.jacfwd(_residual)(x, jax.lax.stop_gradient(target)))
    corr = _unpack(jnp.linalg.solve(_normal_matrix(j), j.T @ _residual(x, target)), d)
    corr_diag = jnp.diagonal(corr)
    return jnp.diag(m - corr_diag) - _zero_value(corr - jnp.diag(corr_diag))


def _fec_single(a2: jax.Array) -> jax.Array:
    d = a2.shape[-1]
    a2 = 0.5 * (a2 + a2.T)
    # Work in the principal frame of a2, held fixed (no derivative): the map is
    # rotation-equivariant, a4(a2) = R . F(R^T a2 R) for *any* fixed rotation R, so the
    # derivative stays exact even at repeated eigenvalues. In that frame the forward
    # values are exactly diagonal, which keeps det(I + 2sC) and C (I + 2sC)^-1 free of
    # cancellation at the huge s the quadrature reaches; the off-diagonal entries carry
    # only derivatives.
    _, v = jnp.linalg.eigh(jax.lax.stop_gradient(a2))
    v = jax.lax.stop_gradient(v)
    target = v.T @ a2 @ v
    diag_t = jnp.diagonal(target)
    target = jnp.diag(diag_t) + _zero_value(target - jnp.diag(diag_t))

    if d == 2:
        # In 2-D the angular central Gaussian has a_i = sqrt(c_i) / (sqrt(c_1) + sqrt(c_2))
        # in its principal frame, so M = a2 exactly (C = a2^2): no inversion needed, and
        # the derivative of every component is carried by ``target`` itself.
        m_final = target
    else:
        m_final = _solve_m(target, diag_t)
    a4_frame = acg_a4(m_final @ m_final)
    return jnp.einsum("ia,jb,kc,ld,abcd->ijkl", v, v, v, v, a4_frame)


def fec(a2: jax.Array) -> jax.Array:
    """Exact closure of Jeffery's equation / fast exact closure FEC
    (Montgomery-Smith, Jack & Smith 2011, J. Fluid Mech. 680:321 and J. Non-Newtonian
    Fluid Mech. 166:343).

    ``a4 = 3 int_0^inf s det(I + 2sC)^(-1/2) S(K K) ds``, ``K = C (I + 2sC)^-1``, with
    ``C`` solved from ``a2 = int_0^inf det(I + 2sC)^(-1/2) K ds`` (see the module
    docstring for the formulation and numerics). No fitted coefficients: exact for
    every state Jeffery's equation reaches from isotropy (any aspect ratio, any
    constant velocity gradient), at isotropy and for aligned fibres; fully symmetric
    and trace-exact. Defined in 2-D and 3-D.
    """
    fn = jnp.vectorize(_fec_single, signature="(d,d)->(d,d,d,d)")
    return fn(a2)
