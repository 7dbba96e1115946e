"""The Slurm executor: a sweep's missing runs as one job array per submission.

``sbatch`` gets one array task per run (``--ntasks`` = ranks per run, ``--time``,
``--partition``, ``--mem`` from the sweep's resources); each task runs
:mod:`pyfold.sweep.worker` on its run folder, whose ``pyfold run --np N`` starts
fold_run under ``mpirun`` inside the allocation (Open MPI takes its slots from Slurm).
The job scripts, the list of run folders of each array, the job ids (``jobs.json``)
and the tasks' output are kept in ``DIR/slurm/``.

Waiting (the default) polls ``squeue`` until no task of the sweep is pending or
running; then a run whose task ended without completing it (time limit, ``scancel``,
a killed fold_run, a lost node) is resubmitted, and resumes from its checkpoint, up to
``resources.retries`` times; a run that failed for a physical reason (status
``failed: ...`` recorded by fold_run) is reported with that cause and not resubmitted.
``sacct`` (where the cluster keeps accounting) adds each task's final Slurm state to
``pyfold sweep status``.
"""
from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

from pyfold.errors import InputError, PyfoldError
from pyfold.sweep import store
from pyfold.sweep.executors import Outcome, bring_build_up_to_date, states_of, worker_command
from pyfold.sweep.progress import Progress
from pyfold.sweep.spec import Resources

SLURM = "slurm"
JOBS = "jobs.json"
#: Seconds between two looks at squeue.
POLL_SECONDS = 2.0
#: Seconds a Slurm command may take.
COMMAND_TIMEOUT = 60
#: squeue states of a task that has not ended.
ACTIVE = ("PENDING", "RUNNING", "CONFIGURING", "COMPLETING", "SUSPENDED", "REQUEUED", "RESIZING", "SIGNALING",
          "STAGE_OUT", "REQUEUE_HOLD", "REQUEUE_FED", "RESV_DEL_HOLD", "STOPPED")


def _command(argv: list[str]) -> subprocess.CompletedProcess:
    if shutil.which(argv[0]) is None:
        raise PyfoldError(f"--executor slurm: {argv[0]} is not on PATH; run on a Slurm cluster's login node "
                          "(scripts/slurm_local start gives a single-node Slurm on this machine)")
    try:
        return subprocess.run(argv, capture_output=True, text=True, timeout=COMMAND_TIMEOUT)
    except subprocess.TimeoutExpired:
        raise PyfoldError(f"{argv[0]} did not answer within {COMMAND_TIMEOUT} s (is slurmctld running?)") from None


def read_jobs(root: Path) -> list[dict]:
    """The arrays submitted for the sweep in ``root`` (oldest first)."""
    try:
        return json.loads((root / SLURM / JOBS).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []


def _write_jobs(root: Path, jobs: list[dict]) -> None:
    path = root / SLURM / JOBS
    tmp = path.with_name(f".{JOBS}.{os.getpid()}")
    tmp.write_text(json.dumps(jobs, indent=1), encoding="utf-8")
    os.replace(tmp, path)


def queue(job_ids: list[str]) -> dict[tuple[str, int], str]:
    """(array job id, task index) -> squeue state, for the tasks of ``job_ids`` not yet ended."""
    if not job_ids:
        return {}
    proc = _command(["squeue", "-h", "-r", "-o", "%F %K %T"])
    if proc.returncode != 0:
        raise PyfoldError(f"squeue failed: {proc.stderr.strip() or proc.stdout.strip()}")
    wanted, out = set(job_ids), {}
    for line in proc.stdout.splitlines():
        fields = line.split()
        if len(fields) == 3 and fields[0] in wanted and fields[1].isdigit():
            out[fields[0], int(fields[1])] = fields[2]
    return out


def accounting(job_ids: list[str]) -> dict[tuple[str, int], str]:
    """(array job id, task index) -> final Slurm state from sacct ({} without accounting)."""
    if not job_ids or shutil.which("sacct") is None:
        return {}
    try:
        proc = subprocess.run(["sacct", "-n", "-P", "-X", "-o", "JobID,State", "-j", ",".join(job_ids)],
                              capture_output=True, text=True, timeout=COMMAND_TIMEOUT)
    except subprocess.TimeoutExpired:
        return {}
    if proc.returncode != 0:
        return {}
    out = {}
    for line in proc.stdout.splitlines():
        job, _, state = line.partition("|")
        head, _, task = job.partition("_")
        if task.isdigit():
            out[head, int(task)] = state.split()[0] if state else ""
    return out


def task_of(jobs: list[dict]) -> dict[str, tuple[str, int]]:
    """run id -> (array job id, task index) of its latest submission."""
    out = {}
    for job in jobs:
        for index, rid in enumerate(job["runs"]):
            out[rid] = (job["job"], index)
    return out


def active_runs(root: Path) -> dict[str, str]:
    """run id -> squeue state, for runs whose latest task is pending or running."""
    jobs = read_jobs(root)
    tasks = task_of(jobs)
    live = queue(sorted({j for j, _ in tasks.values()}))
    return {rid: live[t] for rid, t in tasks.items() if live.get(t) in ACTIVE}


def job_script(root: Path, list_file: Path, ranks: int) -> str:
    """The batch script of one array: its task's run folder from ``list_file``, then the worker."""
    worker = " ".join(shlex.quote(a) for a in worker_command(Path("FOLDER"), ranks, "slurm"))
    worker = worker.replace(" FOLDER ", ' "$folder" ')
    return ("#!/bin/bash\n"
            "# A pyfold sweep's job array (pyfold/sweep/slurm.py): task i runs line i + 1 of the list.\n"
            "set -u\n"
            f"folder=$(sed -n \"$((SLURM_ARRAY_TASK_ID + 1))p\" {shlex.quote(str(list_file))})\n"
            f"exec {worker}\n")


def submit(root: Path, run_ids: list[str], resources: Resources, name: str) -> str:
    """Submit ``run_ids`` as one job array; returns its job id (recorded in ``jobs.json``)."""
    bring_build_up_to_date()
    folder = root / SLURM
    folder.mkdir(exist_ok=True)
    jobs = read_jobs(root)
    k = len(jobs) + 1
    list_file = folder / f"array-{k}.txt"
    list_file.write_text("".join(f"{store.run_folder(root.resolve(), rid)}\n" for rid in run_ids), encoding="utf-8")
    script = folder / f"array-{k}.sh"
    script.write_text(job_script(root.resolve(), list_file.resolve(), resources.np), encoding="utf-8")
    argv = ["sbatch", "--parsable", f"--job-name=pyfold-{name}", f"--array=0-{len(run_ids) - 1}",
            f"--ntasks={resources.np}", f"--time={resources.time}",
            f"--output={(folder / '%A_%a.out').resolve()}", f"--chdir={root.resolve()}"]
    if resources.partition:
        argv.append(f"--partition={resources.partition}")
    if resources.mem:
        argv.append(f"--mem={resources.mem}")
    proc = _command(argv + [str(script.resolve())])
    if proc.returncode != 0:
        message = proc.stderr.strip() or proc.stdout.strip()
        if "partition" in message.lower() or "time limit" in message.lower():
            raise InputError(f"--partition / --time: sbatch refused the job array: {message}")
        raise PyfoldError(f"sbatch failed (exit {proc.returncode}): {message}")
    job = proc.stdout.strip().split(";")[0]
    jobs.append({"job": job, "runs": run_ids, "submitted": time.time(), "np": resources.np, "time": resources.time,
                 "partition": resources.partition, "mem": resources.mem, "script": script.name})
    _write_jobs(root, jobs)
    return job


def finished_walls(root: Path, run_ids: list[str]) -> list[float]:
    """Wall seconds of the complete runs among ``run_ids`` (their attempts summed): the ETA's basis."""
    walls = []
    for rid in run_ids:
        folder = store.run_folder(root, rid)
        if store.run_state(folder).state == "done":
            tries = store.attempts(folder)
            if tries:
                walls.append(sum(float(a.get("wall_s", 0.0)) for a in tries))
    return walls


class SlurmExecutor:
    """Runs a sweep as Slurm job arrays (see the module docstring)."""

    name = "slurm"

    def __init__(self, wait: bool = True) -> None:
        self.wait = wait

    def execute(self, root: Path, run_ids: list[str], resources: Resources, progress: Progress,
                name: str = "sweep") -> Outcome:
        submissions = 0
        peak = 0
        seen: dict[str, str] = {}
        while True:
            states = {rid: s for rid, s in states_of(root, run_ids).items()}
            active = active_runs(root)
            current = {rid: ("running" if rid in active and active[rid] != "PENDING" else
                             "queued" if rid in active else s.state) for rid, s in states.items()}
            failures = {rid: s.detail for rid, s in states.items() if s.state == "failed"}
            todo = [rid for rid, s in states.items() if s.state in ("queued", "interrupted") and rid not in active]
            if todo and submissions <= resources.retries:
                job = submit(root, todo, resources, name)
                submissions += 1
                for rid in todo:
                    current[rid] = "queued"
                verb = "submitted" if submissions == 1 else "resubmitted (resuming from their checkpoints)"
                progress.event(f"{len(todo)} run(s) {verb} as job array {job}", current, [], len(todo))
                active = active_runs(root)
            elif todo and not active:
                for rid in todo:
                    failures[rid] = (f"still {states[rid].state} after {submissions} submission(s) "
                                     f"(resources.retries = {resources.retries}); see {root / SLURM}")
                return Outcome(current, failures)
            if not self.wait:
                return Outcome(current, failures, submitted=True)
            if not active and not todo:
                return Outcome({rid: s.state for rid, s in states_of(root, run_ids).items()}, failures)
            while active:
                time.sleep(POLL_SECONDS)
                active = active_runs(root)
                now = {rid: s.state for rid, s in states_of(root, run_ids).items()}
                walls = finished_walls(root, run_ids)
                # tasks at once: the most seen running (a moment between two tasks shows one fewer)
                peak = max(peak, sum(1 for state in active.values() if state != "PENDING"))
                running = max(1, peak)
                for rid in run_ids:
                    shown = ("running" if rid in active and active[rid] != "PENDING" else
                             "queued" if rid in active else now[rid])
                    if seen.get(rid) != shown:
                        seen[rid] = shown
                        current[rid] = shown
                        if shown in ("done", "failed", "interrupted", "running"):
                            progress.event(f"{rid} {shown}", current, walls, running)
                progress.update(current, walls, running)
