"""Round-off bounds for comparing two floating-point evaluations of one quantity.

Two formulas that agree in exact arithmetic (a model and the model it reduces to, a
rate computed in the lab frame and in the principal frame) differ in floating point
by the rounding of each. With unit round-off ``u = eps/2`` (IEEE round to nearest), a
chain of ``n`` dependent operations on numbers of magnitude ``scale`` has a forward
error of at most ``gamma_n scale``, ``gamma_n = n u / (1 - n u)`` (Higham 2002,
*Accuracy and Stability of Numerical Algorithms*, 2nd ed., sec. 3.1); the difference of
two such evaluations is at most twice that. Eigenvectors enter with the amplification
of their perturbation theory: a backward-stable symmetric eigen-solver returns axes
within ``~ n u |A| / gap`` of exact ones (Davis-Kahan), so an expression through the
axes carries the factor ``condition = |A| / gap``.

The bound depends on the algorithm (operation count, conditioning), never on the
machine: any processor, BLAS kernel or thread count rounds within it.
"""
from __future__ import annotations

import numpy as np

#: Machine epsilon of float64 (2^-52).
EPS = float(np.finfo(np.float64).eps)

#: Longest chain of dependent operations in one orientation-model rate in 3-D, bounded
#: from above: the a4:D contraction (81 products summed), the products D.a, a.D and the
#: closure's own terms (a few 3x3 products each) -- 256 leaves room for every model.
RATE_OPERATIONS = 256


def roundoff_atol(scale: float, operations: int = RATE_OPERATIONS, condition: float = 1.0) -> float:
    """Largest difference of two evaluations: ``2 gamma_n scale condition``."""
    u = EPS / 2.0
    n = operations * max(1.0, condition)
    return 2.0 * n * u / (1.0 - n * u) * scale


def eigen_condition(a2_batch) -> float:
    """``max |a2| / (smallest gap between eigenvalues)`` over a batch of symmetric tensors."""
    worst = 1.0
    for a in np.asarray(a2_batch).reshape((-1,) + np.shape(a2_batch)[-2:]):
        vals = np.linalg.eigvalsh(a)
        worst = max(worst, np.abs(vals).max() / np.diff(vals).min())
    return float(worst)
