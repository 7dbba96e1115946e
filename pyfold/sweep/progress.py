"""Progress of a sweep: counts per state with an ETA, as a live table on a terminal and
as plain lines otherwise (a log file, a batch job's output)."""
from __future__ import annotations

import sys
import time
from collections import Counter
from typing import Callable

from pyfold.sweep.store import STATES


def counts_line(states: dict[str, str]) -> str:
    """``3 done, 1 running, 0 interrupted, 2 queued, 0 failed`` of run id -> state."""
    c = Counter(states.values())
    return ", ".join(f"{c.get(s, 0)} {s}" for s in STATES)


def eta_seconds(walls: list[float], remaining: int, parallel: int) -> float | None:
    """Seconds left: the mean wall time of the runs finished so far, times the runs left,
    over the runs at once. None before any run has finished."""
    if not walls or remaining <= 0:
        return 0.0 if remaining <= 0 else None
    return sum(walls) / len(walls) * remaining / max(1, parallel)


def _eta_text(eta: float | None) -> str:
    if eta is None:
        return "ETA: after the first run"
    return f"ETA {int(eta) // 60}:{int(eta) % 60:02d}"


class Progress:
    """Shows a sweep's progress: ``update(states, walls, parallel)`` and ``event(text)``.

    On a terminal a rich live table (done / running / interrupted / queued / failed, ETA);
    otherwise one plain line per event, with the counts."""

    def __init__(self, total: int, title: str, stream=None) -> None:
        self.total = total
        self.title = title
        self.stream = stream or sys.stdout
        self.live = None
        self.started = time.monotonic()
        self._last: tuple = ()
        if self.stream.isatty():
            from rich.console import Console
            from rich.live import Live

            self.live = Live(console=Console(file=self.stream), refresh_per_second=2, transient=False)
            self.live.start()

    def _table(self, states: dict[str, str], eta: float | None):
        from rich.table import Table

        c = Counter(states.values())
        table = Table(title=self.title)
        for s in STATES:
            table.add_column(s, justify="right")
        table.add_column("ETA", justify="right")
        table.add_column("elapsed", justify="right")
        elapsed = time.monotonic() - self.started
        table.add_row(*(str(c.get(s, 0)) for s in STATES), _eta_text(eta).replace("ETA ", "").replace("ETA: ", ""),
                      f"{int(elapsed) // 60}:{int(elapsed) % 60:02d}")
        return table

    def update(self, states: dict[str, str], walls: list[float], parallel: int) -> None:
        remaining = sum(1 for s in states.values() if s not in ("done", "failed"))
        eta = eta_seconds(walls, remaining, parallel)
        if self.live is not None:
            self.live.update(self._table(states, eta))

    def event(self, text: str, states: dict[str, str], walls: list[float], parallel: int) -> None:
        remaining = sum(1 for s in states.values() if s not in ("done", "failed"))
        line = f"pyfold sweep: {text} [{counts_line(states)}; {_eta_text(eta_seconds(walls, remaining, parallel))}]"
        if self.live is not None:
            self.live.console.print(line, markup=False, highlight=False)
            self.update(states, walls, parallel)
        else:
            print(line, file=self.stream, flush=True)

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()
            self.live = None


def no_progress(*_args) -> None:  # pragma: no cover - a stand-in
    return None


Reporter = Callable[[str], None]
