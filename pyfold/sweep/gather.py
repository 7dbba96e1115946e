"""``DIR/sweep.nc``: one xarray Dataset over a sweep's axes and seed.

Per run (dimensions: the sweep's axes, then ``seed``): ``status`` (``done``,
``failed``, ``interrupted``, ``running``, ``queued``, or ``absent`` for an axis
combination that is not part of the sweep), ``outcome`` (the run file's outcome code,
:mod:`pyfold.outcome`), ``run_id``, ``a2_mean`` and ``a4_mean``
(over the second half of the records), ``a2_final``, and the costs ``wall_seconds``
(summed over attempts), ``attempts`` and ``ranks``. Per point (the axes): the report's
C_I per closure (``ci``, ``ci_error``: :func:`pyfold.report.build_report` over the
point's complete seeds), ``seeds_done`` and ``point_status`` (``complete``,
``incomplete``, ``empty``, ``absent``): an incomplete point keeps what its complete
seeds give, marked, never dropped. Each complete-enough point's report (``pyfold
report`` on its seeds) is written to ``DIR/reports/<point>/``.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from pyfold.errors import InputError
from pyfold.outcome import OUTCOMES, UNKNOWN_FAILURE
from pyfold.sweep import store

#: Variables that record costs (they differ between machines and executors).
COST_VARIABLES = ("wall_seconds", "attempts", "ranks")
NC_NAME = "sweep.nc"
REPORTS = "reports"


def point_label(point: dict[str, Any]) -> str:
    """A folder name for a point: ``key-value_key-value`` with unsafe characters as ``_``."""
    text = "_".join(f"{k}-{v}" for k, v in point.items()) or "all"
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", text)[:200]


def _run_summary(path: Path) -> dict[str, np.ndarray]:
    from pyfold.run_results import open_run

    with open_run(path) as ds:
        a2 = np.asarray(ds["a2"].values, float)
        a4 = np.asarray(ds["a4"].values, float)
    half = a2.shape[0] // 2
    return {"a2_mean": a2[half:].mean(axis=0), "a4_mean": a4[half:].mean(axis=0), "a2_final": a2[-1]}


def gather(root: Path, closures: Sequence[str] | None = None, reports: bool = True,
           progress: Callable[[str], None] | None = None) -> Path:
    """Build and write ``root/sweep.nc`` (see the module docstring); returns its path."""
    import xarray as xr

    say = progress or (lambda text: None)
    data = store.read_manifest(root)
    axes: dict[str, list] = data["axes"]
    seeds: list[int] = data["seeds"]
    names = list(axes)
    shape = [len(axes[n]) for n in names]
    runs = {(tuple(r["point"].get(n) for n in names), r["seed"]): r["id"] for r in data["runs"]}
    points = list(dict.fromkeys(tuple(r["point"].get(n) for n in names) for r in data["runs"]))
    point_dicts = {p: dict(zip(names, p)) for p in points}

    status = np.full(shape + [len(seeds)], "absent", dtype=object)
    run_ids = np.full(shape + [len(seeds)], "", dtype=object)
    outcomes = np.full(shape + [len(seeds)], "", dtype=object)
    wall = np.full(shape + [len(seeds)], math.nan)
    tries = np.zeros(shape + [len(seeds)], dtype=np.int32)
    ranks = np.zeros(shape + [len(seeds)], dtype=np.int32)
    summaries: dict[tuple, dict] = {}
    dim = None
    for (p, seed), rid in runs.items():
        idx = tuple(axes[n].index(v) for n, v in zip(names, p)) + (seeds.index(seed),)
        folder = store.run_folder(root, rid)
        state = store.run_state(folder)
        status[idx], run_ids[idx], outcomes[idx] = state.state, rid, state.outcome
        done = store.attempts(folder)
        tries[idx] = len(done)
        ranks[idx] = max((int(a.get("np", 0)) for a in done), default=0)
        if done:
            wall[idx] = sum(float(a.get("wall_s", 0.0)) for a in done)
        if state.state == "done":
            summaries[idx] = _run_summary(folder / store.RUN_FILE)
            dim = summaries[idx]["a2_mean"].shape[0]
    dim = dim or 3
    labels = ["x", "y", "z"][:dim]
    a2_mean = np.full(shape + [len(seeds), dim, dim], math.nan)
    a2_final = np.full(shape + [len(seeds), dim, dim], math.nan)
    a4_mean = np.full(shape + [len(seeds)] + [dim] * 4, math.nan)
    for idx, s in summaries.items():
        a2_mean[idx], a2_final[idx], a4_mean[idx] = s["a2_mean"], s["a2_final"], s["a4_mean"]

    point_status = np.full(shape, "absent", dtype=object)
    seeds_done = np.zeros(shape, dtype=np.int32)
    ci_names: list[str] = []
    ci_by_point: dict[tuple, dict[str, tuple[float, float]]] = {}
    for p in points:
        pidx = tuple(axes[n].index(v) for n, v in zip(names, p))
        paths = [store.run_folder(root, runs[p, s]) / store.RUN_FILE for s in seeds
                 if (p, s) in runs and status[pidx + (seeds.index(s),)] == "done"]
        n_runs = sum(1 for s in seeds if (p, s) in runs)
        seeds_done[pidx] = len(paths)
        point_status[pidx] = "complete" if len(paths) == n_runs else ("incomplete" if paths else "empty")
        if not paths or closures is not None and not closures:
            continue
        say(f"report of {point_label(point_dicts[p])} ({len(paths)} seed(s))")
        ci_by_point[p] = _point_report(root, point_dicts[p], paths, closures, reports)
        ci_names += [c for c in ci_by_point[p] if c not in ci_names]
    ci = np.full(shape + [len(ci_names)], math.nan)
    ci_err = np.full(shape + [len(ci_names)], math.nan)
    for p, values in ci_by_point.items():
        pidx = tuple(axes[n].index(v) for n, v in zip(names, p))
        for k, c in enumerate(ci_names):
            if c in values:
                ci[pidx + (k,)], ci_err[pidx + (k,)] = values[c]

    run_dims = names + ["seed"]
    coords = {n: (n, _coordinate(axes[n])) for n in names}
    coords |= {"seed": ("seed", np.asarray(seeds, np.int64)), "i": ("i", labels), "j": ("j", labels),
               "k": ("k", labels), "l": ("l", labels), "closure": ("closure", np.asarray(ci_names, dtype=str))}
    ds = xr.Dataset(
        {
            "status": (run_dims, status.astype(str), {"long_name": "run state: " + ", ".join(store.STATES)
                                                       + ", or absent (not part of the sweep)"}),
            "outcome": (run_dims, outcomes.astype(str), {"long_name": "how the run file says the run ended: "
                                                          + ", ".join(OUTCOMES) + " (pyfold.outcome), or "
                                                          + UNKNOWN_FAILURE + " (an older file: see status), "
                                                          "or empty (no run file)"}),
            "run_id": (run_dims, run_ids.astype(str), {"long_name": "content hash of the normalised scene "
                                                                     "(folder runs/<run_id>)"}),
            "a2_mean": (run_dims + ["i", "j"], a2_mean, {"long_name": "a2 averaged over the second half of the "
                                                                      "records", "units": "1"}),
            "a2_final": (run_dims + ["i", "j"], a2_final, {"long_name": "a2 at the last record", "units": "1"}),
            "a4_mean": (run_dims + ["i", "j", "k", "l"], a4_mean,
                        {"long_name": "a4 averaged over the second half of the records", "units": "1"}),
            "wall_seconds": (run_dims, wall, {"long_name": "wall time summed over the run's attempts",
                                              "units": "s"}),
            "attempts": (run_dims, tries, {"long_name": "attempts (runs, resumptions) of the run"}),
            "ranks": (run_dims, ranks, {"long_name": "MPI ranks of the run's attempts"}),
            "point_status": (names, point_status.astype(str),
                             {"long_name": "complete (every seed done), incomplete (some), empty (none), "
                                           "absent (not part of the sweep)"}),
            "seeds_done": (names, seeds_done, {"long_name": "seeds whose run is complete"}),
            "ci": (names + ["closure"], ci, {"long_name": "Folgar-Tucker C_I per closure over the point's "
                                                          "complete seeds (pyfold report)", "units": "1"}),
            "ci_error": (names + ["closure"], ci_err, {"long_name": "standard error of ci (pyfold report)",
                                                       "units": "1"}),
        },
        coords=coords,
        attrs={"sweep": data.get("name", ""), "sweep_file": data.get("sweep_file", ""),
               "axes": ", ".join(names), "cost_variables": ", ".join(COST_VARIABLES)},
    )
    from pyfold.files import atomic_output

    target = root / NC_NAME
    with atomic_output(target) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return target


def _coordinate(values: list) -> np.ndarray:
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return np.asarray(values, dtype=float if any(isinstance(v, float) for v in values) else np.int64)
    return np.asarray([str(v) for v in values], dtype=str)


def _point_report(root: Path, point: dict[str, Any], paths: list[Path], closures: Sequence[str] | None,
                  write: bool) -> dict[str, tuple[float, float]]:
    """C_I per closure (mean, error) of one point's runs; its report written under ``reports/``.

    The runs are paid for, so a point shorter than the estimators need (or without
    orientation) is reported anyway, as ``pyfold main`` does: the report's warnings
    (:func:`pyfold.provenance.applicability_problems`) stand in every output it writes."""
    from pyfold import report
    from pyfold.run_checks import DEFAULT_CLOSURES

    chosen = ",".join(closures) if closures is not None else ",".join(DEFAULT_CLOSURES)
    if write:
        out = root / REPORTS / point_label(point)
        rep, _ = report.report(paths, out, chosen, force=True)
    else:
        rep = report.build_report(paths, chosen, force=True)
    return {c: (float(m.mean), float(m.error)) for c, m in rep.ci.items()}


def check_closures(text: str) -> tuple[str, ...]:
    """``--closures`` as names ("" for none: no C_I, no reports)."""
    names = tuple(c.strip() for c in text.split(",") if c.strip())
    if not names:
        return ()
    from pyfold.run_checks import check_closures as check

    try:
        return tuple(check(names))
    except InputError as exc:
        raise InputError(f"--closures: {exc}") from None

