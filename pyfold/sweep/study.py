"""Studies on sweeps: a study script's simulations as a sweep, run by either executor.

A study keeps its sweep files beside it (``studies/sweeps/<study>.toml`` and
``<study>_large.toml``: a builder from the study script, points, seeds, strain); it
reads the one of its form (:func:`load_form`), may narrow it (``--seeds``,
``--t-end``), runs it (:func:`run_sweep`: ``--executor local|slurm``, ``--np``) and
analyses the run files it gets back, keyed by point and seed. The sweep folder is
the study's ``--out``/``sweep``; ``pyfold sweep status|gather`` work on it as on any sweep.
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any, Sequence

from pyfold.errors import PyfoldError
from pyfold.sweep import store
from pyfold.sweep.spec import SweepSpec, read_sweep

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--executor`` and ``--sweep-dir`` of a study script."""
    from pyfold.sweep.executors import EXECUTORS

    parser.add_argument("--executor", choices=EXECUTORS, default=EXECUTORS[0],
                        help="where the simulations run: this machine, or Slurm job arrays (pyfold sweep)")
    parser.add_argument("--sweep-dir", type=Path, default=None,
                        help="sweep folder of the simulations (default: OUT/sweep)")


def add_form_arguments(parser: argparse.ArgumentParser, large_help: str) -> None:
    """``--large`` (help ``large_help``), ``--seeds`` and ``--t-end`` of a study script: the
    choice of the study's form and the overrides of its seeds and strain."""
    parser.add_argument("--large", action="store_true", help=large_help)
    parser.add_argument("--seeds", type=int, nargs="+", help="override the form's seeds")
    parser.add_argument("--t-end", type=float, help="override the form's strain")


def load_form(folder: Path, study: str, large: bool, seeds: tuple[int, ...] | None = None,
              arguments: dict[str, Any] | None = None) -> SweepSpec:
    """The sweep file ``folder/<study>[_large].toml`` of a study's form, with ``seeds`` and builder
    ``arguments`` replaced when given."""
    spec = read_sweep(Path(folder) / f"{study}{'_large' if large else ''}.toml")
    changes: dict[str, Any] = {}
    if seeds:
        changes["seeds"] = tuple(seeds)
    if arguments:
        changes["arguments"] = {**spec.arguments, **arguments}
    return dataclasses.replace(spec, **changes) if changes else spec


def run_sweep(spec: SweepSpec, root: Path, executor: str = "local", ranks: int | None = None,
              analyse_only: bool = False, extend_from: Sequence[Path] = ()) -> dict[tuple[tuple, int], Path]:
    """Run ``spec`` into ``root`` (nothing when ``analyse_only``) and return ``{(point values, seed):
    run file}`` of its complete runs (point values in the order of ``spec.axes``). Runs that could not
    be completed are named on stderr and left out; a refused scene stops before anything runs.
    ``extend_from``: other sweep folders whose finished runs of the same scenes to an earlier end
    the new runs continue (``pyfold sweep run --extend-from``, :mod:`pyfold.sweep.donors`)."""
    import sys

    from pyfold.sweep.donors import check_sweep_folders, plan_donors
    from pyfold.sweep.executors import make_executor
    from pyfold.sweep.plan import plan
    from pyfold.sweep.progress import Progress

    if ranks is not None:
        spec = dataclasses.replace(spec, resources=dataclasses.replace(spec.resources, np=ranks))
    runs = plan(spec)
    if not analyse_only:
        donor_folders = check_sweep_folders(extend_from, option="extend_from")
        data = store.prepare(root, spec, runs)
        ids = [rid for rid in store.unique_runs(data)
               if store.run_state(store.run_folder(root, rid)).state != "done"]
        if ids:
            plan_donors(root, ids, donor_folders, report=lambda line: print(f"sweep {spec.name}: {line}", flush=True))
            progress = Progress(len(ids), f"sweep {spec.name}")
            try:
                kwargs = {"name": spec.name} if executor == "slurm" else {}
                outcome = make_executor(executor).execute(root, ids, spec.resources, progress, **kwargs)
            finally:
                progress.close()
            for rid, why in outcome.failures.items():
                print(f"sweep {spec.name}: run {rid} left out: {why}", file=sys.stderr)
    names = list(spec.axes)
    out: dict[tuple[tuple, int], Path] = {}
    for r in runs:
        folder = store.run_folder(root, r.run_id)
        if store.run_state(folder).state == "done":
            out[tuple(r.point[n] for n in names), r.seed] = folder / store.RUN_FILE
    if not out and not analyse_only:
        raise PyfoldError(f"sweep {spec.name}: no run completed in {root}")
    return out


def wall_seconds(run_file: Path) -> float:
    """Wall time of a sweep run: its attempts' sum (``attempts.jsonl`` beside it)."""
    return sum(float(a.get("wall_s", 0.0)) for a in store.attempts(run_file.parent))
