"""Fit pyfold's 3-D natural closure to the exact closure of Jeffery's equation.

Question: which coefficients of the natural-closure form (Verleye & Dupret 1993;
Dupret & Verleye 1999)

    a4 = b1 S(d d) + b2 S(d a) + b3 S(a a) + b4 S(d a.a) + b5 S(a a.a) + b6 S(a.a a.a),

with b3, b4, b6 full quadratics in the invariants (II, III) of a2 and b1, b2, b5 fixed
by the trace conditions (Chung & Kwon 2002, J. Rheol. 46:169, eq. 26), best reproduce
the exact closure of Jeffery's equation (C_I = 0; FEC, Montgomery-Smith, Jack & Smith
2011), and how accurate is the result next to IBOF and ORW3 on the same states? The
published NAT1/NAT2 tables were fitted to the same exact solutions but are not
available here; this script makes pyfold's own, reproducible table.

Method.
* States: principal values on a uniform grid of the triangle a1 >= a2 >= a3 >= 0,
  a1 + a2 + a3 = 1, step 1/N (boundaries included: the planar edge a3 = 0, the
  repeated-eigenvalue edges, the isotropic and aligned corners). These are the
  Jeffery-reachable states: with lambda = 1 and the constant elongational gradient
  L = diag(e1, e2, e3) (tr L = 0), fibres starting isotropic are distributed as the
  angular central Gaussian with C = diag(exp(2 e_i t)) (pyfold.closures.exact), and
  a2(C) maps the positive-definite C onto the whole interior of the triangle
  (Montgomery-Smith, Jack & Smith 2011); boundary states are its limits. The closure
  form is rotation invariant, so principal-frame (diagonal) states suffice.
* Exact a4: pyfold.closures.fec on those states.
* Model: pyfold.closures.natural.natural_form, affine in its 3 x 6 coefficients; the
  design matrix is its forward-mode Jacobian (exact for an affine map).
* Objective: sum over states of ||a4 - a4_FEC||_F^2 (all 81 components), subject to
  exactness for aligned fibres (a linear equality of rank 1: b1(0, 0) = 0, which
  with the trace conditions also gives b2(0, 0) + b4(0, 0) = 0), solved by the
  null-space method with numpy's SVD lstsq.
  Isotropy needs no constraint (exact for any coefficients).
* Held out: HELDOUT random states uniform on the triangle (Dirichlet(1, 1, 1),
  sorted, seed SEED) against FEC, and Jeffery populations of shear, uniaxial and
  planar elongation at lambda = 0.6..1 (studies/closures/closure_accuracy.py), whose
  exact a4 is the ACG moment of B B^T, independent of FEC's a2 -> C inversion.
Errors are per state max_ijkl |a4 - a4_exact|, summarised as max and RMS over states.

Command:  python studies/closures/fit_natural_closure.py [--grid 60] [--degree 2] [--write]
Cost: ~35 s on the shared 2 cores (measured; FEC compilation dominates).
Output: a table (natural fit, IBOF, ORW3 on the fit grid, its planar edge, the
held-out and the Jeffery states); with --write, pyfold/closures/_natural_fit.py (the
coefficient table as a Python literal, with date, command and residuals).
"""
from __future__ import annotations

import argparse
import datetime
import pathlib

import numpy as np

from pyfold._jax import jax, jnp
from pyfold import closures as C
from pyfold.closures.natural import natural_form
from pyfold.tensors import aligned_a4

from closure_accuracy import jeffery_states

# Parameters
SEED = 20250
HELDOUT = 24
TABLE = pathlib.Path(__file__).resolve().parents[2] / "pyfold" / "closures" / "_natural_fit.py"


def exponents(degree: int) -> tuple[tuple[int, int], ...]:
    """Monomials II^p III^q of total degree <= ``degree``, by degree then by p descending."""
    return tuple((p, tot - p) for tot in range(degree + 1) for p in range(tot, -1, -1))


def triangle_grid(n: int) -> np.ndarray:
    """Sorted principal values (a1 >= a2 >= a3 >= 0, sum 1) on the grid of step 1/n."""
    pts = {tuple(sorted((i / n, j / n, (n - i - j) / n), reverse=True))
           for i in range(n + 1) for j in range(n + 1 - i)}
    return np.array(sorted(pts, reverse=True))


def heldout_states(n: int, seed: int) -> np.ndarray:
    """Principal values uniform on the triangle, sorted descending."""
    lam = np.random.default_rng(seed).dirichlet(np.ones(3), size=n)
    return -np.sort(-lam, axis=1)


def diag_states(lam: np.ndarray) -> jax.Array:
    return jnp.asarray(np.einsum("ni,ij->nij", lam, np.eye(3)))


def per_state_error(a4: np.ndarray, exact: np.ndarray) -> np.ndarray:
    return np.abs(np.asarray(a4) - np.asarray(exact)).reshape(len(exact), -1).max(axis=1)


def fit(a2: jax.Array, exact: np.ndarray, expo) -> np.ndarray:
    """Constrained linear least squares for the (3, n_monomials) coefficients."""
    n_c = 3 * len(expo)

    def model(c, x):
        return natural_form(x, c.reshape(3, len(expo)), expo).reshape(len(x), -1)

    zero = jnp.zeros(n_c)
    offset, design = np.asarray(model(zero, a2)), np.asarray(jax.jacfwd(model)(zero, a2))
    G = design.reshape(-1, n_c)
    y = (exact.reshape(len(exact), -1) - offset).reshape(-1)
    # aligned fibres exact: natural_form(e1 e1) = e1^4, affine in c (rank 1: b1(0, 0) = 0)
    e1 = jnp.eye(3)[:1]
    al_offset = np.asarray(model(zero, e1[:, :, None] * e1[:, None, :]))
    al_design = np.asarray(jax.jacfwd(model)(zero, e1[:, :, None] * e1[:, None, :])).reshape(-1, n_c)
    al_target = np.asarray(aligned_a4(jnp.array([1.0, 0.0, 0.0]))).reshape(-1) - al_offset.reshape(-1)
    u, s, vt = np.linalg.svd(al_design, full_matrices=True)
    rank = int(np.sum(s > 1e-12 * s[0]))
    particular = vt[:rank].T @ ((u[:, :rank].T @ al_target) / s[:rank])
    null = vt[rank:].T
    z = np.linalg.lstsq(G @ null, y - G @ particular, rcond=None)[0]
    coeffs = particular + null @ z
    print(f"aligned constraint rank {rank} (expected 1: b1(0, 0) = 0); {n_c - rank} free coefficients")
    return coeffs.reshape(3, len(expo))


def write_table(path, coeffs, expo, args, stats, heldout_lam) -> None:
    rows = ",\n".join("    (" + ", ".join(repr(float(c)) for c in row) + ",)" for row in coeffs)
    held = ",\n".join("    (" + ", ".join(repr(float(v)) for v in row) + ")" for row in heldout_lam)
    text = f'''"""Coefficient table of pyfold's 3-D natural closure (:func:`pyfold.closures.natural.natural_3d`).

GENERATED by studies/closures/fit_natural_closure.py -- do not edit by hand; re-run
the command below. These numbers are pyfold's own least-squares fit of the natural
form to the exact closure FEC, NOT the published NAT1/NAT2 coefficients.

Rows of COEFFICIENTS: b3, b4, b6; columns: the monomials II^p III^q of EXPONENTS.
Errors are per state max_ijkl |a4 - a4_FEC|, summarised as max / RMS over states.
"""

FITTED = {datetime.date.today().isoformat()!r}
SCRIPT = "studies/closures/fit_natural_closure.py"
COMMAND = {f"python studies/closures/fit_natural_closure.py --grid {args.grid} --degree {args.degree} --write"!r}
DEGREE = {args.degree}
EXPONENTS = {tuple(expo)!r}
COEFFICIENTS = (
{rows},
)

#: fit states: the triangle grid of step 1 / FIT_GRID_STEPS (FIT_STATES states)
FIT_GRID_STEPS = {args.grid}
FIT_STATES = {stats["n_fit"]}
FIT_MAX_ERROR = {stats["fit_max"]!r}
FIT_RMS_ERROR = {stats["fit_rms"]!r}
#: largest error on the planar edge a3 = 0 of the fit grid (the fit's worst region)
PLANAR_EDGE_MAX_ERROR = {stats["planar_max"]!r}

#: held-out principal values (Dirichlet(1, 1, 1), seed HELDOUT_SEED) and the errors on them
HELDOUT_SEED = {SEED}
HELDOUT_EIGENVALUES = (
{held},
)
HELDOUT_MAX_ERROR = {stats["held_max"]!r}
HELDOUT_RMS_ERROR = {stats["held_rms"]!r}
'''
    path.write_text(text)
    print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=60, help="grid steps per unit of eigenvalue")
    ap.add_argument("--degree", type=int, default=2, help="total degree of b3, b4, b6 in (II, III)")
    ap.add_argument("--write", action="store_true", help=f"write {TABLE}")
    args = ap.parse_args()

    # Problem
    expo = exponents(args.degree)
    lam_fit = triangle_grid(args.grid)
    lam_held = heldout_states(HELDOUT, SEED)
    a2_jef, a4_jef = jeffery_states()
    a2_fit, a2_held = diag_states(lam_fit), diag_states(lam_held)
    fec = jax.jit(C.fec)
    exact_fit, exact_held = np.asarray(fec(a2_fit)), np.asarray(fec(a2_held))

    # Solver
    coeffs = fit(a2_fit, exact_fit, expo)

    # Run
    candidates = {
        "natural (pyfold fit)": jax.jit(lambda x: natural_form(x, jnp.asarray(coeffs), expo)),
        "ibof": jax.jit(C.ibof),
        "orw3": jax.jit(C.orw3),
    }
    planar = lam_fit[:, 2] == 0.0
    rows, stats = [], {}
    for name, f in candidates.items():
        e_fit = per_state_error(f(a2_fit), exact_fit)
        e_held = per_state_error(f(a2_held), exact_held)
        e_jef = per_state_error(f(jnp.asarray(a2_jef)), a4_jef)
        e_corner = per_state_error(f(diag_states(np.array([[1.0, 0, 0], [1 / 3, 1 / 3, 1 / 3]]))),
                                   np.stack([np.asarray(aligned_a4(jnp.array([1.0, 0, 0]))),
                                             np.asarray(C.get_closure("linear")(jnp.eye(3) / 3))]))
        rows.append((name, e_fit.max(), np.sqrt(np.mean(e_fit**2)), e_fit[planar].max(), e_fit[~planar].max(),
                     e_held.max(), np.sqrt(np.mean(e_held**2)), e_jef.max(), e_corner[0], e_corner[1]))
        if name.startswith("natural"):
            stats = dict(n_fit=len(lam_fit), fit_max=float(e_fit.max()), fit_rms=float(np.sqrt(np.mean(e_fit**2))),
                         planar_max=float(e_fit[planar].max()), held_max=float(e_held.max()),
                         held_rms=float(np.sqrt(np.mean(e_held**2))))

    # Save
    print(f"degree {args.degree} in (II, III), {len(expo)} monomials; {len(lam_fit)} fit states, "
          f"{len(lam_held)} held-out, {len(a2_jef)} Jeffery states")
    head = ("closure", "fit max", "fit rms", "planar max", "inner max", "held max", "held rms", "Jeff max",
            "aligned", "isotropic")
    print(f"{head[0]:22s}" + "".join(f"{h:>11s}" for h in head[1:]))
    for row in rows:
        print(f"{row[0]:22s}" + "".join(f"{v:11.2e}" for v in row[1:]))
    print("coefficients (rows b3, b4, b6; columns " + ", ".join(f"II^{p} III^{q}" for p, q in expo) + "):")
    print(np.array2string(coeffs, precision=6, max_line_width=160))
    if args.write:
        write_table(TABLE, coeffs, expo, args, stats, lam_held)


if __name__ == "__main__":
    main()
