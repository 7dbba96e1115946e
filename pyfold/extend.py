"""Extending a run to a later end: ``pyfold run SCENE -o OUT.h5 --resume`` with a larger ``t_end``.

A run file records its scene (``/setup``). When ``--resume`` is given a scene that
differs from the recorded one only by a larger ``numerics.t_end``, the run (complete,
killed or failed) continues from its last checkpoint to the new end, and the file then
holds what a run of the new scene made in one go holds, bit for bit:

* the steps are the same (each step depends only on the state before it and on
  ``t = (step - 1) dt``, not on ``t_end``);
* the record, snapshot and checkpoint intervals stay those of the recorded run. A scene
  that leaves ``output.interval`` / ``snapshot_interval`` / ``checkpoint_interval`` to
  their defaults (which scale with ``t_end``: docs/scenes.md#output) keeps the recorded
  ones; one that sets an interval must set the recorded value. A run made in one go
  equals the extension when its scene sets the same intervals;
* a complete run wrote a last record (and snapshot) at its end step whatever the
  intervals; a run made in one go writes them there only on the intervals. So a complete
  run whose end step is not on the record (snapshot) interval is refused: its last record
  would sum the contact counters over a partial interval;
* ``/setup`` is rewritten from the new scene (verbatim text, normalised scene, resolved
  values with the recorded intervals), each dataset sealed again
  (:func:`pyfold.integrity.seal`), and ``status`` set to ``running`` so a kill during the
  extension leaves a file that ``--resume`` continues.

Any other difference is refused (:class:`pyfold.errors.InputError`, exit 2) naming the
first differing key and both values, before anything is written; so is a ``t_end``
that is not larger than the recorded one for a complete run.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

import h5py
import numpy as np

from pyfold.errors import InputError, PyfoldError
from pyfold.fingerprint import setup_keys

if TYPE_CHECKING:
    from pyfold.scene import ResolvedScene

#: Keys that follow from ``t_end`` (normalised scene keys and ``resolved/<name>``).
T_END_KEYS = ("numerics.t_end", "resolved/t_end", "resolved/n_steps", "resolved/scene_warnings")
#: Scene key of each resolved interval (steps) that defaults to a fraction of ``t_end``.
INTERVALS = {"output_every": "interval", "snapshot_every": "snapshot_interval",
             "checkpoint_every": "checkpoint_interval"}
#: Keys (:func:`pyfold.fingerprint.setup_keys`) an extension may change: ``t_end`` and what
#: follows from it, and the intervals (kept as recorded; a scene that sets one is checked
#: against the recorded value apart, in :func:`plan`).
MAY_CHANGE = frozenset(T_END_KEYS) | frozenset(f"output.{key}" for key in INTERVALS.values()) | frozenset(
    f"resolved/{name}" for name in INTERVALS)


def _same(a, b) -> bool:
    try:
        x, y = np.asarray(a), np.asarray(b)
        if x.dtype.kind in "fiub" and y.dtype.kind in "fiub":
            return x.shape == y.shape and bool(np.all((x == y) | (np.isnan(x.astype(float)) & np.isnan(y.astype(float)))))
    except (TypeError, ValueError):
        pass
    return a == b


@dataclasses.dataclass(frozen=True)
class Extension:
    """How a recorded run continues under a new scene."""

    recorded_t_end: float
    t_end: float
    resolved: ResolvedScene  # the new scene, with the recorded intervals

    @property
    def extends(self) -> bool:
        """True when the run goes on past its recorded end."""
        return self.t_end > self.recorded_t_end


def plan(run_path: Path, resolved: ResolvedScene, scene_path: Path, partial: bool = False) -> Extension:
    """Compare the scene recorded in ``run_path`` with ``resolved`` (read from ``scene_path``);
    ``partial``: ``run_path`` is the file of an unfinished ``pyfold run`` (``OUT.h5.partial``).

    Returns the :class:`Extension` (``extends`` False: the same run, a plain resume).

    Raises
    ------
    InputError
        A difference other than ``t_end`` (naming the key and both values); an interval
        the new scene sets to another value than the recorded one; for a complete run,
        a ``t_end`` not beyond the recorded one, an end step off the record or snapshot
        interval, or no checkpoints.
    """
    from pyfold.run_input import read_setup

    setup = read_setup(run_path)
    recorded = setup.resolved
    old = setup_keys(setup.scene, recorded)
    new = setup_keys(json.loads(resolved.scene_json()),
                       {k: v for k, (v, _, _) in resolved.resolved_datasets().items()})
    old, new = kept_keys(old), kept_keys(new)
    for key in sorted(set(old) | set(new)):
        if key not in old or key not in new or not _same(old[key], new[key]):
            raise InputError(
                f"--resume: {scene_path} differs from the scene {run_path} was made from at key {key!r}: "
                f"{new.get(key, '<missing>')!r} in {scene_path}, {old.get(key, '<missing>')!r} recorded; a run "
                "continues only under its own scene, or one that differs by a larger numerics.t_end (extending it)")
    every = {}
    given = _output_keys(resolved.toml)
    for name, key in INTERVALS.items():
        kept = int(recorded[name])
        every[name] = kept
        if key in given and getattr(resolved, name) != kept:
            raise InputError(
                f"--resume: output.{key} of {scene_path} is {getattr(resolved, name)} steps, the run in {run_path} "
                f"was recorded every {kept} steps; a continued run keeps its intervals (leave output.{key} out to "
                "keep the recorded one)")
    recorded_t_end = float(recorded["t_end"])
    recorded_steps = int(recorded["n_steps"])
    if resolved.n_steps < recorded_steps:
        raise InputError(
            f"--resume: numerics.t_end = {resolved.t_end:g} of {scene_path} is before the end of the run recorded in "
            f"{run_path} (t_end = {recorded_t_end:g}, {recorded_steps} steps); a run can only be extended: give a "
            f"numerics.t_end > {recorded_t_end:g}")
    extension = Extension(recorded_t_end, float(resolved.t_end), dataclasses.replace(resolved, **every))
    if _status(run_path) == "ok" and (extension.extends or not partial):
        # (a partial file with status ok: fold_run finished, the rename did not happen; a
        # plain resume completes it)
        _check_complete(run_path, scene_path, extension, recorded_steps, every)
    return extension


def kept_keys(keys: Mapping[str, object]) -> dict[str, object]:
    """``keys`` (:func:`pyfold.fingerprint.setup_keys`, or the flattened normalised scene alone)
    without :data:`MAY_CHANGE`: what a run and its extension must share. A sweep looking for a
    run to extend (:mod:`pyfold.sweep.donors`) narrows its candidates with it, so that both ask
    the same question; :func:`plan` then decides."""
    return {key: value for key, value in keys.items() if key not in MAY_CHANGE}


def _output_keys(toml_text: str) -> set[str]:
    """The keys the scene file itself sets in ``[output]`` (the normalised scene has
    every default filled in, so only the verbatim text tells what the user chose)."""
    import tomllib

    try:
        table = tomllib.loads(toml_text).get("output", {})
    except tomllib.TOMLDecodeError:  # pragma: no cover - validated before
        return set(INTERVALS.values())
    return set(table) if isinstance(table, dict) else set()


def _status(path: Path) -> str:
    with h5py.File(path, "r") as f:
        status = f.attrs.get("status", b"")
    return (status.decode(errors="replace") if isinstance(status, bytes) else str(status)).strip()


def _check_complete(run_path: Path, scene_path: Path, extension: Extension, steps: int, every: dict) -> None:
    """A complete run extends only past its end, from its final checkpoint, with its last
    record and snapshot on their intervals (see the module docstring)."""
    if not extension.extends:
        raise InputError(
            f"--resume: nothing to resume: {run_path} is complete (status ok) to t_end = {extension.recorded_t_end:g}, "
            f"and {scene_path} asks for the same end; to extend the run give a numerics.t_end > "
            f"{extension.recorded_t_end:g}")
    if every["checkpoint_every"] == 0:
        raise InputError(
            f"--resume: {run_path} was made without checkpoints (output.checkpoint_interval = 0): there is no "
            "state to continue from; run the longer scene from the start (with --force)")
    for name, key in (("output_every", "interval"), ("snapshot_every", "snapshot_interval")):
        k = every[name]
        if k > 0 and steps % k != 0:
            raise InputError(
                f"--resume: {run_path} ends at step {steps}, not a multiple of its output.{key} ({k} steps): its "
                f"last {'record' if name == 'output_every' else 'snapshot'} is off the interval, which a run made "
                "in one go would not have; it cannot be extended to equal one. Run the longer scene from the start "
                "(with --force), or choose t_end and the intervals so that the end falls on them")


def rewrite_setup(path: Path, resolved: ResolvedScene) -> None:
    """Replace ``/setup`` of ``path`` by that of ``resolved`` (sealed) and set ``status = running``."""
    from pyfold.run_input import fixed_string, write_setup

    try:
        with h5py.File(path, "a") as f:
            f.attrs["status"] = fixed_string("running")  # first: a file cut short here is no finished run
            del f["setup"]
            write_setup(f, resolved)
    except OSError as exc:
        raise PyfoldError(f"cannot write the new /setup into {path} ({exc}); the run so far is kept there") from None
