"""How a run ended, read from its run file's root attributes.

fold_run writes, beside the human-readable ``status`` (``"running"``, ``"ok"`` or
``"failed: step N, t = T: cause"``), the same as data (fortran/io/fold_outcome.f90):
``outcome`` (one of :data:`OUTCOMES`), ``outcome_step``, ``outcome_time``,
``outcome_cause`` and ``outcome_residual`` (relative residual of the last Stokes
solve, NaN without a solver). :func:`outcome_of` reads them; for a file written
before these attributes, or one whose status was recorded after them (``pyfold run``
marking a killed fold_run, a full disk that took the outcome's flush: the two then
disagree), the outcome is read from the status text, the kind of failure then being :data:`UNKNOWN_FAILURE`
unless the text says it.
"""
from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping, MutableMapping
from pathlib import Path
from typing import Any

#: Outcome codes, in the order of fortran/io/fold_outcome.f90 OUTCOME_NAMES (codes 1..5
#: are fold_status's: the status a failing step returned).
OUTCOMES = ("completed", "input_error", "not_converged", "io_error", "contact_cap", "blow_up",
            "untrusted_stress", "interrupted", "running")
#: A failure whose kind the file does not record (its status text alone says it failed).
UNKNOWN_FAILURE = "failed"
#: What ``pyfold run`` writes into the status of a file whose fold_run ended without
#: recording a cause (killed by a signal, the out-of-memory killer, a node lost).
NO_CAUSE = "without recording a cause"

#: The root attributes of the outcome.
_ATTRIBUTES = ("outcome", "outcome_step", "outcome_time", "outcome_cause", "outcome_residual")
_FAILED = re.compile(r"failed: step (\d+), t = ([^:]+): (.*)", re.DOTALL)


@dataclasses.dataclass(frozen=True)
class Outcome:
    """How a run ended (or that it is running).

    Attributes
    ----------
    code : str
        One of :data:`OUTCOMES`, or :data:`UNKNOWN_FAILURE`.
    status : str
        The human-readable ``status`` attribute as written.
    step, time : int or float or None
        The step the run ended at and its time [s] (completed: the last step; failed:
        the failing step); None when not recorded.
    cause : str
        The cause of a failure ("" otherwise).
    residual : float or None
        Relative residual of the last Stokes solve; None without a solver.
    """

    code: str
    status: str
    step: int | None = None
    time: float | None = None
    cause: str = ""
    residual: float | None = None

    @property
    def completed(self) -> bool:
        """The run made all its steps (status ``ok``)."""
        return self.code == "completed"

    @property
    def interrupted(self) -> bool:
        """The run was stopped from outside (a resume continues it)."""
        return self.code == "interrupted"


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode(errors="replace").strip()
    if hasattr(value, "item") and not isinstance(value, str):  # numpy scalar or 0-d array
        return _text(value.item())
    return str(value).strip()


def _number(value: Any, kind: type) -> Any:
    if value is None:
        return None
    try:
        number = kind(value.item() if hasattr(value, "item") else value)
    except (TypeError, ValueError):
        return None
    return None if isinstance(number, float) and not math.isfinite(number) else number


def from_status_text(status: str) -> Outcome:
    """The outcome a status text alone gives (files without the outcome attributes)."""
    if status == "ok":
        return Outcome("completed", status)
    if status == "running":
        return Outcome("running", status)
    match = _FAILED.match(status)
    cause = match.group(3) if match else status
    if NO_CAUSE in status:
        code = "interrupted"
    elif cause.startswith("I/O:"):
        code = "io_error"
    else:
        code = UNKNOWN_FAILURE
    if match is None:
        return Outcome(code, status, cause=cause)
    return Outcome(code, status, step=int(match.group(1)), time=_number(match.group(2), float), cause=cause)


def _agrees(code: str, status: str) -> bool:
    """Whether an outcome code and a status text say the same."""
    if code == "completed":
        return status == "ok"
    if code == "running":
        return status == "running"
    return status.startswith("failed")


def outcome_of(attrs: Mapping[str, Any]) -> Outcome | None:
    """The outcome recorded in a run file's root attributes (h5py or xarray ``attrs``);
    None when there is no ``status``."""
    if attrs.get("status") is None:
        return None
    status = _text(attrs["status"])
    code = attrs.get("outcome")
    code = None if code is None else _text(code)
    # an outcome that disagrees with the status (still "running" beside an ended status,
    # "completed" beside a failure): the status was recorded after it
    if code not in OUTCOMES or not _agrees(code, status):
        return from_status_text(status)
    return Outcome(code, status, step=_number(attrs.get("outcome_step"), int),
                   time=_number(attrs.get("outcome_time"), float),
                   cause=_text(attrs.get("outcome_cause", "")), residual=_number(attrs.get("outcome_residual"), float))


def read_outcome(path: Path) -> Outcome | None:
    """The outcome of the run file ``path``; None when it has no status or is not
    readable as HDF5."""
    import h5py

    try:
        with h5py.File(path, "r", locking=False) as f:
            return outcome_of(f.attrs)
    except (OSError, ValueError):
        return None


def write_status_outcome(attrs: MutableMapping[str, Any], status: str) -> None:
    """Set the outcome attributes to what ``status`` (just written by a caller other
    than fold_run, e.g. for a killed fold_run) says, so both agree."""
    import numpy as np

    from pyfold.run_input import fixed_string

    outcome = from_status_text(status)
    if outcome.code not in OUTCOMES:  # no code of its own: readers go by the status
        for name in _ATTRIBUTES:
            if name in attrs:
                del attrs[name]
        return
    attrs["outcome"] = fixed_string(outcome.code)
    attrs["outcome_step"] = np.int64(-1 if outcome.step is None else outcome.step)
    attrs["outcome_time"] = np.float64(math.nan if outcome.time is None else outcome.time)
    attrs["outcome_cause"] = fixed_string(outcome.cause)
    attrs["outcome_residual"] = np.float64(math.nan)
