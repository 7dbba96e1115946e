"""Accuracy of every closure against the exact closure, over many orientation states.

Question: how far is each registered closure a4 = f(a2) from the exact a4 of
Jeffery's equation from isotropy (FEC; Montgomery-Smith, Jack & Smith 2011), over
(i) random admissible states spanning isotropic to nearly aligned and (ii) states
Jeffery's equation actually reaches (shear and elongation, several aspect ratios),
and how large are the jumps of the orthotropic fits where two eigenvalues of a2
coincide? This is the exhaustive version of the bounds the unit tests check on a
few states (tests/macro/test_closures.py: ERROR_VS_EXACT, REPEATED_EIGENVALUE_JUMP).
Method: one jitted evaluation per closure on the whole batch; for the Jeffery
states the exact a4 is the angular-central-Gaussian moment of B B^T
(pyfold.closures.exact.acg_a4), independent of the a2 -> C inversion inside FEC.
Command:  python studies/closures/closure_accuracy.py [--states 2000] [--out closure_accuracy.nc]
Cost: ~10 s on 2 cores for 2000 states (forward-only compilation dominates; FEC ~3 s).
Output: a table (closure, max and RMS error vs exact on random and Jeffery states,
max jump at a1 = a2 and a2 = a3, compile+run time) and a netCDF file with the same.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.linalg as sl
import xarray as xr

from pyfold._jax import jax, jnp
from pyfold import closures as C
from pyfold.closures.exact import acg_a2, acg_a4

# Parameters
SEED = 2024
LAMBDAS = (0.6, 0.8, 0.95, 1.0)  # Jeffery shape factors
TIMES = np.linspace(0.25, 12.0, 24)  # strain units
FLOWS = {
    "shear": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
    "uniaxial": np.diag([1.0, -0.5, -0.5]),
    "planar": np.diag([1.0, -1.0, 0.0]),
}


def random_states(n: int, seed: int) -> np.ndarray:
    """Moments of random anisotropic populations (isotropic to nearly aligned)."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, 3, 3))
    for k in range(n):
        g = rng.normal(size=(400, 3)) * rng.uniform(0.02, 1.0, size=3)
        p = g / np.linalg.norm(g, axis=1, keepdims=True)
        out[k] = p.T @ p / len(p)
    return out


def jeffery_states() -> tuple[np.ndarray, np.ndarray]:
    """(a2, exact a4) of Jeffery populations from isotropy, B = exp(t (W + lambda D))."""
    covs = []
    for L in FLOWS.values():
        D, W = 0.5 * (L + L.T), 0.5 * (L - L.T)
        for lam in LAMBDAS:
            # elongation saturates fast: stop before the states become numerically aligned
            for t in TIMES if L[0, 1] else TIMES[TIMES < 4.0]:
                B = sl.expm(t * (W + lam * D))
                covs.append(B @ B.T / np.trace(B @ B.T))
    covs = jnp.asarray(np.stack(covs))
    return np.asarray(jax.jit(jax.vmap(acg_a2))(covs)), np.asarray(jax.jit(jax.vmap(acg_a4))(covs))


def degenerate_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """States with a1 = a2 or a2 = a3 in their principal frame and randomly rotated."""
    rng = np.random.default_rng(SEED + 1)
    diag, rotated, rots = [], [], []
    # a1 = a2 = x (x in (1/3, 1/2)) and a2 = a3 = y (y in (0, 1/3))
    values = [(x, x, 1 - 2 * x) for x in np.linspace(0.34, 0.49, n)]
    values += [(1 - 2 * y, y, y) for y in np.linspace(0.01, 0.32, n)]
    for v in values:
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        diag.append(np.diag(v))
        rotated.append(R @ np.diag(v) @ R.T)
        rots.append(R)
    return np.stack(diag), np.stack(rotated), np.stack(rots)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=2000)
    ap.add_argument("--out", default="closure_accuracy.nc")
    args = ap.parse_args()

    # Problem
    a2_random = random_states(args.states, SEED)
    a2_jeffery, a4_jeffery = jeffery_states()
    deg, deg_rot, rots = degenerate_pairs(16)
    batch = jnp.asarray(np.concatenate([a2_random, a2_jeffery, deg, deg_rot]))
    n_r, n_j, n_d = len(a2_random), len(a2_jeffery), len(deg)

    # Solver / Run
    names = C.available(3)
    results = {}
    for name in names:
        start = time.perf_counter()
        a4 = np.asarray(jax.jit(C.get_closure(name, 3))(batch))
        results[name] = (a4, time.perf_counter() - start)
    exact_random = results["fec"][0][:n_r]
    rows = []
    for name in names:
        a4, seconds = results[name]
        err_r = np.abs(a4[:n_r] - exact_random).reshape(n_r, -1).max(axis=1)
        err_j = np.abs(a4[n_r:n_r + n_j] - a4_jeffery).reshape(n_j, -1).max(axis=1)
        a4_deg = a4[n_r + n_j:n_r + n_j + n_d]
        a4_rot = a4[n_r + n_j + n_d:]
        back = np.einsum("nia,njb,nkc,nld,nabcd->nijkl", rots, rots, rots, rots, a4_deg)
        jump = np.abs(back - a4_rot).reshape(n_d, -1).max(axis=1)
        rows.append((name, err_r.max(), np.sqrt(np.mean(err_r**2)), err_j.max(),
                     jump[: n_d // 2].max(), jump[n_d // 2:].max(), seconds))

    # Save
    print(f"{'closure':16s} {'max|e| rnd':>11s} {'rms rnd':>9s} {'max|e| Jef':>11s} "
          f"{'jump a1=a2':>11s} {'jump a2=a3':>11s} {'time [s]':>9s}")
    for row in rows:
        print(f"{row[0]:16s} {row[1]:11.2e} {row[2]:9.2e} {row[3]:11.2e} {row[4]:11.2e} {row[5]:11.2e} {row[6]:9.1f}")
    ds = xr.Dataset(
        {
            "max_error_random": ("closure", [r[1] for r in rows], {"units": "1", "long_name": "max |a4 - a4_exact| over random states"}),
            "rms_error_random": ("closure", [r[2] for r in rows], {"units": "1", "long_name": "RMS over states of max-component error"}),
            "max_error_jeffery": ("closure", [r[3] for r in rows], {"units": "1", "long_name": "max |a4 - a4_exact| over Jeffery populations"}),
            "jump_a1_eq_a2": ("closure", [r[4] for r in rows], {"units": "1", "long_name": "max jump of a4 at a1 = a2 under rotation"}),
            "jump_a2_eq_a3": ("closure", [r[5] for r in rows], {"units": "1", "long_name": "max jump of a4 at a2 = a3 under rotation"}),
            "seconds": ("closure", [r[6] for r in rows], {"units": "s", "long_name": "compile + evaluation time"}),
        },
        coords={"closure": list(names)},
        attrs={"n_random_states": n_r, "n_jeffery_states": n_j, "seed": SEED},
    )
    ds.to_netcdf(args.out, engine="h5netcdf")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
