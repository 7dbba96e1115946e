"""Executors: what runs a sweep's missing runs. One interface (:class:`Executor`), two kinds:

``local``
    As many runs at once as the usable cores allow (cores // ranks per run, at least
    one), each through :mod:`pyfold.sweep.worker` in its own process (its MPI ranks
    under ``mpirun`` when ``np > 1``), its output in ``runs/<id>/log.txt``.
``slurm``
    A Slurm job array (:mod:`pyfold.sweep.slurm`).

Both leave the same files (:mod:`pyfold.sweep.store`), so a sweep started with one can
be continued with the other.
"""
from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Protocol

from pyfold.sweep import donors, store
from pyfold.sweep.progress import Progress
from pyfold.sweep.spec import Resources

#: Executor names (the default first).
EXECUTORS = ("local", "slurm")
#: Seconds between looks at the runs' states.
POLL_SECONDS = 0.5


@dataclasses.dataclass
class Outcome:
    """What an executor left: run id -> state, and the causes of failed runs."""

    states: dict[str, str]
    failures: dict[str, str]
    submitted: bool = False  # slurm --no-wait: submitted, not waited for


class Executor(Protocol):
    """Runs the given runs of a prepared sweep folder to completion (or to a physical failure)."""

    name: str

    def execute(self, root: Path, run_ids: list[str], resources: Resources, progress: Progress) -> Outcome:
        """Run ``run_ids`` (each a folder under ``root/runs``); returns their final states."""
        ...


def states_of(root: Path, run_ids: list[str]) -> dict[str, store.RunState]:
    return {rid: store.run_state(store.run_folder(root, rid)) for rid in run_ids}


def bring_build_up_to_date() -> None:
    """Locate fold_run once here (importing pyfold's extension modules, which brings an editable
    build up to date) before workers start, so that they do not all rebuild it at once."""
    from pyfold.commands.run import find_fold_run

    find_fold_run()


def worker_command(folder: Path, ranks: int, executor: str) -> list[str]:
    """The command that completes one run (the python running pyfold now)."""
    return [sys.executable, "-m", "pyfold.sweep.worker", str(folder), "--np", str(ranks), "--executor", executor]


class LocalExecutor:
    """Runs on this machine, as many at once as the cores allow."""

    name = "local"

    def __init__(self, parallel: int | None = None) -> None:
        self.parallel = parallel

    def slots(self, ranks: int) -> int:
        from pyfold.commands.run import usable_cores

        return self.parallel or max(1, usable_cores() // ranks)

    def execute(self, root: Path, run_ids: list[str], resources: Resources, progress: Progress) -> Outcome:
        slots = self.slots(resources.np)
        bring_build_up_to_date()
        current = {rid: s.state for rid, s in states_of(root, run_ids).items()}
        todo = [rid for rid in run_ids if current[rid] in ("queued", "interrupted")]
        live: dict[str, subprocess.Popen] = {}
        started: dict[str, float] = {}
        walls: list[float] = []
        failures: dict[str, str] = {rid: s.detail for rid, s in states_of(root, run_ids).items() if s.state == "failed"}
        progress.event(f"{len(todo)} run(s) to run, {slots} at once with {resources.np} rank(s) each", current,
                       walls, slots)
        try:
            while todo or live:
                while todo and len(live) < slots:
                    rid = todo.pop(0)
                    folder = store.run_folder(root, rid)
                    donor = donors.planned(folder) if current[rid] == "queued" else None
                    with open(folder / store.LOG, "a", encoding="utf-8") as log:
                        live[rid] = subprocess.Popen(worker_command(folder, resources.np, self.name), stdout=log,
                                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                                     start_new_session=True)
                    started[rid] = time.monotonic()
                    current[rid] = "running"
                    progress.event(f"{rid} started" + (f", {donor.note()}" if donor else ""), current, walls,
                                   slots)
                time.sleep(POLL_SECONDS)
                for rid, proc in list(live.items()):
                    if proc.poll() is None:
                        continue
                    del live[rid]
                    state = store.run_state(store.run_folder(root, rid))
                    current[rid] = state.state
                    wall = time.monotonic() - started[rid]
                    if state.state == "done":
                        walls.append(wall)
                        progress.event(f"{rid} done in {wall:.0f} s", current, walls, slots)
                    elif state.state == "failed":
                        failures[rid] = state.detail
                        progress.event(f"{rid} failed: {state.detail}", current, walls, slots)
                    else:
                        failures[rid] = (f"pyfold run exited with status {proc.returncode}; see "
                                         f"{store.run_folder(root, rid) / store.LOG}")
                        current[rid] = "failed" if proc.returncode not in (0,) else state.state
                        progress.event(f"{rid} ended with status {proc.returncode} ({state.state})", current,
                                       walls, slots)
                progress.update(current, walls, slots)
        except BaseException:
            for proc in live.values():  # the worker's pyfold run stops fold_run and keeps run.h5.partial
                try:
                    os.kill(proc.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
            for proc in live.values():
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:  # pragma: no cover
                    os.killpg(proc.pid, signal.SIGKILL)
            raise
        final = {rid: s.state for rid, s in states_of(root, run_ids).items()}
        return Outcome(final, {rid: why for rid, why in failures.items() if final.get(rid) != "done"})


def make_executor(name: str, **options) -> Executor:
    """The executor called ``name`` (one of :data:`EXECUTORS`)."""
    if name == "local":
        return LocalExecutor(options.get("parallel"))
    from pyfold.sweep.slurm import SlurmExecutor

    return SlurmExecutor(wait=options.get("wait", True))
