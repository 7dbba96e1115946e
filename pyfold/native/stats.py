"""Orientation moments computed by the Fortran core (``fold_orientation_stats``).

a2_ij = Σ_k w_k p_ki p_kj / Σ_k w_k,  a4_ijkl = Σ_k w_k p_ki p_kj p_kl p_km / Σ_k w_k
(Advani & Tucker 1987, J. Rheol. 31:751). This is what the direct simulation
writes every output step; the JAX twin for the macro layer is
``pyfold.tensors.a2_from_vectors`` / ``a4_from_vectors``.
"""
from __future__ import annotations

import numpy as np

from pyfold.errors import InputError, checked
from pyfold.native import load


def _weights(weights, n: int) -> np.ndarray:
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,):
        raise InputError(f"weights: expected shape ({n},), got {w.shape}")
    return w


def orientation_moments(p, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """a2 (d, d) and a4 (d, d, d, d) of one population ``p`` of shape (N, d), d = 2 or 3."""
    p = np.asarray(p, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3) or p.shape[0] < 1:
        raise InputError(f"p: expected shape (N >= 1, 2 or 3), got {p.shape}")
    ext = load("_fold_stats")
    a2, a4, stat, msg = ext.fold_orientation_moments(np.asfortranarray(p.T), _weights(weights, p.shape[0]))
    checked(stat, msg)
    return a2, a4


def orientation_moments_series(p, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """a2 (nt, d, d) and a4 (nt, d, d, d, d) of snapshots ``p`` of shape (nt, N, d)."""
    p = np.asarray(p, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] not in (2, 3) or p.shape[1] < 1 or p.shape[0] < 1:
        raise InputError(f"p: expected shape (nt >= 1, N >= 1, 2 or 3), got {p.shape}")
    ext = load("_fold_stats")
    pf = np.asfortranarray(np.transpose(p, (2, 1, 0)))
    a2, a4, stat, msg = ext.fold_orientation_moments_batch(pf, _weights(weights, p.shape[1]))
    checked(stat, msg)
    return np.moveaxis(a2, -1, 0), np.moveaxis(a4, -1, 0)
