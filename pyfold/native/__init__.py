"""Python side of the Fortran core: shape checks, then the f2py kernels.

Each binding area has its own extension module (``pyfold._fold_stats``, ...),
imported lazily so the macro layer works without the native build. Arrays are
handed over Fortran-ordered: a Python ``(N, d)`` array of vectors is the
Fortran ``p(d, N)``.
"""
from __future__ import annotations

import importlib
from types import ModuleType

from pyfold.errors import PyfoldError


def load(name: str) -> ModuleType:
    """Import the compiled extension ``pyfold.<name>`` with a helpful error."""
    try:
        return importlib.import_module(f"pyfold.{name}")
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise PyfoldError(
            f"the native extension pyfold.{name} is not built ({exc}); "
            "install pyfold with `scripts/test` or `pip install .` (see README)"
        ) from exc
