"""Independent NumPy/SciPy reference for the Folgar--Tucker equation with the IBOF closure.

Used by ``benchmarks/bench_ft_batch.py`` both as the timing baseline (one
``scipy.integrate.solve_ivp`` per case, the way such studies are usually run) and
as an independent check of ``pyfold.models`` (JAX/diffrax): everything here is
plain NumPy written from the papers, sharing with pyfold only the *table* of
published IBOF coefficients (data, not code).

Equations
---------
Folgar & Tucker (1984, J. Reinf. Plast. Compos. 3:98), in the form of Advani &
Tucker (1987, J. Rheol. 31:751)::

    da/dt = W.a - a.W + xi (D.a + a.D - 2 a4:D) + 2 C_I gamma_dot (I - 3 a)

with ``D = (L + L^T)/2``, ``W = (L - L^T)/2``, ``gamma_dot = sqrt(2 D:D)``.

IBOF closure (Chung & Kwon 2002, J. Rheol. 46:169, eqs. 24-30)::

    a4 = b1 S(I I) + b2 S(I a) + b3 S(a a) + b4 S(I a.a) + b5 S(a a.a) + b6 S(a.a a.a)

where ``S`` is the full index symmetrisation, ``b3, b4, b6`` are fifth-order
polynomials in the invariants ``II = (1 - tr(a.a))/2`` and ``III = det a`` and
``b1, b2, b5`` follow from the normalisation and symmetry conditions.
"""
from __future__ import annotations

import itertools

import numpy as np
from scipy.integrate import solve_ivp

#: Monomials II^m III^n of the IBOF polynomials, in the order of Chung & Kwon
#: (2002), Table 1: beta_i = sum_k a_ik II^m_k III^n_k.
IBOF_POWERS: tuple[tuple[int, int], ...] = (
    (0, 0), (1, 0), (2, 0), (0, 1), (0, 2), (1, 1), (2, 1), (1, 2), (3, 0), (0, 3),
    (3, 1), (2, 2), (1, 3), (4, 0), (0, 4), (4, 1), (3, 2), (2, 3), (1, 4), (5, 0), (0, 5),
)

_PERMS = tuple(itertools.permutations(range(4)))


def _sym4(t: np.ndarray) -> np.ndarray:
    """Mean of a (3,3,3,3) tensor over all 24 index permutations."""
    return sum(np.transpose(t, p) for p in _PERMS) / 24.0


# The symmetrised dyads S(X Y) are linear in each factor, so they are assembled
# from index-permuted outer products once per call.
def ibof_a4(a: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """IBOF closure ``a4(a)`` of Chung & Kwon (2002) for one 3x3 orientation tensor.

    Parameters
    ----------
    a : (3, 3) array
    coeffs : (3, 21) array
        Rows: the published coefficients of ``beta_3, beta_4, beta_6``, columns in
        the order of :data:`IBOF_POWERS`.
    """
    I = np.eye(3)
    aa = a @ a
    II = 0.5 * (np.trace(a) ** 2 - np.trace(aa))
    III = np.linalg.det(a)
    mono = np.array([II**m * III**n for m, n in IBOF_POWERS])
    b3, b4, b6 = coeffs @ mono
    b1 = 3.0 / 5.0 * (
        -1.0 / 7.0
        + b3 / 5.0 * (1.0 / 7.0 + 4.0 / 7.0 * II + 8.0 / 3.0 * III)
        - b4 * (1.0 / 5.0 - 8.0 / 15.0 * II - 14.0 / 15.0 * III)
        - b6 * (1.0 / 35.0 - 24.0 / 105.0 * III - 4.0 / 35.0 * II + 16.0 / 15.0 * II * III + 8.0 / 35.0 * II**2)
    )
    b2 = 6.0 / 7.0 * (
        1.0
        - b3 / 5.0 * (1.0 + 4.0 * II)
        + 7.0 / 5.0 * b4 * (1.0 / 6.0 - II)
        - b6 * (-1.0 / 5.0 + 2.0 / 3.0 * III + 4.0 / 5.0 * II - 8.0 / 5.0 * II**2)
    )
    b5 = -4.0 / 5.0 * b3 - 7.0 / 5.0 * b4 - 6.0 / 5.0 * b6 * (1.0 - 4.0 / 3.0 * II)
    out = lambda x, y: np.einsum("ij,kl->ijkl", x, y)  # noqa: E731
    return _sym4(
        b1 * out(I, I)
        + b2 * out(I, a)
        + b3 * out(a, a)
        + b4 * out(I, aa)
        + b5 * out(a, aa)
        + b6 * out(aa, aa)
    )


def ft_rate(a: np.ndarray, L: np.ndarray, ci: float, xi: float, a4: np.ndarray) -> np.ndarray:
    """Folgar--Tucker ``da/dt`` for given ``a``, ``a4`` (NumPy, one state)."""
    D = 0.5 * (L + L.T)
    W = 0.5 * (L - L.T)
    gd = np.sqrt(2.0 * np.sum(D * D))
    return (
        W @ a
        - a @ W
        + xi * (D @ a + a @ D - 2.0 * np.einsum("ijkl,kl->ij", a4, D))
        + 2.0 * ci * gd * (np.eye(3) - 3.0 * a)
    )


def solve_ft_ibof(
    ci: float,
    xi: float,
    a2_0: np.ndarray,
    L: np.ndarray,
    t_eval: np.ndarray,
    coeffs: np.ndarray,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    method: str = "DOP853",
) -> np.ndarray:
    """One Folgar--Tucker/IBOF integration with ``solve_ivp``; returns ``a2`` (nt, 3, 3)."""

    def rhs(_t, y):
        a = y.reshape(3, 3)
        a = 0.5 * (a + a.T)
        return ft_rate(a, L, ci, xi, ibof_a4(a, coeffs)).ravel()

    sol = solve_ivp(
        rhs, (float(t_eval[0]), float(t_eval[-1])), np.asarray(a2_0, float).ravel(),
        method=method, t_eval=t_eval, rtol=rtol, atol=atol,
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y.T.reshape(-1, 3, 3)
