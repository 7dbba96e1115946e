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
is used directly; in 3-D ``M ~ a2`` starts Gauss-Newton steps on the principal
values in the (derivative-free) principal frame of a2 (Jacobian written out; stopped
once the next step, extrapolated from quadratic convergence, is below round-off, at
most NEWTON_STEPS), followed by one implicit-function step on all components that
carries the exact derivative (rotation equivariance makes the fixed frame harmless,
also at repeated eigenvalues). In that frame ``C`` is diagonal in value, so a2's
residual, its Jacobian and a4 are evaluated from the principal values, the
off-diagonal components (zero value, nonzero derivative) entering to first order,
which is exact for the value and the first derivative (:func:`_a4_frame`). The same
formulas hold in 2-D, where the result reduces to the planar natural closure
(``A_1122 = a1 a2 / 2``).

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
from pyfold.tensors import det

# Double-exponential nodes: s = exp(A sinh t), t in [-T, T] with step H.
_T, _H, _A = 4.0, 1.0 / 16.0, 3.0
_t = np.arange(-_T, _T + 0.5 * _H, _H)
_S = np.exp(_A * np.sinh(_t))
_W = _H * _A * np.cosh(_t) * _S

#: Most Gauss-Newton steps for a2 -> C (the stopping rule of _gauss_newton ends the
#: iteration after 3-5 on the default run's records).
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
    # S is linear: symmetrise the integral of K K once, not the integrand at every node
    kk = jnp.einsum("n,nij,nkl->ijkl", jnp.asarray(_W * _S) * g, k, k)
    return 3.0 * _symmetrise(kk)


def _symmetrise(t: jax.Array) -> jax.Array:
    """Fully symmetric part of ``t_ijkl`` with ``t_ijkl = t_jikl = t_ijlk = t_klij``
    (an integral of ``K K``, ``K`` symmetric): the six pairings of
    :func:`pyfold.closures._basis.sym_product`."""
    return (t + jnp.transpose(t, (0, 2, 1, 3)) + jnp.transpose(t, (0, 2, 3, 1)) + jnp.transpose(t, (2, 3, 0, 1))
            + jnp.transpose(t, (2, 0, 3, 1)) + jnp.transpose(t, (2, 0, 1, 3))) / 6.0


def _principal_terms(c: jax.Array):
    """Nodes of the principal-frame integrands for a *diagonal* covariance ``diag(c)``:
    ``q_ni = 1 + 2 s_n c_i`` and the weights ``w_n g_n``, ``g = prod_j q_j^(-1/2)``."""
    q = 1.0 + 2.0 * jnp.asarray(_S)[:, None] * c[None, :]
    wg = jnp.asarray(_W) * jnp.prod(q, axis=-1) ** -0.5
    return q, wg


def _acg_a2_principal(c: jax.Array) -> jax.Array:
    """Principal values of :func:`acg_a2` for a *diagonal* covariance ``diag(c)``:
    ``a_i = int g(s) c_i / (1 + 2 s c_i) ds``, ``g = prod_j (1 + 2 s c_j)^(-1/2)``.
    Elementwise, so the Gauss-Newton iteration below is cheap to compile and run."""
    q, wg = _principal_terms(c)
    return jnp.einsum("n,nd->d", wg, c / q)


def _principal_jacobian(m: jax.Array):
    """``a(m)`` (the principal values of :func:`acg_a2` at ``C = diag(m)^2``) and its
    Jacobian ``da_i/dm_j = 2 m_j int g [delta_ij / q_i^2 - s c_i / (q_i q_j)] ds``
    (from ``dg/dc_j = -s g / q_j`` and ``d(c_i/q_i)/dc_i = 1/q_i^2``), written out: the
    three integrals as one reduction over the nodes (one fused pass, no forward-mode
    sweep per column and no small matrix products, whose fixed cost dominates at d = 3)."""
    d = m.shape[-1]
    c = m * m
    q, wg = _principal_terms(c)
    f = c / q
    iq = 1.0 / q
    cross = (jnp.asarray(_S)[:, None, None] * f[:, :, None] * iq[:, None, :]).reshape(-1, d * d)
    tot = jnp.sum(wg[:, None] * jnp.concatenate([f, iq * iq, cross], axis=1), axis=0)
    a, diag, cross = tot[:d], tot[d:2 * d], tot[2 * d:].reshape(d, d)
    return a, (jnp.diag(diag) - cross) * (2.0 * m)[None, :]


def _solve3(n: jax.Array, b: jax.Array) -> jax.Array:
    """``n^-1 b`` for a symmetric positive definite (d, d) ``n`` by its adjugate: no LU
    call inside the loop. A step's round-off is corrected by the next one, so the root
    is that of the LU-solved iteration (tests/macro/test_closures_fec_speed.py compares
    with all NEWTON_STEPS steps, tests/macro/test_closures.py with a reference)."""
    return _adjugate(n) @ b / det(n)


def _zero_value(x: jax.Array) -> jax.Array:
    """``x`` with forward value exactly 0 but the derivative of ``x``."""
    return x - jax.lax.stop_gradient(x)


def _normal_matrix(j: jax.Array) -> jax.Array:
    # Levenberg-Marquardt damping: a2(M^2) is even in an eigenvalue of M that
    # vanishes (aligned or planar a2), so J^T J is singular exactly there.
    jtj = j.T @ j
    return jtj + DAMPING * jnp.trace(jtj) / jtj.shape[0] * jnp.eye(jtj.shape[0])


#: Gauss-Newton stops when the next step, extrapolated from the last two, is below this
#: many units of round-off (``m`` is O(1): ``sum(m) = 1``); see :func:`_gauss_newton`.
STOP_ULPS = 1.0


def _gauss_newton(fixed: jax.Array):
    """Principal values ``m`` of ``M`` (``sum(m) = 1``) with ``_acg_a2_principal(m^2) =
    fixed``, by Gauss-Newton from ``m = fixed``, and the number of steps taken.

    It stops when the next step would be below round-off: after a step ``dm_k`` the
    error is ~ ``K dm_k^2`` (quadratic convergence, ``K`` estimated as
    ``dm_k / dm_(k-1)^2``), i.e. the next step ~ ``dm_k^3 / dm_(k-1)^2``; at most
    NEWTON_STEPS steps. Stopping one step earlier and leaving the last one to the
    implicit-function step of :func:`_solve_m` would give the same value but a
    derivative evaluated ~sqrt(eps) away from the root (measured: 4e-9 off)."""
    d = fixed.shape[-1]
    eps = jnp.finfo(fixed.dtype).eps

    def gn_step(m):
        a, ja = _principal_jacobian(m)
        j = jnp.concatenate([ja, jnp.ones((1, d), ja.dtype)])
        r = jnp.concatenate([a - fixed, jnp.sum(m)[None] - 1.0])
        return -_solve3(_normal_matrix(j), j.T @ r)

    def cond(s):
        _, k, prev, last = s
        nxt = last**3 / jnp.where(prev > 0.0, prev**2, 1.0)
        done = (k >= 2) & (nxt <= STOP_ULPS * eps)
        return (k < NEWTON_STEPS) & ~done & (last > 0.0)

    def body(s):
        m, k, _, last = s
        dm = gn_step(m)
        return m + dm, k + 1, last, jnp.max(jnp.abs(dm))

    inf = jnp.asarray(jnp.inf, fixed.dtype)
    m, k, _, _ = jax.lax.while_loop(cond, body, (fixed, jnp.asarray(0), inf, inf))
    return m, k


def _solve_m(diag_t: jax.Array, target_off: jax.Array) -> jax.Array:
    """``M`` (C = M^2, tr M = 1) with ``acg_a2(M^2) = target`` in the principal frame of
    ``target = diag(diag_t) + target_off`` (``target_off``: zero value, off-diagonal
    derivative); the forward value of ``M`` is diagonal, its derivative the
    implicit-function one of all components."""
    d = diag_t.shape[-1]
    iu = np.triu_indices(d)
    n_full = iu[0].size
    m = jax.lax.stop_gradient(_gauss_newton(jax.lax.stop_gradient(diag_t))[0])

    # Implicit-function step on the full symmetric system (unknowns the upper triangle of
    # M, residuals acg_a2(M^2) - target on the upper triangle and tr M - 1): zero at the
    # root, derivative -(J^T J)^-1 J^T dR/d(target). At a diagonal M the Jacobian is block
    # diagonal: the principal block of _gauss_newton, and for each off-diagonal pair
    # d a2_ij / d M_ij = (m_i + m_j) int g / (q_i q_j) ds alone (dC_ij = (m_i + m_j) dM_ij,
    # dK = Q^-1 dC Q^-1, dg ~ tr(Q^-1 dC) = 0); the damping is that of the full system.
    a, ja = _principal_jacobian(m)
    c = m * m
    q, wg = _principal_terms(c)
    j_off = (m[:, None] + m[None, :]) * jnp.einsum("n,ni,nj->ij", wg, 1.0 / q, 1.0 / q)
    off = iu[0] != iu[1]
    j_pairs = j_off[iu[0][off], iu[1][off]]
    j = jnp.concatenate([ja, jnp.ones((1, d), ja.dtype)])
    lam = DAMPING * (jnp.sum(j * j) + jnp.sum(j_pairs**2)) / n_full  # damping of the full system
    r = jnp.concatenate([a - diag_t, jnp.sum(m)[None] - 1.0])
    m_final = m - _solve3(j.T @ j + lam * jnp.eye(d), j.T @ r)
    # off-diagonal: M_ij = -(j_ij^2 + lam)^-1 j_ij (0 - target_ij), of zero value
    scale = j_off / (j_off**2 + lam)
    return jnp.diag(m_final) + scale * target_off


def _a4_frame(m: jax.Array) -> jax.Array:
    """:func:`acg_a4` at ``C = M^2`` for ``M`` whose forward value is diagonal, ``diag(m)``
    (``m`` its diagonal with derivative): ``K = diag(c / q) + Q^-1 dC Q^-1`` and
    ``g = prod q^(-1/2)`` with ``q = 1 + 2 s c`` from the diagonal, the off-diagonal
    part of ``C`` entering only to first order (it has zero value), which is exact for the
    value and the first derivative. No adjugate or determinant per node."""
    d = m.shape[-1]
    mm = m @ m
    c = jnp.diagonal(mm)
    e = mm - jnp.diag(c)  # zero value
    q, wg = _principal_terms(c)
    k = jnp.eye(d) * (c / q)[:, None, :] + e[None] / (q[:, :, None] * q[:, None, :])
    kk = jnp.einsum("n,nij,nkl->ijkl", wg * jnp.asarray(_S), k, k)
    return 3.0 * _symmetrise(kk)


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
    target_off = _zero_value(target - jnp.diag(diag_t))

    if d == 2:
        # In 2-D the angular central Gaussian has a_i = sqrt(c_i) / (sqrt(c_1) + sqrt(c_2))
        # in its principal frame, so M = a2 exactly (C = a2^2): no inversion needed, and
        # the derivative of every component is carried by ``target`` itself.
        m_final = jnp.diag(diag_t) + target_off
    else:
        m_final = _solve_m(diag_t, target_off)
    a4_frame = _a4_frame(m_final).reshape(d * d, d * d)
    # back to the lab frame: (v x v) A (v x v)^T on the (d^2, d^2) form, two products
    vv = jnp.kron(v, v)
    return (vv @ a4_frame @ vv.T).reshape((d,) * 4)


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
