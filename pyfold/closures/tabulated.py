"""The "exact" closure: a4 tabulated in time (e.g. measured in a direct simulation)."""
from __future__ import annotations

import equinox as eqx
import numpy as np

from pyfold._jax import jax, jnp
from pyfold.errors import InputError


class TabulatedA4(eqx.Module):
    """a4(t) interpolated linearly in time from a table, ignoring the a2 it is given.

    Feeds a direct simulation's own fourth-order tensor into an orientation model,
    so that the model error can be separated from the closure error.

    Parameters
    ----------
    times : array (nt,)
        Strictly increasing sample times [s], ``nt >= 2``.
    a4_series : array (nt, d, d, d, d)
        Fourth-order tensor at each time, d in {2, 3}.

    Notes
    -----
    Outside ``[times[0], times[-1]]`` the end values are held constant (no
    extrapolation). ``closure(a2, t)`` returns shape ``(d, d, d, d)`` whatever the
    leading axes of ``a2``; vmap over ``a2`` for batches.
    """

    times: jax.Array
    a4_series: jax.Array

    def __init__(self, times, a4_series):
        t = np.asarray(times, dtype=np.float64)
        a4 = np.asarray(a4_series, dtype=np.float64)
        if t.ndim != 1 or t.size < 2:
            raise InputError(f"times: expected a 1-D array of at least 2 samples, got shape {t.shape}")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
            raise InputError("times: must be finite and strictly increasing")
        d = a4.shape[-1] if a4.ndim == 5 else None
        if a4.ndim != 5 or a4.shape[0] != t.size or d not in (2, 3) or a4.shape[1:] != (d,) * 4:
            raise InputError(
                f"a4_series: expected shape (nt={t.size}, d, d, d, d) with d in {{2, 3}}, got {a4.shape}"
            )
        if not np.all(np.isfinite(a4)):
            raise InputError("a4_series: contains NaN or infinity")
        self.times = jnp.asarray(t)
        self.a4_series = jnp.asarray(a4)

    @property
    def dim(self) -> int:
        return int(self.a4_series.shape[-1])

    def __call__(self, a2: jax.Array, t) -> jax.Array:
        del a2  # the tabulated tensor is the truth; a2 is accepted for a uniform signature
        t = jnp.clip(jnp.asarray(t, dtype=self.times.dtype), self.times[0], self.times[-1])
        i = jnp.clip(jnp.searchsorted(self.times, t, side="right") - 1, 0, self.times.shape[0] - 2)
        t0, t1 = self.times[i], self.times[i + 1]
        w = (t - t0) / (t1 - t0)
        return (1.0 - w) * self.a4_series[i] + w * self.a4_series[i + 1]
