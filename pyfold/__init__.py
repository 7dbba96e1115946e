"""pyfold: coupled multi-scale toolkit for fibre-suspension flow.

Kept light on purpose: importing :mod:`pyfold` loads neither JAX nor the native
core; submodules (``pyfold.closures``, ``pyfold.models``, ``pyfold.fit``,
``pyfold.scene``, ...) load what they need.
"""
from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("pyfold")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

from pyfold.errors import (  # noqa: E402
    ConvergenceError,
    EigenvalueCrossingWarning,
    InadmissibleOrientationWarning,
    InputError,
    PyfoldError,
    PyfoldWarning,
)

__all__ = [
    "__version__",
    "PyfoldError",
    "InputError",
    "ConvergenceError",
    "PyfoldWarning",
    "InadmissibleOrientationWarning",
    "EigenvalueCrossingWarning",
]


def __getattr__(name: str):
    # Lazy: `pyfold.open_run` without importing xarray/h5py at `import pyfold`.
    if name == "open_run":
        from pyfold.run_results import open_run

        return open_run
    raise AttributeError(f"module 'pyfold' has no attribute {name!r}")
