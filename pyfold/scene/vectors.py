"""Axis vectors of a scene (``particles[i].direction``, ``particles[i].orientations``),
normalised at the door.

Every component may be as large as a float allows (``1e308``) or as small
(``5e-324``): each row is divided by its largest ``|component|`` before its norm is
taken, so the squares neither overflow to infinity nor underflow to zero, and the
unit vector is exact to round-off. A row that is zero or not finite is refused,
naming the key and the row; numpy emits no warning on any input.
"""
from __future__ import annotations

import numpy as np

__all__ = ["unit_rows"]


def unit_rows(rows, what: str = "entry") -> tuple[np.ndarray | None, str | None]:
    """Normalise the rows of an ``(n, dim)`` array of axes.

    Parameters
    ----------
    rows : array_like (n, dim)
    what : str
        How a row is called in the message (``"entry"``, ``"row"``).

    Returns
    -------
    (unit, None) or (None, message)
        ``unit`` the rows scaled to length 1; ``message`` why the first bad row is
        refused (``row 3 is zero``, ``entry 0 is not finite: [...]``), for the caller to
        report under its key.
    """
    arr = np.asarray(rows, dtype=np.float64)
    arr = arr.reshape(-1, arr.shape[-1]) if arr.ndim else arr.reshape(1, 1)
    finite = np.all(np.isfinite(arr), axis=1)
    if not np.all(finite):
        k = int(np.argmin(finite))
        return None, f"{what} {k} is not finite: {arr[k].tolist()}; allowed: finite components"
    scale = np.max(np.abs(arr), axis=1) if arr.size else np.zeros(len(arr))
    if np.any(scale == 0.0):
        k = int(np.argmin(scale))
        return None, f"{what} {k} is zero; allowed: a non-zero vector (it is normalised)"
    with np.errstate(under="ignore"):  # a component below 1e-308 of the largest is 0 in the unit vector
        scaled = arr / scale[:, None]  # largest |component| 1: the sum of squares is in [1, dim]
        return scaled / np.sqrt(np.sum(scaled * scaled, axis=1))[:, None], None
