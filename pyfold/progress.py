"""Plain progress lines for runs whose output is no terminal (a file, a pipe, a batch log).

A progress bar redraws one line in place, which a log file records as a stream of
control characters (or, with rich, as nothing until the end). When stderr is not a
terminal, ``pyfold run`` prints instead one self-contained line every
``interval`` seconds (:data:`DEFAULT_INTERVAL`, ``--progress-every``, or
``$PYFOLD_PROGRESS_EVERY``)::

    pyfold run: progress step 1200/4000 (30.0 %), t = 120, strain 120, elapsed 62 s, ETA 145 s, load 3.10 2.90 2.50

and a last one when the run ends. ``strain`` is ``shear_rate * t`` (the scalar
deformation rate ``sqrt(2 D:D)`` of the scene), the ETA extrapolates the steps done
by this process at their mean rate, ``load`` is the 1, 5 and 15 minute load average
(``os.getloadavg``; "n/a" where there is none). :func:`parse_line` reads such a line
back (``pyfold main`` shows each seed's latest one).
"""
from __future__ import annotations

import math
import os
import re
import threading
import time
from dataclasses import dataclass
from typing import Callable

from pyfold.errors import InputError

#: Seconds between two progress lines by default.
DEFAULT_INTERVAL = 30.0
#: Shortest interval accepted [s] (a line per second is already a busy log).
MIN_INTERVAL = 1.0
#: Longest interval accepted [s] (one day).
MAX_INTERVAL = 86400.0
#: Environment variable overriding :data:`DEFAULT_INTERVAL`.
INTERVAL_ENV = "PYFOLD_PROGRESS_EVERY"

_LINE = re.compile(r"progress step (?P<step>\d+)/(?P<total>\d+) \((?P<percent>[0-9.]+) %\), t = (?P<t>\S+), "
                   r"strain (?P<strain>\S+), elapsed (?P<elapsed>\d+) s, ETA (?P<eta>n/a|[0-9.]+)")


def check_interval(value: float, option: str = "--progress-every") -> float:
    """Refuse an interval outside [:data:`MIN_INTERVAL`, :data:`MAX_INTERVAL`] seconds (InputError naming ``option``)."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and MIN_INTERVAL <= value <= MAX_INTERVAL):
        raise InputError(f"{option}: must be a number of seconds in [{MIN_INTERVAL:g}, {MAX_INTERVAL:g}], got {value!r}")
    return float(value)


def default_interval() -> float:
    """:data:`DEFAULT_INTERVAL`, or ``$PYFOLD_PROGRESS_EVERY`` when set (checked as the option is)."""
    text = os.environ.get(INTERVAL_ENV)
    if text is None or text.strip() == "":
        return DEFAULT_INTERVAL
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"${INTERVAL_ENV}: must be a number of seconds in [{MIN_INTERVAL:g}, {MAX_INTERVAL:g}], "
                         f"got {text!r}") from None
    return check_interval(value, f"${INTERVAL_ENV}")


def load_average() -> str:
    """The 1, 5 and 15 minute load averages, or ``"n/a"``."""
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except (AttributeError, OSError):  # pragma: no cover - not Unix
        return "n/a"


def format_line(prefix: str, step: int, total: int, t: float, strain: float, elapsed: float,
                eta: float | None) -> str:
    """One progress line (see the module docstring)."""
    percent = 100.0 * step / total if total > 0 else 100.0
    eta_text = f"{eta:.0f} s" if eta is not None and math.isfinite(eta) else "n/a"
    return (f"{prefix}progress step {step}/{total} ({percent:.1f} %), t = {t:.6g}, strain {strain:.6g}, "
            f"elapsed {elapsed:.0f} s, ETA {eta_text}, load {load_average()}")


@dataclass(frozen=True)
class ProgressState:
    """What a progress line says."""

    step: int
    total: int
    percent: float
    t: float
    strain: float
    elapsed: float
    eta: float | None


def parse_line(line: str) -> ProgressState | None:
    """The state a progress line reports, or None when ``line`` is not one."""
    m = _LINE.search(line)
    if m is None:
        return None
    eta = m["eta"]
    return ProgressState(step=int(m["step"]), total=int(m["total"]), percent=float(m["percent"]), t=float(m["t"]),
                         strain=float(m["strain"]), elapsed=float(m["elapsed"]),
                         eta=None if eta == "n/a" else float(eta))


class PlainProgress:
    """Progress lines at a steady rate, from a thread, of the latest state given to :meth:`update`.

    ``emit`` receives each line; ``strain_rate`` turns ``t`` into a strain. Use as a
    context manager: the last line is written on exit (when a state was received)."""

    def __init__(self, emit: Callable[[str], None], total: int, strain_rate: float, interval: float,
                 prefix: str = "pyfold run: ", clock: Callable[[], float] = time.monotonic):
        self.emit, self.total, self.strain_rate = emit, int(total), float(strain_rate)
        self.interval, self.prefix, self.clock = float(interval), prefix, clock
        self._lock = threading.Lock()
        self._state: tuple[int, int, float] | None = None  # step, total, t
        self._first_step: int | None = None
        self._start = clock()
        self._first_time = self._start
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def __enter__(self) -> PlainProgress:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.write()

    def update(self, step: int, total: int, t: float) -> None:
        with self._lock:
            if self._first_step is None:
                # the first state seen: a resumed run starts far from step 0, and the ETA
                # counts only the steps this process made
                self._first_step = step
                self._first_time = self.clock()
            self._state = (int(step), int(total), float(t))

    def line(self) -> str | None:
        """The line for the latest state (None before the first one)."""
        with self._lock:
            if self._state is None:
                return None
            step, total, t = self._state
            now = self.clock()
            done = step - self._first_step
            spent = now - self._first_time
            eta = (total - step) * spent / done if done > 0 and spent > 0 else (0.0 if step >= total else None)
        return format_line(self.prefix, step, total, t, self.strain_rate * t, now - self._start, eta)

    def write(self) -> None:
        text = self.line()
        if text is not None:
            self.emit(text)

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            self.write()


def latest_in_log(path, tail_bytes: int = 8192) -> ProgressState | None:
    """The last progress line of a log file (its last ``tail_bytes``), or None."""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - tail_bytes))
            text = f.read().decode("utf-8", errors="replace")
    except OSError:
        return None
    for line in reversed(text.splitlines()):
        state = parse_line(line)
        if state is not None:
            return state
    return None


def describe(name: str, state: ProgressState | None) -> str:
    """``name: step a/b (p %), strain s, ETA e s`` (or ``name: starting``)."""
    if state is None:
        return f"{name}: starting (placement, first steps)"
    eta = f"{state.eta:.0f} s" if state.eta is not None else "n/a"
    return (f"{name}: step {state.step}/{state.total} ({state.percent:.1f} %), strain {state.strain:.6g}, "
            f"ETA {eta}")
