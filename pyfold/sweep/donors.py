"""Donors: a finished run that a sweep's new run continues instead of starting again at t = 0.

A sweep whose strain was raised (its ``numerics.t_end``, or a builder's ``t_end``), or
one that asks for the scenes of a shorter sweep to a later end, would compute again
what a finished run already holds. So before the executor starts, every queued run (no
run file, no partial) looks for a *donor*: a finished run (state ``done``) of the same
scene but for a smaller ``t_end``, among the runs of the sweep folder itself (the runs
of an earlier, shorter form stay in ``runs/``) and of the sweep folders given with
``--extend-from``. Whether a finished run is "the same run, to an earlier end" is
:func:`pyfold.extend.plan`'s question, the one ``pyfold run --resume`` asks: the
candidates are narrowed by their normalised scene without the keys an extension may
change (:func:`pyfold.extend.kept_keys`), then asked of :func:`pyfold.extend.plan`,
the largest ``t_end`` first; the first it accepts is the donor, recorded in
``runs/<id>/donor.json``.

The worker (:mod:`pyfold.sweep.worker`) copies the donor's run file (only read: the
donor's sweep stays as it is) to the run's ``run.h5.partial`` and continues it with
``pyfold run --resume``, which extends it to the run a single ``pyfold run`` of the
scene makes (bit for bit without the Stokes solver, to its tolerance with it, as any
resume); killed during the extension it is an interrupted run like any other. The attempt that copied it names the donor in ``attempts.jsonl``
(:func:`extended_from`); the costs there are the extension's, the donor's stay with it.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Callable, Mapping, Sequence

from pyfold.errors import InputError, PyfoldError
from pyfold.sweep import store

#: The option that names other sweep folders to take donors from.
OPTION = "--extend-from"
#: ``from`` of the attempt that started a run as a copy of its donor (attempts.jsonl).
EXTENDED = "extended"
#: Errors that make a finished run no donor (unreadable, damaged, another format): it is passed over.
NOT_A_DONOR = (PyfoldError, OSError, KeyError, ValueError, TypeError)


@dataclasses.dataclass(frozen=True)
class Donor:
    """A finished run another run of the same scene continues to a later end."""

    run_id: str
    run_file: Path  # absolute
    t_end: float  # its recorded end

    def note(self) -> str:
        """What the sweep's output says of a run that continues this one."""
        return f"extended from {self.run_id} at t = {self.t_end:g}"

    def record(self) -> dict:
        """The donor as a JSON object (``donor.json``, ``attempts.jsonl``)."""
        return {"id": self.run_id, "run_file": str(self.run_file), "t_end": self.t_end}


def from_record(data: object) -> Donor | None:
    """The donor of a JSON object written by :meth:`Donor.record`; None when it is not one."""
    try:
        return Donor(str(data["id"]), Path(data["run_file"]), float(data["t_end"]))
    except (TypeError, KeyError, ValueError):
        return None


def check_sweep_folders(folders: Sequence[str | Path], option: str = OPTION) -> list[Path]:
    """The sweep folders ``folders`` (absolute, each once), checked before anything is written:
    InputError naming ``option`` for one that is not a sweep folder (no readable manifest or
    no ``runs/``), since a mistyped folder would otherwise silently give no donor."""
    out: list[Path] = []
    for given in folders:
        path = Path(given)
        if str(given) == "":
            raise InputError(f"{option}: empty path; name the folder of an earlier pyfold sweep run (its --out)")
        if not path.is_dir():
            raise InputError(f"{option}: {path} is not a folder; name the folder of an earlier pyfold sweep run "
                             "(its --out)")
        missing = [name for name in (store.MANIFEST, store.RUNS) if not (path / name).exists()]
        if missing:
            raise InputError(f"{option}: {path} is not a sweep folder (no {' and no '.join(missing)}); name the "
                             "folder of an earlier pyfold sweep run (its --out)")
        try:
            store.read_manifest(path)
        except InputError as exc:
            raise InputError(f"{option}: {str(exc).removeprefix('DIR: ')}") from None
        if path.resolve() not in out:
            out.append(path.resolve())
    return out


def scene_key(scene: Mapping) -> str:
    """A hash of the normalised ``scene`` without the keys an extension may change: runs that
    differ here cannot continue one another, so only those that share it are asked of
    :func:`pyfold.extend.plan` (which also compares the resolved values)."""
    from pyfold.extend import kept_keys
    from pyfold.fingerprint import flatten

    text = json.dumps(kept_keys(flatten(dict(scene))), sort_keys=True, separators=(",", ":"), allow_nan=True,
                      default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def finished_runs(roots: Sequence[Path]) -> dict[str, list[Donor]]:
    """The finished runs of the sweep folders ``roots`` by :func:`scene_key` of their recorded
    scenes (a run file found twice, through two names of one folder, counts once)."""
    from pyfold.run_input import read_setup

    index: dict[str, list[Donor]] = {}
    seen: set[Path] = set()
    for root in roots:
        runs = root / store.RUNS
        if not runs.is_dir():
            continue
        for folder in sorted(runs.iterdir()):
            run_file = (folder / store.RUN_FILE).resolve()
            if run_file in seen or not run_file.is_file() or store.run_state(folder).state != "done":
                continue
            seen.add(run_file)
            try:
                setup = read_setup(run_file)
                donor = Donor(folder.name, run_file, float(setup.resolved["t_end"]))
                key = scene_key(setup.scene)
            except NOT_A_DONOR:
                continue
            index.setdefault(key, []).append(donor)
    return index


def find_donor(folder: Path, index: Mapping[str, list[Donor]]) -> Donor | None:
    """The donor of the run in ``folder`` among ``index`` (:func:`finished_runs`): of the runs
    :func:`pyfold.extend.plan` lets its scene (``folder/scene.toml``, as ``pyfold run``
    reads it) extend, the one with the largest ``t_end``; None when there is none.

    A donor must also have the output, snapshot and checkpoint intervals the scene resolves to
    by itself: an extension keeps the donor's, and defaults that scale with ``t_end`` would
    otherwise give one run id two different files (finer records when extended than when run
    in one go), which ``pyfold sweep gather`` refuses to put in one ensemble."""
    from pyfold.extend import INTERVALS, plan
    from pyfold.run_input import read_setup
    from pyfold.scene import load_scene

    scene = folder / store.SCENE
    try:
        resolved = load_scene(scene)
    except NOT_A_DONOR:  # the run itself will say what is wrong with its scene
        return None
    candidates = [d for d in index.get(scene_key(json.loads(resolved.scene_json())), [])
                  if d.t_end < resolved.t_end]
    own = {name: int(resolved.resolved_datasets()[name][0]) for name in INTERVALS}
    for donor in sorted(candidates, key=lambda d: -d.t_end):  # stable: the sweep folder first on a tie
        try:
            recorded = read_setup(donor.run_file).resolved
            if any(int(recorded[name]) != own[name] for name in INTERVALS):
                continue
            if plan(donor.run_file, resolved, scene).extends:
                return donor
        except NOT_A_DONOR:
            continue
    return None


def planned(folder: Path) -> Donor | None:
    """The donor recorded for the run in ``folder`` (``donor.json``); None without a readable one."""
    try:
        return from_record(json.loads((folder / store.DONOR).read_text(encoding="utf-8")))
    except (OSError, ValueError):
        return None


def plan_donors(root: Path, run_ids: Sequence[str], extend_from: Sequence[Path] = (),
                report: Callable[[str], None] | None = None) -> dict[str, Donor]:
    """Record the donor of every queued run of ``run_ids`` in the sweep folder ``root``
    (``donor.json``; one that no longer has a donor loses its record and starts at t = 0).
    Donors come from ``root`` and the sweep folders ``extend_from``
    (:func:`check_sweep_folders`), and from the folder of a donor recorded earlier, so
    that a later invocation without ``--extend-from`` keeps it. ``report`` gets one line
    per donor found. Returns run id -> donor."""
    queued = [rid for rid in run_ids if store.run_state(store.run_folder(root, rid)).state == "queued"]
    if not queued:
        return {}
    roots = [root.resolve(), *extend_from]
    for rid in queued:
        earlier = planned(store.run_folder(root, rid))
        if earlier is not None:
            roots.append(earlier.run_file.parent.parent.parent)
    index = finished_runs(list(dict.fromkeys(roots)))
    found: dict[str, Donor] = {}
    for rid in queued:
        folder = store.run_folder(root, rid)
        donor = find_donor(folder, index) if index else None
        if donor is None:
            (folder / store.DONOR).unlink(missing_ok=True)
            continue
        store.write_atomic(folder / store.DONOR, json.dumps(donor.record()))
        found[rid] = donor
        if report:
            report(f"{rid}: {donor.note()} ({donor.run_file.parent})")
    return found


def start_from_donor(folder: Path) -> Donor | None:
    """Make the queued run in ``folder`` a copy of its recorded donor (:func:`planned`): the
    donor's run file copied (read only) to ``run.h5.partial``, which ``pyfold run --resume``
    then extends. Under the run's destination lock, and never over a run file or partial
    that is there: a run that has one is resumed, not replaced. None (the run starts at
    t = 0) without a record, or when the donor is no longer a finished run."""
    from pyfold.destination import acquire

    donor = planned(folder)
    if donor is None:
        return None
    if store.run_state(donor.run_file.parent).state != "done":
        print(f"pyfold sweep: {folder.name}: its donor {donor.run_file} is no longer a finished run; starting at "
              "t = 0", file=sys.stderr, flush=True)
        return None
    out, partial = folder / store.RUN_FILE, folder / store.PARTIAL
    copy = folder / (store.PARTIAL + ".copy")
    with acquire(out, "the sweep run's file", command=f"pyfold sweep: copying {donor.run_file}"):
        if os.path.lexists(out) or os.path.lexists(partial):
            return None
        copy.unlink(missing_ok=True)  # a copy cut short by a signal before its clean-up ran
        try:
            shutil.copyfile(donor.run_file, copy)
            os.replace(copy, partial)  # whole or not at all: a copy cut short is no interrupted run
        except OSError as exc:  # e.g. a full disk: the run is made from t = 0 instead (and says why it fails)
            print(f"pyfold sweep: {folder.name}: cannot copy {donor.run_file} ({exc.strerror or exc}); starting "
                  "at t = 0", file=sys.stderr, flush=True)
            return None
        finally:
            copy.unlink(missing_ok=True)
    return donor


def extended_from(folder: Path) -> Donor | None:
    """The donor the run in ``folder`` was started from (its attempts: the latest start, from
    a donor or from t = 0, counts); None for a run started at t = 0 or not yet started."""
    donor = None
    for attempt in store.attempts(folder):
        origin = str(attempt.get("from", ""))
        if origin == EXTENDED:
            donor = from_record(attempt.get("donor"))
        elif origin == "queued" or origin.startswith("start"):
            donor = None
    return donor


def describe(folder: Path, state: str) -> str:
    """`` (extended from <id> at t = …)`` for a run continued from a donor, `` (to be …)`` for a
    queued run with one; "" otherwise (the lines of ``pyfold sweep status``)."""
    if state == "queued":
        donor = planned(folder)
        return f" (to be {donor.note()})" if donor else ""
    donor = extended_from(folder)
    return f" ({donor.note()})" if donor else ""
