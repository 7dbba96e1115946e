"""The sweep folder: a manifest, one folder per run, and what state each run is in.

Layout of ``DIR``::

    sweep.json            the manifest: name, axes, seeds, resources, and every run
                          (its identity, point and seed) of the sweep last run here
    runs/<id>/scene.toml  the run's scene
    runs/<id>/run.h5      its run file (run.h5.partial while it runs; run.xmf beside it)
    runs/<id>/attempts.jsonl   one line per attempt (start, end, exit status, executor,
                          host, Slurm job), the source of the costs in sweep.nc
    runs/<id>/attempt.<host>.<pid>.open.json   the attempt under way, renewed by its worker
                          every few seconds (:func:`attempts`: one that stopped being renewed
                          was killed, and counts with the costs of its last renewal)
    runs/<id>/log.txt     what ``pyfold run`` printed (local executor)
    runs/<id>/donor.json  its donor, a finished run of its scene to an earlier end that it
                          starts as a copy of (:mod:`pyfold.sweep.donors`), found while it was queued
    slurm/                job scripts, run lists, job ids and logs of the Slurm executor
    sweep.nc              the gathered dataset (``pyfold sweep gather``)
    reports/<point>/      ``pyfold report`` of each point's seeds

A run's state (:func:`run_state`) is read from its files alone (the outcome
attributes of ``run.h5``, :mod:`pyfold.outcome`), so any machine sharing ``DIR`` sees
the same: ``done`` (outcome ``completed``, status ``ok``), ``failed`` (a failure
recorded by fold_run, status ``failed: <cause>``: a physical failure, not retried),
``running`` (its destination lock is held), ``interrupted`` (a ``run.h5.partial``,
or a ``run.h5`` whose fold_run was killed without recording a cause: resumed from its
checkpoint), ``queued`` (nothing yet).
"""
from __future__ import annotations

import dataclasses
import fcntl
import json
import math
import os
import time
from pathlib import Path
from typing import Any

from pyfold.errors import InputError
from pyfold.outcome import read_outcome

MANIFEST = "sweep.json"
RUNS = "runs"
SCENE = "scene.toml"
RUN_FILE = "run.h5"
PARTIAL = RUN_FILE + ".partial"
LOCK = RUN_FILE + ".lock"
ATTEMPTS = "attempts.jsonl"
LOG = "log.txt"
DONOR = "donor.json"
#: An attempt under way (``attempt.<host>.<pid>.open.json``): its entry so far, rewritten by the
#: worker every ``heartbeat_s`` seconds and removed once its line is in ``attempts.jsonl``.
OPEN_ATTEMPT = "attempt.{host}.{pid}.open.json"
OPEN_GLOB = "attempt.*.open.json"
#: Seconds between two renewals of an open attempt (the worker's default; each entry states its own).
HEARTBEAT_S = 30.0
#: An open attempt not renewed for this many of its intervals ended without closing: a SIGKILL, a lost
#: node, the machine stopped. It is then counted as a ``killed`` attempt with its last renewal's costs.
STALE_BEATS = 4
#: Run states, in the order tables show them.
STATES = ("done", "running", "interrupted", "queued", "failed")


@dataclasses.dataclass(frozen=True)
class RunState:
    state: str  # one of STATES
    detail: str = ""  # the cause of a failure, or what was found
    outcome: str = ""  # the run file's outcome code (pyfold.outcome.OUTCOMES), "" without a run file


def run_folder(root: Path, run_id: str) -> Path:
    return root / RUNS / run_id


def lock_held(path: Path) -> bool:
    """Whether another process holds the destination lock file ``path`` (pyfold.destination)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)  # releases a lock taken here
    return False


def run_state(folder: Path) -> RunState:
    """The state of the run in ``folder`` (see the module docstring)."""
    if lock_held(folder / LOCK):
        return RunState("running")
    out, partial = folder / RUN_FILE, folder / PARTIAL
    if partial.exists():
        return RunState("interrupted", "run.h5.partial kept for --resume")
    if out.exists():
        outcome = read_outcome(out)
        if outcome is None:
            return RunState("interrupted", "run.h5 without a readable status")
        if outcome.completed:
            return RunState("done", outcome=outcome.code)
        if outcome.interrupted:
            return RunState("interrupted", outcome.status, outcome.code)
        return RunState("failed", outcome.status, outcome.code)
    return RunState("queued")


def manifest(spec, runs) -> dict[str, Any]:
    """The manifest of a planned sweep (what ``sweep.json`` holds)."""
    return {"name": spec.name, "sweep_file": str(spec.path), "axes": {k: list(v) for k, v in spec.axes.items()},
            "seeds": list(spec.seeds), "resources": dataclasses.asdict(spec.resources),
            "runs": [{"id": r.run_id, "point": r.point, "seed": r.seed} for r in runs]}


def read_manifest(root: Path) -> dict[str, Any]:
    """``DIR/sweep.json``; InputError naming DIR when it is not a sweep folder."""
    path = root / MANIFEST
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"DIR: {root} is not a sweep folder (no {MANIFEST}); make one with pyfold sweep run "
                         f"SWEEP.toml --out {root}") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"DIR: {path} is not readable as a sweep manifest: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("runs"), list):
        raise InputError(f"DIR: {path} is not a sweep manifest (no runs)")
    return data


def check_folder(root: Path, wanted: dict[str, Any]) -> None:
    """Refuse ``--out`` when it holds something other than this sweep: a file, a folder with other
    content, or the folder of a sweep of another name (InputError naming it). A sweep of the same
    name with other points, seeds or strain (a study narrowed or extended) takes the folder over:
    its manifest is replaced, the runs already there are reused where the scenes are the same."""
    if root.exists() and not root.is_dir():
        raise InputError(f"--out: {root} exists and is not a folder")
    if not root.exists():
        return
    if not (root / MANIFEST).exists():
        if any(root.iterdir()):
            raise InputError(f"--out: {root} is not empty and holds no sweep ({MANIFEST}); choose a new or empty "
                             "folder")
        return
    have = read_manifest(root)
    if have.get("name") != wanted["name"]:
        raise InputError(f"--out: {root} holds another sweep ({have.get('name')!r}, {len(have['runs'])} runs, from "
                         f"{have.get('sweep_file')}), not {wanted['name']!r}: choose another --out")


def prepare(root: Path, spec, runs) -> dict[str, Any]:
    """Create ``DIR`` (manifest, run folders, scenes), keeping every file already there.
    Returns the manifest."""
    data = manifest(spec, runs)
    check_folder(root, data)
    (root / RUNS).mkdir(parents=True, exist_ok=True)
    for r in runs:
        folder = run_folder(root, r.run_id)
        folder.mkdir(exist_ok=True)
        scene = folder / SCENE
        if not scene.exists():
            write_atomic(scene, r.toml)
    # resources may change between invocations (the command line): the latest is kept
    write_atomic(root / MANIFEST, json.dumps(data, indent=1))
    return data


def unique_runs(data: dict[str, Any]) -> list[str]:
    """Run identities of a manifest, each once, in order."""
    return list(dict.fromkeys(r["id"] for r in data["runs"]))


def record_attempt(folder: Path, entry: dict[str, Any]) -> None:
    """Append one attempt (a JSON line) to the run's ``attempts.jsonl``."""
    with open(folder / ATTEMPTS, "a", encoding="utf-8") as f:
        f.write(json.dumps(entry) + "\n")


def open_attempt(folder: Path, host: str, pid: int) -> Path:
    """The open-attempt file of the worker ``pid`` on ``host`` for the run in ``folder``."""
    return folder / OPEN_ATTEMPT.format(host=host, pid=pid)


def _key(entry: dict[str, Any]) -> tuple:
    return entry.get("host"), entry.get("pid"), entry.get("start")


def attempts(folder: Path, now: float | None = None) -> list[dict[str, Any]]:
    """The run's attempts in the order they started: the lines of ``attempts.jsonl`` (lines that
    cannot be read, e.g. cut by a kill, are skipped) and the *killed* ones, open attempts whose
    worker stopped renewing them more than :data:`STALE_BEATS` intervals before ``now``
    (``state`` "killed", ``end`` the last renewal, ``wall_s`` and ``cpu_s`` as of then: the
    CPU time of at most one interval per process is missing). An attempt under way is not
    listed, as before its end."""
    try:
        lines = (folder / ATTEMPTS).read_text(encoding="utf-8").splitlines()
    except OSError:
        lines = []
    out = []
    for line in lines:
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    closed = {_key(a) for a in out}
    now = time.time() if now is None else now
    for path in sorted(folder.glob(OPEN_GLOB)):
        try:
            entry = json.loads(path.read_text(encoding="utf-8"))
            beat = float(entry.get("beat", entry["start"]))
            stale = now - beat > STALE_BEATS * float(entry.get("heartbeat_s", HEARTBEAT_S))
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if stale and _key(entry) not in closed:  # not also closed (killed between its line and the removal)
            out.append(dict(entry, state="killed", end=beat, rc=None))
    return sorted(out, key=lambda a: float(a.get("start", 0.0)))


def cpu_seconds(folder: Path) -> float:
    """CPU time of the run in ``folder`` over all its attempts [s] (a resumed run pays for each; a
    killed one, :func:`attempts`, as of its last renewal); NaN without a recorded attempt, or when
    one lacks its CPU time (e.g. killed before its first renewal, or where the worker cannot read
    its children's CPU time)."""
    recorded = attempts(folder)
    return float(sum(a.get("cpu_s", math.nan) for a in recorded)) if recorded else math.nan


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file beside it: a reader sees the old or the new text."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{time.monotonic_ns()}")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
