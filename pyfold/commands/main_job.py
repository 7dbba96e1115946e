"""``pyfold main``: the bundled default job of the README.

By default the job answers with the seed's physics: the bundled ``fluid_coupled.toml``
(fibres coupled through the Stokes solver, with the collision strategy) is simulated for
several seeds beside their contacts-only twins (the same placement and time step, Jeffery
kinematics), and the report's C_I is the fluid-coupled one with the contacts-only one beside
it. ``--quick`` is the quick look: the bundled ``default.toml`` (contacts only) with a small
Stokes scene beside it. With ``--scene`` the scene's resolved model decides: a Stokes scene
gets its contacts-only twins, any other scene the contacts-only report.

The scene is simulated for several seeds (the scene's seed, seed + 1, ...),
``--np`` runs at a time as separate processes, then :mod:`pyfold.report` measures
C_I per closure by trajectory fit (the recommended value; fits on a bound flagged and
excluded) and by rate regression over the stationary part of every run, closure-free
(with the runs' own a4), each with its ensemble error, beside the published
correlations at the scene's phi beta, whether and when the steady state was reached,
and the closures ranked by their a4:D error with paired significance tests, effect
sizes and equivalence verdicts (the same report as ``pyfold report`` on the run
files), every output naming the physics model, resolution and strain range. A scene
shorter than one Jeffery period is reported with that warning in every output. The
small Stokes scene runs while the report is computed.

Every invocation writes a fresh, timestamped results folder under ``--out``
(``run-YYYYmmdd-HHMMSS``), assembled in a hidden temporary folder and renamed
into place only when complete, so an earlier result is never overwritten and
an interrupted job leaves no half-written folder. ``<out>/latest`` points to
the newest complete result. ``--out`` is locked for the job's life (``<out>.lock``
beside it, :mod:`pyfold.destination`): a second job with the same ``--out`` is
refused (exit 2) naming the holder.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path


from pyfold.errors import InputError, PyfoldError
from pyfold.run_checks import DEFAULT_CLOSURES

def _bundled_scenes() -> Path:
    """data/scenes of the source tree (editable install), or pyfold/scenes of a wheel."""
    installed = Path(__file__).resolve().parents[1] / "scenes"
    return installed if installed.is_dir() else Path(__file__).resolve().parents[2] / "data" / "scenes"


#: Scenes bundled with pyfold.
SCENES = _bundled_scenes()
DEFAULT_SCENE = SCENES / "default.toml"
STOKES_SCENE = SCENES / "stokes_small.toml"
#: The scene of the default job: fibres coupled through the Stokes solver, numerics by the
#: study preset (docs/speed_accuracy.md)
FLUID_SCENE = SCENES / "fluid_coupled.toml"
#: Seeds of the ensemble by default: enough for a standard error across seeds and a
#: paired test (3 degrees of freedom), and two rounds of two processes on 2 cores.
DEFAULT_SEEDS = 4
#: Processes at a time by default (the 2 cores the README's budget assumes).
DEFAULT_PROCESSES = 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/main", help="parent folder of the results (default: out/main)")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--scene", default=None,
                       help=f"scene to simulate (default: the bundled {FLUID_SCENE.name}, fibres coupled through "
                            "the Stokes solver); a scene resolving to the Stokes model gets its contacts-only twins "
                            "on the same seeds, any other scene the contacts-only report")
    which.add_argument("--quick", action="store_true",
                       help=f"the quick look (minutes): the bundled {DEFAULT_SCENE.name} (contacts only, Jeffery "
                            f"kinematics) and the small Stokes scene {STOKES_SCENE.name} beside it")
    parser.add_argument("--np", type=int, default=DEFAULT_PROCESSES, metavar="N",
                        help="cores to use: N seeds are simulated at a time, one MPI rank each "
                             f"(default {DEFAULT_PROCESSES})")
    parser.add_argument("--seeds", type=int, default=DEFAULT_SEEDS, metavar="K",
                        help=f"seeds of the ensemble: the scene's seed, seed + 1, ... (default {DEFAULT_SEEDS})")
    parser.add_argument("--closures", default=None,
                        help="comma-separated closures to estimate C_I with and to judge: 'exact' (the runs' own "
                             "a4) or names of pyfold.closures.available(dim) "
                             f"(default: {','.join(DEFAULT_CLOSURES)}, those defined in the scene's dimension)")


def _scene_dim(scene: Path) -> int:
    """The scene's dimension (2 or 3), from the complete validation (a bad scene stops here)."""
    from pyfold.scene import load_scene

    return load_scene(scene).dim


def choose_scene(scene: str | None, quick: bool) -> tuple[Path, bool]:
    """The scene of the job and whether it is the fluid-coupled job (contacts-only twins beside it):
    ``--quick`` the bundled contacts-only scene; ``--scene`` a scene whose resolved model decides
    (a bad scene stops here, with its validation error); neither the bundled fluid-coupled scene."""
    if quick:
        return DEFAULT_SCENE, False
    if not scene:
        return FLUID_SCENE, True
    path = Path(scene)
    if not path.is_file():
        raise InputError(f"--scene: no such scene file: {path}")
    from pyfold.scene import load_scene

    return path, load_scene(path).hydrodynamics == "stokes"


def run(args: argparse.Namespace) -> int:
    scene, fluid = choose_scene(args.scene, bool(getattr(args, "quick", False)))
    from pyfold.commands.run import check_ranks

    check_ranks(args.np)
    if args.seeds < 1:
        raise InputError(f"--seeds: must be an integer >= 1, got {args.seeds}")
    dim = _scene_dim(scene)
    if args.closures is None:
        from pyfold.closures import available

        closures = tuple(c for c in DEFAULT_CLOSURES if c == "exact" or c in available(dim))
    else:
        from pyfold.run_checks import check_closures

        closures = check_closures(args.closures, dim)
    if args.out == "":
        raise InputError("--out: empty path; name the parent folder of the results (default: out/main)")
    parent = Path(args.out)
    if parent.exists() and not parent.is_dir():
        raise InputError(f"--out: must be a folder (or not exist yet), got the file {parent}")
    from pyfold.destination import acquire, make_parent

    make_parent(parent, "--out")  # where its lock file goes
    with acquire(parent, "--out", command=f"pyfold main --out {parent}"):
        return _run_locked(parent, scene, args.np, args.seeds, closures, fluid)


def _run_locked(parent: Path, scene: Path, processes: int, n_seeds: int, closures: tuple[str, ...],
                fluid: bool = False) -> int:
    """The job, with its results folder ``parent`` locked."""
    try:
        parent.mkdir(exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out: cannot create the folder {parent}: {exc.strerror or exc}") from None
    stamp = time.strftime("run-%Y%m%d-%H%M%S")
    final = parent / stamp
    suffix = 1
    while final.exists():
        suffix += 1
        final = parent / f"{stamp}-{suffix}"
    work = Path(tempfile.mkdtemp(prefix=".partial-", dir=parent))
    try:
        _job(work, scene, processes, n_seeds, closures, fluid)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    work.rename(final)
    latest = parent / "latest"
    if latest.is_symlink() or not latest.exists():
        tmp_link = parent / f".latest-{os.getpid()}"
        tmp_link.unlink(missing_ok=True)
        tmp_link.symlink_to(final.name)
        tmp_link.replace(latest)
    print(f"pyfold main: results in {final}")
    return 0


def with_seed(text: str, seed: int) -> str:
    """The scene text with ``numerics.seed = seed`` (the line replaced in place, so the
    comments stay; added under ``[numerics]``, or in a new ``[numerics]`` table)."""
    lines = text.splitlines()
    table = None
    numerics_at = None
    for k, line in enumerate(lines):
        header = re.match(r"\s*\[\s*([^\]]+?)\s*\]", line)
        if header and not line.lstrip().startswith("[["):
            table = header.group(1)
            if table == "numerics":
                numerics_at = k
            continue
        if line.lstrip().startswith("[["):
            table = None
            continue
        if table == "numerics" and re.match(r"\s*seed\s*=", line):
            comment = line[line.index("#"):] if "#" in line else ""
            lines[k] = f"seed = {seed}" + (f"                   {comment}" if comment else "")
            return "\n".join(lines) + "\n"
    if numerics_at is not None:
        lines.insert(numerics_at + 1, f"seed = {seed}")
        return "\n".join(lines) + "\n"
    return text.rstrip("\n") + f"\n\n[numerics]\nseed = {seed}\n"


class _Jobs:
    """Child processes ``pyfold run`` (:func:`pyfold.commands.run.run_scene` with a log), at most
    ``slots`` at a time, each with a log file.

    The children run in their own sessions; on an error or a signal in the main job
    every running child gets SIGTERM (``pyfold run`` then stops its fold_run) and is
    waited for, so nothing outlives the job."""

    def __init__(self, slots: int, logs: Path):
        self.slots = max(1, int(slots))
        self.logs = logs
        self.running: dict[str, tuple[subprocess.Popen, object, Path, float]] = {}
        self.done: dict[str, tuple[int, float]] = {}
        self.last_report = time.monotonic()

    def report_progress(self) -> None:
        """Every progress interval (pyfold.progress), one line per running seed: its step,
        strain and ETA, from the plain progress lines its `pyfold run` writes to its log."""
        from pyfold.progress import default_interval, describe, latest_in_log

        if time.monotonic() - self.last_report < default_interval():
            return
        self.last_report = time.monotonic()
        for name, (_, _, log_path, _) in self.running.items():
            print(f"pyfold main:   {describe(name, latest_in_log(log_path))}", flush=True)

    def start(self, name: str, scene: Path, out: Path) -> None:
        """Start `pyfold run` of ``scene`` with one rank (fold_run and the placement are
        serial per run: the parallelism is over seeds)."""
        from pyfold.commands import run as run_command

        log_path = self.logs / f"{name.replace(' ', '_')}.log"
        log = open(log_path, "w", encoding="utf-8")
        try:
            proc = run_command.run_scene(scene, out, ranks=1, log=log)
        except BaseException:
            log.close()
            raise
        self.running[name] = (proc, log, log_path, time.perf_counter())

    def wait_one(self) -> str:
        while True:
            for name, (proc, log, log_path, t0) in list(self.running.items()):
                if proc.poll() is not None:
                    log.close()
                    del self.running[name]
                    self.done[name] = (proc.returncode, time.perf_counter() - t0)
                    if proc.returncode != 0:
                        tail = log_path.read_text(encoding="utf-8", errors="replace").strip().splitlines()[-8:]
                        raise PyfoldError(f"`pyfold run` for {name} failed (exit {proc.returncode}):\n  "
                                          + "\n  ".join(tail))
                    return name
            self.report_progress()
            time.sleep(0.2)

    def run_all(self, jobs: list[tuple[str, Path, Path]], say) -> None:
        queue = list(jobs)
        while queue or self.running:
            while queue and len(self.running) < self.slots:
                self.start(*queue.pop(0))
            if self.running:
                name = self.wait_one()
                say(f"{name} done ({self.done[name][1]:.0f} s)")

    def stop(self) -> None:
        for proc, log, _, _ in self.running.values():
            if proc.poll() is None:
                proc.terminate()
        deadline = time.monotonic() + 20.0
        for proc, log, _, _ in self.running.values():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()
        self.running.clear()


def contacts_only_twin(text: str, dt: float) -> str:
    """The scene text with the contacts-only model (``model.hydrodynamics = "jeffery"``) at the
    time step ``dt`` of its fluid-coupled run: the same particles, seed and outputs, no Stokes
    settings and no preset."""
    import tomllib

    import tomli_w

    data = tomllib.loads(text)
    data.setdefault("model", {})["hydrodynamics"] = "jeffery"
    num = data.setdefault("numerics", {})
    for key in ("stokes", "preset", "time_scheme"):
        num.pop(key, None)
    num["dt"] = float(dt)
    if "title" in data:
        data["title"] = f"{data['title']} (contacts-only twin)"
    return tomli_w.dumps(data)


def twin_lines(fluid, twin) -> list[str]:
    """The fluid-coupled C_I against the contacts-only twins' (two pyfold.report.Report of the
    same seeds): closure-free rate regression and every trajectory fit, with the difference."""
    import math

    lines = ["", "Fluid-coupled against contacts only (the same seeds and time step; contacts-only twins in "
             "contacts_only/):", f"  {'C_I':<28} {'fluid-coupled':>22} {'contacts only':>22} {'difference':>22}"]

    def row(label, a, b):
        if a is None or b is None:
            return
        err = math.hypot(a.error, b.error) if math.isfinite(a.error) and math.isfinite(b.error) else math.nan
        lines.append(f"  {label:<28} {a.mean:+11.3e} ± {a.error:8.1e} {b.mean:+11.3e} ± {b.error:8.1e} "
                     f"{a.mean - b.mean:+11.3e} ± {err:8.1e}")

    row("closure-free (rate regr.)", fluid.ci.get("exact"), twin.ci.get("exact"))
    for c in fluid.ci_fit:
        row(f"{c} (trajectory fit)", fluid.ci_fit.get(c), twin.ci_fit.get(c))
    return lines


def _job(outdir: Path, scene: Path, processes: int, n_seeds: int, closures: tuple[str, ...],
         fluid: bool = False) -> None:
    """Simulate the seeds, report on them (and run the Stokes scene meanwhile; with ``fluid``
    the contacts-only twins instead, reported beside the fluid-coupled C_I)."""
    from pyfold import report
    from pyfold.scene import load_scene

    def say(text: str) -> None:
        print(f"pyfold main: {text}", flush=True)

    t_start = time.perf_counter()
    base = load_scene(scene).seed
    seeds = [base + k for k in range(n_seeds)]
    text = scene.read_text(encoding="utf-8")
    scratch = Path(tempfile.mkdtemp(prefix=".scenes-", dir=outdir))
    jobs = _Jobs(processes, scratch)
    try:
        runs, pending = [], []
        for seed in seeds:
            seed_scene = scene  # the scene's own seed: the file itself
            if seed != base:
                seed_scene = scratch / f"seed_{seed}.toml"
                seed_scene.write_text(with_seed(text, seed), encoding="utf-8")
                if load_scene(seed_scene).seed != seed:  # the text edit must mean what it says
                    raise PyfoldError(f"{scene}: could not set numerics.seed = {seed} in a copy of the scene")
            runs.append(outdir / f"run_seed{seed}.h5")
            pending.append((f"seed {seed}", seed_scene, runs[-1]))
        twins = []
        if fluid:
            (outdir / "contacts_only").mkdir()
            for seed, (_, seed_scene, _) in zip(seeds, list(pending)):
                twin = scratch / f"twin_{seed}.toml"
                twin.write_text(contacts_only_twin(seed_scene.read_text(encoding="utf-8"),
                                                   load_scene(seed_scene).dt), encoding="utf-8")
                twins.append(outdir / "contacts_only" / f"run_seed{seed}.h5")
                pending.insert(len(twins) - 1, (f"contacts-only twin of seed {seed}", twin, twins[-1]))
        say(f"1/3 direct simulation of {scene.name}, seeds {', '.join(map(str, seeds))} "
            + ("with their contacts-only twins " if fluid else "") + f"({jobs.slots} at a time)")
        jobs.run_all(pending, say)
        stokes = not fluid and STOKES_SCENE.is_file() and scene.resolve() == DEFAULT_SCENE.resolve()
        if stokes:
            say(f"2/3 small Stokes scene {STOKES_SCENE.name} (fibres coupled through the fluid), beside step 3")
            jobs.start("Stokes scene", STOKES_SCENE, outdir / "stokes_run.h5")
        say("3/3 report: steady state, C_I per closure, closure errors and ranking, Folgar-Tucker per closure")
        # the simulations are done: a run shorter than the estimators need is reported with the
        # warning in every output rather than thrown away
        rep = report.build_report(runs, closures, progress=lambda t: say(f"  {t}"), force=True)
        extra = []
        if stokes:
            while jobs.running:
                jobs.wait_one()
            extra = [report.stokes_summary(outdir / "stokes_run.h5")]
        elif fluid:
            say("  the contacts-only twins")
            extra = twin_lines(rep, report.build_report(twins, closures, force=True))
        else:
            extra = ["Stokes scene: skipped (it runs with the bundled default scene only)"]
        extra.append(f"main job: {n_seeds} seeds, {jobs.slots} processes at a time; "
                     f"{time.perf_counter() - t_start:.0f} s wall")
        report.write_report(rep, outdir, extra)
    except BaseException:
        jobs.stop()
        raise
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    print("\n".join(report.summary_lines(rep) + [""] + extra))
