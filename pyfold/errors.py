"""Exceptions shared by every layer of pyfold.

Fortran kernels return an integer status and a message; :func:`checked` turns a
non-zero status into the matching typed exception, carrying the Fortran text.
The status codes mirror ``fortran/core/fold_status.f90``.
"""
from __future__ import annotations

FOLD_OK = 0
FOLD_INPUT_ERROR = 1
FOLD_NOT_CONVERGED = 2
FOLD_IO_ERROR = 3
FOLD_OVERLAP = 4
FOLD_NUMERICAL = 5


class PyfoldError(Exception):
    """Base class of every error pyfold raises on purpose."""


class InputError(PyfoldError, ValueError):
    """Invalid user input: names the offending key and the allowed range."""


class ConvergenceError(PyfoldError, RuntimeError):
    """An iterative solver stopped before reaching its tolerance."""


class NativeIOError(PyfoldError, OSError):
    """A file could not be read or written by the native core."""


class OverlapError(PyfoldError, RuntimeError):
    """Particle overlap the collision strategy could not resolve."""


class NumericalError(PyfoldError, ArithmeticError):
    """NaN, infinity or another numerical blow-up."""



class PyfoldWarning(UserWarning):
    """Base class of every warning pyfold emits on purpose."""


class DamagedRunWarning(PyfoldWarning):
    """A run file read with ``allow_damaged``: the named damaged datasets are left out
    or cut (pyfold.run_results.open_run)."""


class UnverifiedRunWarning(PyfoldWarning):
    """A run file of a format without checksums (format_version 1.0): read unverified."""


class InadmissibleOrientationWarning(PyfoldWarning, RuntimeWarning):
    """A computed ``a2`` left the set of orientation tensors (symmetric, unit
    trace, positive semi-definite) by more than the solver's error allows: the
    model (usually its closure) is outside its domain of validity there."""


class EigenvalueCrossingWarning(PyfoldWarning, RuntimeWarning):
    """Two eigenvalues of ``a2`` crossed (or came closer than the integration
    resolves) in a model built on the principal axes of ``a2`` (RSC, ARD-RSC,
    pARD, iARD-RPR, pARD-RPR, MRD): the equations are ill-posed there, and
    round-off decides which path the solution takes."""

_RAISES: dict[int, type[PyfoldError]] = {
    FOLD_INPUT_ERROR: InputError,
    FOLD_NOT_CONVERGED: ConvergenceError,
    FOLD_IO_ERROR: NativeIOError,
    FOLD_OVERLAP: OverlapError,
    FOLD_NUMERICAL: NumericalError,
}


def checked(stat: int, errmsg: bytes | str) -> None:
    """Raise the exception matching a Fortran status code, with its message."""
    if int(stat) == FOLD_OK:
        return
    text = errmsg.decode(errors="replace") if isinstance(errmsg, bytes) else str(errmsg)
    raise _RAISES.get(int(stat), PyfoldError)(text.strip() or f"native error, status {stat}")
