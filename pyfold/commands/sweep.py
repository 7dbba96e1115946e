"""``pyfold sweep run|status|gather``: many runs described by one sweep file.

``pyfold sweep run SWEEP.toml --out DIR [--executor local|slurm]`` checks the sweep
file and every scene it makes (exit 2 naming the key, nothing written), prepares
``DIR`` (:mod:`pyfold.sweep.store`) and runs what is not complete: nothing when every
run is done; interrupted runs resume from their checkpoints; runs that failed for a
physical reason are reported with their cause (exit 1), not retried. A run not yet
started whose scene a finished run holds to an earlier ``numerics.t_end`` (in ``DIR``, or
in the sweep folders of ``--extend-from``) continues a copy of that run instead of
starting at t = 0 (:mod:`pyfold.sweep.donors`).
``pyfold sweep status DIR`` lists the runs and their states (with Slurm's, for the
Slurm executor). ``pyfold sweep gather DIR`` writes ``DIR/sweep.nc`` and a report per
point (:mod:`pyfold.sweep.gather`). docs/cluster.md describes the sweep file.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from pyfold.errors import InputError, PyfoldError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pyfold.sweep.executors import EXECUTORS

    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    run = sub.add_parser("run", help="run a sweep's missing runs into DIR")
    run.add_argument("sweep", metavar="SWEEP.toml", help="sweep file (docs/cluster.md)")
    run.add_argument("--out", required=True, metavar="DIR", help="sweep folder (created; reused when it holds "
                                                                  "this sweep)")
    run.add_argument("--executor", default=EXECUTORS[0], help=f"one of {', '.join(EXECUTORS)} (default "
                                                               f"{EXECUTORS[0]})")
    run.add_argument("--np", type=int, default=None, help="MPI ranks per run (default: the sweep file's resources.np)")
    run.add_argument("--parallel", type=int, default=None,
                     help="local: runs at once (default: usable cores // ranks per run)")
    run.add_argument("--partition", default=None, help="slurm: partition (default: resources.partition)")
    run.add_argument("--time", default=None, help="slurm: time limit per run (default: resources.time)")
    run.add_argument("--mem", default=None, help="slurm: memory per run (default: resources.mem)")
    run.add_argument("--retries", type=int, default=None,
                     help="slurm: resubmissions of timed-out or cancelled runs (default: resources.retries)")
    run.add_argument("--no-wait", action="store_true", help="slurm: submit and return (follow with "
                                                            "pyfold sweep status DIR)")
    run.add_argument("--extend-from", action="append", default=[], metavar="DIR",
                     help="other sweep folders (the --out of earlier sweeps) whose finished runs may be continued: "
                          "a new run whose scene one of them (or a run in --out) holds to an earlier "
                          "numerics.t_end starts as a copy of it (the largest t_end; the original is left as it "
                          "is) and is extended like pyfold run --resume extends a run; repeat the option for "
                          "several folders")
    status = sub.add_parser("status", help="the state of each run of a sweep folder")
    status.add_argument("dir", metavar="DIR")
    gather = sub.add_parser("gather", help="DIR/sweep.nc over the sweep's axes and seed, and a report per point")
    gather.add_argument("dir", metavar="DIR")
    gather.add_argument("--closures", default=None,
                        help="comma-separated closures of the reports' C_I (default: pyfold report's; \"\": no C_I)")
    gather.add_argument("--no-reports", action="store_true", help="C_I only, no report folders")


def run(args: argparse.Namespace) -> int:
    return {"run": _run, "status": _status, "gather": _gather}[args.action](args)


def _resources(args: argparse.Namespace, spec):
    from pyfold.sweep.spec import check_resources

    given = {k: getattr(args, k) for k in ("np", "partition", "time", "mem", "retries")
             if getattr(args, k) is not None}
    problems: list[str] = []
    resources = check_resources({**dataclasses.asdict(spec.resources), **given}, "", problems)
    if problems:
        raise InputError("; ".join("--" + p for p in problems))
    return resources


def _run(args: argparse.Namespace) -> int:
    from pyfold.sweep import store
    from pyfold.sweep.donors import check_sweep_folders, plan_donors
    from pyfold.sweep.executors import EXECUTORS, make_executor
    from pyfold.sweep.plan import plan
    from pyfold.sweep.progress import Progress
    from pyfold.sweep.spec import read_sweep

    if args.executor not in EXECUTORS:
        raise InputError(f"--executor: {args.executor!r}; allowed: {', '.join(EXECUTORS)}")
    if args.parallel is not None and args.parallel < 1:
        raise InputError(f"--parallel: must be an integer >= 1, got {args.parallel}")
    if args.out == "":
        raise InputError("--out: empty path; name the sweep folder")
    spec = read_sweep(args.sweep)
    resources = _resources(args, spec)
    extend_from = check_sweep_folders(args.extend_from)
    from pyfold.commands.run import check_ranks

    if args.executor == "local":
        check_ranks(resources.np, oversubscribe=False, option="--np (resources.np)")
    runs = plan(spec)
    root = Path(args.out)
    spec = dataclasses.replace(spec, resources=resources)
    data = store.prepare(root, spec, runs)
    ids = store.unique_runs(data)
    before = {rid: store.run_state(store.run_folder(root, rid)).state for rid in ids}
    done = sum(1 for s in before.values() if s == "done")
    print(f"pyfold sweep: {spec.name}: {len(data['runs'])} runs ({len(ids)} distinct) in {root}; {done} already "
          "complete", flush=True)
    todo = [rid for rid in ids if before[rid] != "done"]
    if not todo:
        print("pyfold sweep: nothing to run")
        return 0
    plan_donors(root, todo, extend_from, report=lambda line: print(f"pyfold sweep: {line}", flush=True))
    executor = make_executor(args.executor, parallel=args.parallel, wait=not args.no_wait)
    progress = Progress(len(ids), f"sweep {spec.name}")
    try:
        if args.executor == "slurm":
            outcome = executor.execute(root, todo, resources, progress, name=spec.name)
        else:
            outcome = executor.execute(root, todo, resources, progress)
    finally:
        progress.close()
    if outcome.submitted:
        print(f"pyfold sweep: submitted; follow with: pyfold sweep status {root}")
        return 0
    states = {rid: store.run_state(store.run_folder(root, rid)).state for rid in ids}
    from pyfold.sweep.progress import counts_line

    print(f"pyfold sweep: {counts_line(states)}")
    if outcome.failures:
        lines = [f"  {rid}: {why}" for rid, why in outcome.failures.items()]
        raise PyfoldError(f"{len(outcome.failures)} run(s) not complete:\n" + "\n".join(lines))
    return 0


def _status(args: argparse.Namespace) -> int:
    from pyfold.sweep import store
    from pyfold.sweep.donors import describe
    from pyfold.sweep.progress import counts_line

    root = Path(args.dir)
    data = store.read_manifest(root)
    slurm_state = _slurm_states(root)
    states = {}
    print(f"sweep {data.get('name')}: {len(data['runs'])} runs in {root}")
    for r in data["runs"]:
        folder = store.run_folder(root, r["id"])
        state = store.run_state(folder)
        states[r["id"]] = state.state
        point = ", ".join(f"{k} = {v}" for k, v in r["point"].items())
        extra = f" [slurm {slurm_state[r['id']]}]" if r["id"] in slurm_state else ""
        detail = f": {state.detail}" if state.state in ("failed", "interrupted") and state.detail else ""
        origin = describe(folder, state.state)
        print(f"  {r['id']}  {point + ', ' if point else ''}seed {r['seed']}: {state.state}{origin}{extra}{detail}")
    print(counts_line(states))
    return 1 if any(s == "failed" for s in states.values()) else 0


def _slurm_states(root: Path) -> dict[str, str]:
    """run id -> ``JOB_TASK STATE`` of its latest Slurm task (squeue, else sacct); {} without Slurm."""
    from pyfold.sweep import slurm

    jobs = slurm.read_jobs(root)
    if not jobs:
        return {}
    tasks = slurm.task_of(jobs)
    ids = sorted({j for j, _ in tasks.values()})
    try:
        live = slurm.queue(ids)
    except PyfoldError as exc:
        print(f"pyfold sweep: warning: {exc}", file=sys.stderr)
        live = {}
    final = slurm.accounting(ids)
    out = {}
    for rid, (job, index) in tasks.items():
        state = live.get((job, index)) or final.get((job, index)) or "ended"
        out[rid] = f"{job}_{index} {state}"
    return out


def _gather(args: argparse.Namespace) -> int:
    from pyfold.sweep.gather import check_closures, gather

    closures = None if args.closures is None else check_closures(args.closures)
    path = gather(Path(args.dir), closures=closures, reports=not args.no_reports,
                  progress=lambda text: print(f"pyfold sweep: {text}", flush=True))
    print(f"pyfold sweep: {path}")
    return 0
