"""One run of a sweep, wherever it executes: ``python -m pyfold.sweep.worker RUN_FOLDER --np N``.

Brings the run in ``RUN_FOLDER`` (:mod:`pyfold.sweep.store`) to completion with
``pyfold run``: nothing to do when it is ``done``; its physical failure reported
(exit 1) when it is ``failed``; ``pyfold run --resume`` from the last checkpoint when
it was ``interrupted`` (cancelled, timed out, killed), and a fresh ``pyfold run
--force`` when it was interrupted before its first checkpoint (``--resume`` refuses
that file with exit 2); ``pyfold run`` when ``queued``, or, when ``pyfold sweep run``
found it a donor (a finished run of its scene to an earlier end,
:mod:`pyfold.sweep.donors`), a copy of the donor's run file continued by ``pyfold run
--resume`` like an interrupted run. Each attempt is appended to
``attempts.jsonl`` (start, end, wall and CPU seconds, exit status, host, Slurm job). The exit status is
``pyfold run``'s. Signals (``scancel``, a time limit) reach ``pyfold run``, which stops
fold_run and keeps the partial file for the next attempt.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import socket
import sys
import threading
import time
from pathlib import Path

from pyfold.sweep import store


def slurm_job() -> str:
    """``JOBID_TASK`` of the Slurm array task this runs in ("" outside Slurm)."""
    job = os.environ.get("SLURM_ARRAY_JOB_ID") or os.environ.get("SLURM_JOB_ID") or ""
    task = os.environ.get("SLURM_ARRAY_TASK_ID")
    return f"{job}_{task}" if job and task is not None else job


def _cpu_seconds() -> float:
    """CPU time of this process and its finished children (fold_run, mpirun) [s]."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def process_table() -> dict[int, tuple[int, int]] | None:
    """pid -> (parent pid, CPU clock ticks of the process and of its finished children) of every
    process ``/proc`` shows (Linux); None where ``/proc`` cannot be read."""
    try:
        entries = [e for e in os.listdir("/proc") if e.isdigit()]
    except OSError:
        return None
    table = {}
    for name in entries:
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                text = f.read().decode("ascii", "replace")
        except OSError:  # ended meanwhile, or not ours to read
            continue
        fields = text[text.rindex(")") + 2:].split()  # after "pid (comm) ": state ppid ...
        table[int(name)] = (int(fields[1]), sum(int(x) for x in fields[11:15]))  # utime stime cutime cstime
    return table


def descendants(pid: int, table: dict[int, tuple[int, int]]) -> list[int]:
    """The live descendants of ``pid`` in ``table`` (:func:`process_table`)."""
    children: dict[int, list[int]] = {}
    for child, (ppid, _ticks) in table.items():
        children.setdefault(ppid, []).append(child)
    out, stack = [], list(children.get(pid, []))
    while stack:
        p = stack.pop()
        out.append(p)
        stack.extend(children.get(p, []))
    return out


def descendants_cpu_seconds(pid: int | None = None) -> float | None:
    """CPU time of the live descendants of ``pid`` (this process by default) and of their own
    finished children [s], from ``/proc`` (Linux); None where ``/proc`` cannot be read. The
    finished children of ``pid`` itself are not included (``RUSAGE_CHILDREN`` has them)."""
    table = process_table()
    if table is None:
        return None
    pid = os.getpid() if pid is None else pid
    return sum(table[p][1] for p in descendants(pid, table)) / os.sysconf("SC_CLK_TCK")


class _Heartbeat:
    """Rewrites the open-attempt file ``path`` with ``entry`` and the attempt's wall and CPU
    seconds so far every ``interval`` seconds, until :meth:`stop`."""

    def __init__(self, path: Path, entry: dict, cpu0: float, interval: float) -> None:
        self.path, self.entry, self.cpu0, self.interval = path, entry, cpu0, interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="pyfold-sweep-heartbeat", daemon=True)

    def beat(self) -> None:
        now = time.time()
        entry = dict(self.entry, beat=now, wall_s=now - self.entry["start"], heartbeat_s=self.interval)
        live = descendants_cpu_seconds()
        if live is not None:
            entry["cpu_s"] = _cpu_seconds() + live - self.cpu0
        try:
            store.write_atomic(self.path, json.dumps(entry))
        except OSError:  # pragma: no cover - a full disk: the run itself says what fails
            pass

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            self.beat()

    def start(self) -> None:
        self.beat()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def run_folder(folder: Path, ranks: int, executor: str = "local", heartbeat: float = store.HEARTBEAT_S) -> int:
    """Complete the run in ``folder`` (see the module docstring), renewing its open attempt every
    ``heartbeat`` seconds; returns an exit status."""
    from pyfold.cli import main as cli_main

    state = store.run_state(folder)
    if state.state == "done":
        print(f"pyfold sweep: {folder.name}: already complete", flush=True)
        return 0
    if state.state == "failed":
        print(f"pyfold sweep: {folder.name}: {state.detail} (not retried)", file=sys.stderr, flush=True)
        return 1
    argv = ["run", str(folder / store.SCENE), "-o", str(folder / store.RUN_FILE), "--np", str(ranks),
            "--oversubscribe"]
    start = time.time()
    cpu0 = _cpu_seconds()
    entry = {"start": start, "executor": executor, "host": socket.gethostname(), "pid": os.getpid(),
             "job": slurm_job(), "np": ranks, "from": state.state}
    rc = 1
    opened = store.open_attempt(folder, entry["host"], entry["pid"])
    pulse = _Heartbeat(opened, entry, cpu0, heartbeat)
    pulse.start()
    attempted = True  # False: another process made the run meanwhile, no attempt of this worker's
    try:  # from here on every exit, an exception in the donor step included, records the attempt
        if state.state == "queued":
            # no donor, or another process made the run meanwhile: act on what is there now
            state = _start_from_donor(folder, entry) or store.run_state(folder)
            if state.state in ("done", "failed", "running"):
                attempted = False
                print(f"pyfold sweep: {folder.name}: {state.state} by another process meanwhile, left as it is",
                      file=sys.stderr if state.state != "done" else sys.stdout, flush=True)
                return 0 if state.state == "done" else 1
            pulse.beat()  # the donor it started from, at once
        if state.state == "interrupted":
            rc = cli_main(argv + ["--resume", "--force"])
            if rc == 2 and store.run_state(folder).state == "interrupted":
                # nothing to resume (killed before its first checkpoint, the file is damaged, or a
                # donor's file the run's scene cannot extend after all): start over
                print(f"pyfold sweep: {folder.name}: not resumable, starting again", file=sys.stderr, flush=True)
                entry["from"] = "start (not resumable)"
                entry.pop("donor", None)
                rc = cli_main(argv + ["--force"])
        else:  # --force: only a stale run.xmf can be here (its run.h5 was removed); the lock guards the rest
            rc = cli_main(argv + ["--force"])
    finally:
        pulse.stop()
        if attempted:
            _close_attempt(folder, entry, opened, rc, start, cpu0)
        else:
            opened.unlink(missing_ok=True)
    return rc


def _close_attempt(folder: Path, entry: dict, opened: Path, rc: int, start: float, cpu0: float) -> None:
    """Record the finished attempt ``entry`` (end, exit status, state, wall and CPU time) in the run's
    attempts log and remove its open file."""
    entry.update(end=time.time(), rc=rc, state=store.run_state(folder).state)
    entry["wall_s"] = entry["end"] - start
    entry["cpu_s"] = _cpu_seconds() - cpu0
    try:
        store.record_attempt(folder, entry)
        opened.unlink(missing_ok=True)
    except OSError:  # pragma: no cover - the run's own result is what counts
        pass


def _start_from_donor(folder: Path, entry: dict) -> store.RunState | None:
    """Copy the queued run's donor into ``folder`` (:func:`pyfold.sweep.donors.start_from_donor`),
    noting it in the attempt ``entry``; the run's new state (interrupted: continued by
    ``--resume``), or None when it has no donor and starts at t = 0."""
    from pyfold.errors import PyfoldError
    from pyfold.sweep import donors

    try:
        donor = donors.start_from_donor(folder)
    except PyfoldError as exc:  # its lock held: the pyfold run below says so, naming the holder
        print(f"pyfold sweep: {folder.name}: not started from its donor: {exc}", file=sys.stderr, flush=True)
        return None
    if donor is None:
        return None
    entry.update({"from": donors.EXTENDED, "donor": donor.record()})
    print(f"pyfold sweep: {folder.name}: {donor.note()} (a copy of {donor.run_file})", flush=True)
    return store.run_state(folder)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pyfold.sweep.worker", description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--np", type=int, default=1)
    parser.add_argument("--executor", default="local")
    parser.add_argument("--heartbeat", type=float, default=store.HEARTBEAT_S,
                        help="seconds between two renewals of the open attempt (default %(default)g)")
    args = parser.parse_args(argv)
    if not args.heartbeat > 0:
        parser.error(f"--heartbeat: {args.heartbeat:g} s; must be > 0")
    return run_folder(args.folder, args.np, args.executor, args.heartbeat)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
