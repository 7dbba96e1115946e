"""Closure approximations ``a4 = f(a2)`` for fibre orientation models.

Every closure is a pure JAX function of ``a2`` with shape ``(..., d, d)`` returning
``(..., d, d, d, d)`` (d = 3, and d = 2 for planar orientation where the literature
defines it); all are jit-, vmap- and grad-able in float64.

Public API
----------
get_closure(name, dim=3)
    The closure function; unknown names raise :class:`pyfold.errors.InputError`.
available(dim=3)
    Names of the closures defined in that dimension.
resolve(closure)
    Uniform two-argument callable ``(a2, t) -> a4`` from a name, a plain ``f(a2)`` or
    a :class:`TabulatedA4` (the "exact" closure: a4 measured in a simulation).
"""
from __future__ import annotations

import dataclasses
from typing import Callable

from pyfold._jax import jax, jnp
from pyfold.errors import InputError
from pyfold.closures.linear import linear
from pyfold.closures.quadratic import quadratic
from pyfold.closures.hybrid import hybrid
from pyfold.closures.tabulated import TabulatedA4
from pyfold.closures.implicit import siq, sihyb
from pyfold.closures.symmetric_quadratic import sqc
from pyfold.closures.natural import natural_2d, natural_3d
from pyfold.closures.ibof import ibof
from pyfold.closures.orthotropic import ore, orf, orl, ors, orw, orw3
from pyfold.closures.exact import fec

__all__ = [
    "get_closure",
    "available",
    "resolve",
    "TabulatedA4",
    "CLOSURES",
    "linear",
    "quadratic",
    "hybrid",
    "siq",
    "sihyb",
    "sqc",
    "natural_2d",
    "natural_3d",
    "ibof",
    "ore",
    "ors",
    "orf",
    "orl",
    "orw",
    "orw3",
    "fec",
]

Closure = Callable[[jax.Array], jax.Array]

#: name -> {dim: function}. One entry per published closure and dimension.
CLOSURES: dict[str, dict[int, Closure]] = {
    "linear": {2: linear, 3: linear},
    "quadratic": {2: quadratic, 3: quadratic},
    "hybrid": {2: hybrid, 3: hybrid},
    # Karl, Schneider & Böhlke (2023) call their implicit hybrid closure SIHYB;
    # "implicit_hybrid" is the same function under the contract's generic name.
    "implicit_hybrid": {2: sihyb, 3: sihyb},
    "sihyb": {2: sihyb, 3: sihyb},
    "siq": {2: siq, 3: siq},
    "sqc": {2: sqc, 3: sqc},
    # 3-D: the natural form with pyfold's own fit to FEC (not the published NAT1/NAT2)
    "natural": {2: natural_2d, 3: natural_3d},
    "ibof": {3: ibof},
    "ore": {3: ore},
    "ors": {3: ors},
    "orf": {3: orf},
    "orl": {3: orl},
    "orw": {3: orw},
    "orw3": {3: orw3},
    "fec": {2: fec, 3: fec},
}

_EXACT_HINT = (
    "'exact' is not a function of a2: build pyfold.closures.TabulatedA4(times, a4_series) "
    "from the simulation's a4 and pass that object instead"
)


#: Published closures deliberately not provided, with the reason and the alternative.
NOT_PROVIDED: dict[str, str] = {
    name: (
        f"the published 3-D natural closure {name.upper()} (Verleye & Dupret 1993; Dupret & "
        "Verleye 1999) is not provided: its coefficient tables are unavailable (not found in any "
        "source reachable when pyfold was written). Use 'natural' (pyfold's own least-squares refit "
        "of the same natural-closure form to the exact closure; its coefficients are not the "
        "published ones) or 'fec' (the exact closure of Jeffery's equation that NAT1/NAT2 approximate)"
    )
    for name in ("nat1", "nat2")
}


def available(dim: int = 3) -> tuple[str, ...]:
    """Names of the closures ``f(a2)`` defined in dimension ``dim`` (2 or 3).

    The data-driven "exact" closure is not listed: it is a :class:`TabulatedA4`.
    """
    if dim not in (2, 3):
        raise InputError(f"dim must be 2 (planar) or 3 (spatial), got {dim!r}")
    return tuple(name for name, impl in CLOSURES.items() if dim in impl)


def get_closure(name: str, dim: int = 3) -> Closure:
    """The closure ``a4 = f(a2)`` called ``name`` (case-insensitive) in dimension ``dim``.

    Raises
    ------
    InputError
        Unknown name (the message lists the allowed names), a closure that the
        literature does not define in ``dim``, or ``name == "exact"``.
    """
    if dim not in (2, 3):
        raise InputError(f"dim must be 2 (planar) or 3 (spatial), got {dim!r}")
    key = str(name).strip().lower()
    if key == "exact":
        raise InputError(f"closure {name!r}: {_EXACT_HINT}")
    if key in NOT_PROVIDED:
        raise InputError(f"closure {name!r}: {NOT_PROVIDED[key]}")
    if key not in CLOSURES:
        raise InputError(
            f"closure: unknown name {name!r}; allowed: {', '.join(sorted(CLOSURES))}, "
            "or a TabulatedA4 for 'exact'"
        )
    impl = CLOSURES[key]
    if dim not in impl:
        raise InputError(
            f"closure {key!r} is not defined for dim={dim}; it exists for dim in {sorted(impl)}; "
            f"closures available in {dim}-D: {', '.join(available(dim))}"
        )
    return impl[dim]


@dataclasses.dataclass(frozen=True)
class _ByName:
    """``(a2, t) -> a4`` for a registered name; the dimension is read from ``a2``'s shape
    (static under jit). Hashable and comparable, so it can be a static field."""

    name: str

    def __call__(self, a2: jax.Array, t=None) -> jax.Array:
        return get_closure(self.name, a2.shape[-1])(a2)


@dataclasses.dataclass(frozen=True)
class _TimeIndependent:
    """``(a2, t) -> a4`` wrapping a plain ``f(a2)``; hashable when ``f`` is."""

    fn: Closure

    def __call__(self, a2: jax.Array, t=None) -> jax.Array:
        return self.fn(a2)


def resolve(closure) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """Turn any closure specification into a uniform callable ``(a2, t) -> a4``.

    Parameters
    ----------
    closure : str | TabulatedA4 | callable
        A registered name (validated now for d = 2 or 3), a :class:`TabulatedA4`
        (returned unchanged: it already takes ``(a2, t)``), or a plain ``f(a2)``.

    Raises
    ------
    InputError
        Unknown name, ``"exact"`` given as a string, or a non-callable object.
    """
    if isinstance(closure, TabulatedA4):
        return closure
    if isinstance(closure, str):
        key = closure.strip().lower()
        if key == "exact":
            raise InputError(f"closure {closure!r}: {_EXACT_HINT}")
        if key not in CLOSURES:
            get_closure(key)  # raises the InputError listing the allowed names
        return _ByName(key)
    if isinstance(closure, (_ByName, _TimeIndependent)):
        return closure
    if callable(closure):
        return _TimeIndependent(closure)
    raise InputError(
        f"closure: expected a name, a callable f(a2) or a TabulatedA4, got {type(closure).__name__}"
    )


#: Closures whose contraction ``a4:B`` has a cheaper closed form than forming a4;
#: name -> {dim: (a2, B) -> a4:B}. Same values to round-off (tested).
CONTRACTIONS: dict[str, dict[int, Callable[[jax.Array, jax.Array], jax.Array]]] = {}


def _register_contractions() -> None:
    from pyfold.closures.ibof import ibof_contract
    from pyfold.closures.natural import natural_3d_contract

    def quadratic_contract(a2, B):
        return a2 * jnp.sum(a2 * B, axis=(-2, -1))[..., None, None]

    CONTRACTIONS.update({
        "ibof": {3: ibof_contract},
        "natural": {3: natural_3d_contract},
        "quadratic": {2: quadratic_contract, 3: quadratic_contract},
    })


_register_contractions()


@dataclasses.dataclass(frozen=True)
class _Contraction:
    """``(a2, B, t) -> a4:B`` for any closure: the closed form where one exists,
    else the closure's a4 contracted (hashable, so it can sit in a static field)."""

    closure: object

    def __call__(self, a2: jax.Array, B: jax.Array, t=None) -> jax.Array:
        if isinstance(self.closure, _ByName):
            fast = CONTRACTIONS.get(self.closure.name, {}).get(a2.shape[-1])
            if fast is not None:
                return fast(a2, B)
        a4 = self.closure(a2, t)
        return jnp.einsum("...ijkl,...kl->...ij", a4, B)


def resolve_contraction(closure) -> Callable[[jax.Array, jax.Array, jax.Array], jax.Array]:
    """Uniform ``(a2, B, t) -> a4:B`` (``B`` symmetric) for any closure specification
    accepted by :func:`resolve`; orientation models call this when they need only
    the contraction, which for IBOF and the natural closure is ~5x cheaper."""
    return _Contraction(resolve(closure))

