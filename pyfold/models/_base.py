"""Common machinery of the orientation models: parameter fields, closure, validation."""
from __future__ import annotations

import abc
import dataclasses

from typing import Any, ClassVar

import equinox as eqx
import numpy as np

from pyfold._jax import jax, jnp
from pyfold.closures import resolve, resolve_contraction
from pyfold.errors import InputError

DEFAULT_CLOSURE = "ibof"


def _as_float(x) -> jax.Array:
    return jnp.asarray(x, dtype=jnp.float64)


def parameter(default: float, low: float | None = None, high: float | None = None):
    """A float model parameter: stored as a float64 JAX array so that it is a dynamic
    leaf (differentiable, vmappable over a leading axis, no recompilation per value).

    ``low`` / ``high`` bound its allowed range: :meth:`OrientationModel.__check_init__`
    checks every bounded parameter with :func:`check_range`.
    """
    metadata = {} if low is None and high is None else {"range": (low, high)}
    return eqx.field(default=default, converter=_as_float, metadata=metadata)


def closure_field(default: Any = DEFAULT_CLOSURE):
    """The closure: a name, a plain ``f(a2)`` or a ``TabulatedA4``.

    Kept as an ordinary field rather than ``static=True``: a ``TabulatedA4`` carries
    arrays that must stay dynamic, while names and plain functions are non-array
    leaves that ``equinox.filter_jit`` / ``eqx.partition(model, eqx.is_array)``
    treat as static anyway. Use the ``equinox.filter_*`` transformations on models.
    """
    return eqx.field(default=default)


def check_range(name: str, value, low: float | None = None, high: float | None = None) -> None:
    """Raise InputError if a *concrete* parameter value leaves ``[low, high]``.

    Traced values (inside jit/vmap/grad) are not checked.
    """
    if isinstance(value, jax.core.Tracer):
        return
    v = np.asarray(value, dtype=np.float64)
    lo = -np.inf if low is None else low
    hi = np.inf if high is None else high
    if not np.all(np.isfinite(v)) or np.any(v < lo) or np.any(v > hi):
        raise InputError(f"{name}: must be finite and in [{lo:g}, {hi:g}], got {value!r}")


class OrientationModel(eqx.Module):
    """Base class: a model is a pure ``rate(t, a2, L) -> da2/dt``.

    Subclasses declare their parameters with :func:`parameter`, a ``closure`` field,
    a shape factor ``xi`` and a static ``dim`` (3 or 2), and implement :meth:`_rate`;
    :class:`ClosureModel` declares the last three once for the models of this package.

    Attributes
    ----------
    uses_eigenvectors : bool (class attribute)
        The rate depends on the principal axes of ``a2`` (RSC, ARD-RSC, iARD-RPR,
        pARD, pARD-RPR, MRD). Such a model is ill-posed where two eigenvalues of
        ``a2`` cross (see :class:`~pyfold.models.RSC`), and
        :func:`~pyfold.models.solve_orientation` / :func:`~pyfold.models.solve_batch`
        look for crossings in their solutions and warn
        (:class:`pyfold.errors.EigenvalueCrossingWarning`).
    """

    uses_eigenvectors: ClassVar[bool] = False

    @abc.abstractmethod
    def _rate(self, t, a2: jax.Array, L: jax.Array) -> jax.Array:
        """Unsymmetrised ``Da2/Dt`` of the model (subclasses define it)."""

    def a4(self, a2: jax.Array, t) -> jax.Array:
        """Fourth-order tensor from the model's closure (``(a2, t) -> a4``)."""
        return resolve(self.closure)(a2, t)  # type: ignore[attr-defined]

    def a4_contract(self, a2: jax.Array, B: jax.Array, t) -> jax.Array:
        """``a4:B`` for a symmetric ``B`` (closed form where the closure has one)."""
        return resolve_contraction(self.closure)(a2, B, t)  # type: ignore[attr-defined]

    def rate(self, t, a2: jax.Array, L: jax.Array) -> jax.Array:
        """Material derivative ``Da2/Dt`` [1/s] at time ``t`` for the gradient ``L`` (d, d).

        The result is symmetrised: the models are symmetric in exact arithmetic,
        and closures without full index symmetry would otherwise leak a tiny
        antisymmetric part into the integrated ``a2``.
        """
        a2 = jnp.asarray(a2, dtype=jnp.float64)
        L = jnp.asarray(L, dtype=jnp.float64)
        d = self.dim  # type: ignore[attr-defined]
        if a2.shape[-2:] != (d, d) or L.shape[-2:] != (d, d):
            raise InputError(
                f"{type(self).__name__}(dim={d}): a2 and L must have shape (d, d) = ({d}, {d}); "
                f"got a2 {a2.shape}, L {L.shape}"
            )
        r = self._rate(t, a2, L)
        return 0.5 * (r + jnp.swapaxes(r, -1, -2))

    def _check_parameter_ranges(self) -> None:
        # Subclass first, each class's own fields in declaration order: the order in
        # which equinox runs the classes' ``__check_init__`` methods.
        bounds = {f.name: f.metadata["range"] for f in dataclasses.fields(self) if "range" in f.metadata}
        for cls in type(self).__mro__:
            for name in vars(cls).get("__annotations__", {}):
                if name in bounds:
                    check_range(name, getattr(self, name), *bounds.pop(name))

    def __check_init__(self):
        self._check_parameter_ranges()
        d = self.dim  # type: ignore[attr-defined]
        if d not in (2, 3):
            raise InputError(f"dim must be 2 (planar) or 3 (spatial), got {d!r}")
        closure = self.closure  # type: ignore[attr-defined]
        if isinstance(closure, str):
            from pyfold.closures import get_closure

            get_closure(closure, d)  # raises InputError listing the allowed names
        else:
            resolve(closure)
            table_dim = getattr(closure, "dim", None)
            if isinstance(table_dim, int) and table_dim != d:
                raise InputError(f"closure: tabulated a4 has d = {table_dim}, but the model has dim = {d}")
        check_range("xi", self.xi, -1.0, 1.0)  # type: ignore[attr-defined]


class ClosureModel(OrientationModel):
    """An orientation model with the fields every model of this package shares.

    Attributes
    ----------
    xi : float
        Shape factor ``(beta^2 - 1)/(beta^2 + 1)`` in [-1, 1] (default 1: slender fibres).
    closure : str | callable | TabulatedA4
        Closure for ``a4`` (see :func:`pyfold.closures.resolve`; default ``"ibof"``).
    dim : int
        3 (spatial) or 2 (planar orientation); static.

    Subclasses add their own parameters with :func:`parameter` and implement
    :meth:`OrientationModel._rate`.
    """

    xi: jax.Array = parameter(1.0)
    closure: Any = closure_field()
    dim: int = eqx.field(default=3, static=True)
