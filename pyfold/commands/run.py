"""``pyfold run SCENE.toml [-o OUT.h5] [--np N] [--force]``: the direct simulation of a scene.

Validate the scene completely -> write ``OUT.h5.partial`` (``/setup`` +
``/initial``) -> run ``fold_run`` on it (under ``mpirun -np N --oversubscribe``
when N > 1) with a progress bar fed by its ``PROGRESS`` lines -> rename to
``OUT.h5`` -> write ``OUT.xmf`` (ParaView) -> print a summary.

An existing ``OUT.h5`` is refused before any work unless ``--force``; even then
it stays intact until the new file is complete (atomic rename). Exit status:
0 success; 2 bad scene or run file (from ``fold_run`` too); 1 failure. On a
``fold_run`` failure (exit 1: blow-up, unresolvable overlap, I/O) the file with
the results up to the last good state and ``status = "failed: ..."`` is kept
as ``OUT.h5``.
"""
from __future__ import annotations

import argparse
import importlib
import os
import shlex
import shutil
import subprocess
import sys
import threading
from collections import deque
from pathlib import Path

from pyfold.errors import InputError, PyfoldError

#: Environment variable naming the fold_run executable explicitly.
FOLD_RUN_ENV = "PYFOLD_FOLD_RUN"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE.toml", help="scene file (see docs/scenes.md)")
    parser.add_argument("-o", "--output", metavar="OUT.h5", default=None,
                        help="run file to write (default: the scene's name with .h5, in the current folder)")
    parser.add_argument("--np", type=int, default=1, metavar="N", help="MPI ranks (default 1: no mpirun)")
    parser.add_argument("--force", action="store_true", help="replace an existing OUT.h5 (only once the new run ends)")


def find_fold_run() -> Path:
    """Locate the ``fold_run`` executable.

    Order (``fortran/app/README.md``): ``$PYFOLD_FOLD_RUN``; the build tree of an
    editable install (next to pyfold's compiled extension modules, and their
    ``fortran/app``); ``<site-packages>/pyfold/fold_run`` of a regular install;
    the environment's ``bin``; ``fold_run`` on ``PATH``.
    """
    explicit = os.environ.get(FOLD_RUN_ENV)
    if explicit:
        path = Path(explicit)
        if not (path.is_file() and os.access(path, os.X_OK)):
            raise PyfoldError(f"${FOLD_RUN_ENV} = {explicit}: not an executable file")
        return path
    candidates: list[Path] = []
    try:  # importing an extension also brings an editable build up to date
        ext = importlib.import_module("pyfold._fold_stats")
        build = Path(ext.__file__).resolve().parent
        candidates += [build / "fold_run", build / "fortran" / "app" / "fold_run"]
    except ImportError:
        pass
    try:  # a regular install puts it inside the package (fortran/app/README.md)
        from importlib.resources import files

        installed = files("pyfold") / "fold_run"
        if isinstance(installed, Path):
            candidates.append(installed)
    except (ModuleNotFoundError, TypeError):  # pragma: no cover
        pass
    candidates.append(Path(sys.prefix) / "bin" / "fold_run")
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    on_path = shutil.which("fold_run")
    if on_path:
        return Path(on_path)
    raise PyfoldError("the fold_run executable was not found (looked in " + ", ".join(map(str, candidates))
                      + f", and on PATH); build pyfold (scripts/bootstrap) or set ${FOLD_RUN_ENV}")


def _launch_command(fold_run: Path, run_file: Path, ranks: int) -> tuple[list[str], dict[str, str]]:
    env = dict(os.environ)
    if ranks == 1:
        return [str(fold_run), str(run_file)], env
    mpirun = shutil.which("mpirun") or shutil.which("mpiexec")
    if mpirun is None:
        raise PyfoldError("--np > 1 needs mpirun (Open MPI) on PATH")
    if hasattr(os, "geteuid") and os.geteuid() == 0:  # Open MPI refuses root without these
        env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
        env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    return [mpirun, "-np", str(ranks), "--oversubscribe", str(fold_run), str(run_file)], env


def _stream(pipe, sink: deque, echo) -> None:
    for line in iter(pipe.readline, ""):
        sink.append(line.rstrip("\n"))
        echo(line.rstrip("\n"))
    pipe.close()


def _execute(command: list[str], env: dict[str, str], n_steps: int) -> tuple[int, list[str]]:
    """Run fold_run; PROGRESS lines drive a rich progress bar, other lines are shown.

    Returns the exit code and the last lines it printed (stdout and stderr).
    """
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    console = Console(stderr=True)
    tail: deque[str] = deque(maxlen=40)
    with Progress(TextColumn("fold_run"), BarColumn(), TextColumn("{task.completed}/{task.total} steps"),
                  TextColumn("t = {task.fields[t]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                  console=console, transient=False) as progress:
        task = progress.add_task("run", total=n_steps, t="0")
        proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                bufsize=1)
        err_thread = threading.Thread(target=_stream, args=(proc.stderr, tail, lambda s: progress.console.print(
            s, markup=False, highlight=False)), daemon=True)
        err_thread.start()
        try:
            for line in iter(proc.stdout.readline, ""):
                line = line.rstrip("\n")
                fields = line.split()
                if len(fields) == 4 and fields[0] == "PROGRESS":
                    try:
                        progress.update(task, completed=int(fields[1]), total=int(fields[2]), t=f"{float(fields[3]):.6g}")
                        continue
                    except ValueError:
                        pass
                tail.append(line)
                progress.console.print(line, markup=False, highlight=False)
            rc = proc.wait()
        except BaseException:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
            raise
        finally:
            err_thread.join(timeout=10)
    return rc, list(tail)


def _cause(tail: list[str]) -> str:
    lines = [t for t in tail if t.strip() and not t.startswith("PROGRESS")]
    errors = [t for t in lines if "error" in t.lower() or "fail" in t.lower()] or lines
    return "\n".join(errors[-5:]) if errors else "(no message)"


def run(args: argparse.Namespace) -> int:
    from pyfold.scene import load_scene

    if args.np < 1:
        raise InputError(f"--np: must be an integer >= 1, got {args.np}")
    out = Path(args.output) if args.output else Path(Path(args.scene).stem + ".h5")
    if out.exists() and not args.force:
        raise InputError(f"-o: {out} exists; pass --force to replace it (it stays intact until the new run is complete)")
    if out.exists() and not out.is_file():
        raise InputError(f"-o: {out} exists and is not a file")
    if not out.parent.is_dir():
        raise InputError(f"-o: folder {out.parent} does not exist")
    partial = out.with_name(out.name + ".partial")

    resolved = load_scene(args.scene)
    for warning in resolved.warnings:
        print(f"pyfold run: warning: {warning}", file=sys.stderr)
    fold_run = find_fold_run()
    command, env = _launch_command(fold_run, partial, args.np)

    from pyfold.run_file import write_run_file
    from pyfold.scene.initial import initial_state

    initial = initial_state(resolved)
    cli = "pyfold run " + " ".join(shlex.quote(a) for a in getattr(args, "argv", None) or
                                   [args.scene, "-o", str(out), "--np", str(args.np)] + (["--force"] if args.force else []))
    write_run_file(partial, resolved, initial, cli)
    rc, tail = _execute(command, env, resolved.n_steps)

    if rc == 2:
        raise InputError(f"fold_run rejected the run file {partial} (kept for inspection):\n{_cause(tail)}")
    if rc != 0:
        _mark_failed(partial, rc)
    if out.exists() and not args.force:  # appeared while we ran: never overwrite it
        raise PyfoldError(f"{out} appeared during the run; the results stay in {partial}")
    os.replace(partial, out)
    from pyfold.runs import run_summary, write_xdmf

    xmf = None
    try:
        xmf = write_xdmf(out)
    except PyfoldError as exc:
        print(f"pyfold run: warning: no XDMF written: {exc}", file=sys.stderr)
    if rc != 0:
        raise PyfoldError(f"fold_run exited with status {rc}; results up to the last good state in {out}:\n"
                          f"{_cause(tail)}")
    print(f"pyfold run: {out}" + (f" (ParaView: {xmf})" if xmf else ""))
    print(resolved.summary().splitlines()[0])
    print(run_summary(out))
    return 0


def _mark_failed(path: Path, rc: int) -> None:
    """Give a file left by a crashed fold_run a status, if it recorded none."""
    import h5py

    from pyfold.run_file import fixed_string

    try:
        with h5py.File(path, "a") as f:
            status = f.attrs.get("status")
            if status is None or (bytes(status).decode(errors="replace") if not isinstance(status, str)
                                  else status).strip() in ("", "running", "ok"):
                f.attrs["status"] = fixed_string(f"failed: fold_run exited with status {rc} without recording a cause")
    except OSError:  # pragma: no cover - a file fold_run left unreadable
        pass
