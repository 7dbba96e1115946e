"""``pyfold run SCENE.toml [-o OUT.h5] [--np N] [--force | --resume]``: the direct simulation of a scene.

Validate the scene completely -> write ``OUT.h5.partial`` (``/setup`` +
``/initial``) -> run ``fold_run`` on it (under ``mpirun -np N --oversubscribe``
when N > 1) with a progress bar fed by its ``PROGRESS`` lines (on a terminal; else
plain progress lines every ``--progress-every`` seconds: :mod:`pyfold.progress`) -> rename to
``OUT.h5`` -> write ``OUT.xmf`` (ParaView) -> print a summary.

Nothing is overwritten without ``--force``, and every refusal comes before any
work: ``-o`` must end in ``.h5`` (or ``.hdf5``, ``.nc``: the run also writes
``OUT.xmf`` beside it, and ``OUT.h5.partial`` while it runs), an existing
``OUT.h5`` or ``OUT.xmf`` is refused, and so is an existing ``OUT.h5.partial``
(an interrupted run: continue it with ``--resume``, or start again with
``--force``). Even with ``--force`` an existing ``OUT.h5`` stays intact until
the new file is complete (atomic rename).

``-o``'s folder is created (with its parents) when missing, and removed again when
the run is refused before it starts; a path through an existing file is refused.

``--resume`` continues ``OUT.h5.partial`` (or a failed ``OUT.h5``, whose
``status`` is not ``ok``) from its last checkpoint with ``fold_run --resume``,
then finishes like a run (rename, ``OUT.xmf`` rewritten, summary). Its scene must be
the recorded one, or differ only by a larger ``numerics.t_end``: then the run (also a
complete ``OUT.h5``) is extended to the new end, bit for bit as a run made in one go
(:mod:`pyfold.extend`); any other difference is refused with exit 2 naming the key,
and so is a complete run given no later end. The file is
verified first (:func:`pyfold.integrity.verify_path`): a dataset that fails its
checksum is refused with exit 2 naming it. A file another
process holds open (a reader's HDF5 lock: an undone ``ds.close()``) is refused
with exit 2 naming that process, before anything is moved.

One writer per destination (:mod:`pyfold.destination`): before anything is
written the run takes an exclusive lock on ``OUT.h5.lock`` (pid, host, start
time and command recorded in it), held until it ends and inherited by
``fold_run`` / ``mpirun``, so an orphaned ``fold_run`` of a killed pyfold still
holds it; a second ``pyfold run`` or ``--resume`` of the same ``-o`` is refused
(exit 2) naming the holder. A failed run removes only a ``.partial`` it created
itself. Links: a symbolic link at ``OUT.h5``, ``OUT.xmf`` or ``OUT.h5.partial``
counts as an existing file (refused without ``--force``); with ``--force`` the
link itself is replaced by a new file, its target is never written;
``--resume`` refuses a link. The scene file is never an output (also through a
symbolic or hard link): refused with exit 2 naming both paths. ``-o ""`` and a
name that, with ``.partial``, exceeds its folder's NAME_MAX are refused.

``--np`` is bounded by :func:`rank_bound` (``OVERSUBSCRIBE_FACTOR`` ranks per
usable core; more only with ``--oversubscribe``, never more than
``MAX_RANKS``). ``fold_run`` (or ``mpirun``) runs in its own session; when
pyfold ends for any reason (an exception, SIGINT, SIGTERM, SIGHUP: see
:mod:`pyfold.cli`, or interpreter exit) its whole process group is terminated
and waited for, and ``OUT.h5.partial`` is kept for ``--resume``.

Exit status: 0 success; 2 bad scene, option or run file (from ``fold_run``
too), or a destination another process writes; 1 failure; 130 / 143 / 129
interrupted by SIGINT / SIGTERM / SIGHUP before ``OUT.h5`` was complete and in
place (after that, the XDMF and summary are finished and the status is the
run's). On a
``fold_run`` failure (exit 1: blow-up, unresolvable overlap, I/O) the file with
the results up to the last good state and ``status = "failed: ..."`` is kept
as ``OUT.h5``. A complete run whose ``OUT.xmf`` cannot be written (a full disk)
keeps ``OUT.h5``, the result, with no ``OUT.xmf`` (never a half-written one:
:func:`pyfold.files.atomic_output`), prints the summary and exits 1 naming the
cause; ``python -c "from pyfold.run_results import write_xdmf; write_xdmf('OUT.h5')"``
writes it once there is space.
"""
from __future__ import annotations

import argparse
import atexit
import importlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from pathlib import Path

from pyfold.command_line import command_line
from pyfold.destination import LOCK_SUFFIX, acquire, check_name_length, lock_path, open_elsewhere, \
    refuse_input_as_output
from pyfold.errors import InputError, PyfoldError
from pyfold.progress import DEFAULT_INTERVAL, INTERVAL_ENV
from pyfold.xdmf_files import xdmf_data_path

#: Environment variable naming the fold_run executable explicitly.
FOLD_RUN_ENV = "PYFOLD_FOLD_RUN"
#: Suffixes accepted for ``-o`` (the XDMF companion is ``OUT`` with suffix ``.xmf``).
RUN_SUFFIXES = (".h5", ".hdf5", ".nc")
#: MPI ranks allowed per usable core without ``--oversubscribe``.
OVERSUBSCRIBE_FACTOR = 4
#: Absolute ceiling of ``--np``, also with ``--oversubscribe``.
MAX_RANKS = 4096
#: Seconds a terminated fold_run / mpirun group gets to exit before SIGKILL.
TERMINATE_GRACE = 3.0
#: Suffix of the run file while fold_run writes it (``OUT.h5.partial``).
PARTIAL_SUFFIX = ".partial"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE.toml", help="scene file (see docs/scenes.md)")
    parser.add_argument("-o", "--output", metavar="OUT.h5", default=None,
                        help="run file to write, ending in .h5 (.hdf5, .nc); OUT.xmf is written beside it "
                             "(default: the scene's name with .h5, in the current folder)")
    parser.add_argument("--np", type=int, default=1, metavar="N",
                        help=f"MPI ranks (default 1: no mpirun; at most {OVERSUBSCRIBE_FACTOR} per usable core "
                             "without --oversubscribe)")
    parser.add_argument("--oversubscribe", action="store_true",
                        help=f"allow --np beyond {OVERSUBSCRIBE_FACTOR} ranks per usable core (up to {MAX_RANKS})")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing OUT.h5 / OUT.xmf (only once the new run ends), or start again "
                             "over an interrupted OUT.h5.partial")
    parser.add_argument("--resume", action="store_true",
                        help="continue OUT.h5.partial (or a failed OUT.h5) from its last checkpoint; with a scene "
                             "that differs only by a larger numerics.t_end, extend the run (also a complete OUT.h5) "
                             "to the new end")
    parser.add_argument("--progress-every", type=float, default=None, metavar="SECONDS",
                        help="when stderr is not a terminal (a log file, a batch job), a plain progress line "
                             f"(step, strain, ETA, load) every SECONDS (default: ${INTERVAL_ENV} or "
                             f"{DEFAULT_INTERVAL:g}; a progress bar on a terminal)")


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity, else ``os.cpu_count()``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def rank_bound(oversubscribe: bool = False) -> int:
    """The largest ``--np`` accepted: ``OVERSUBSCRIBE_FACTOR`` x usable cores, or
    ``MAX_RANKS`` with ``--oversubscribe``."""
    return MAX_RANKS if oversubscribe else OVERSUBSCRIBE_FACTOR * usable_cores()


def check_ranks(ranks: int, oversubscribe: bool = False, option: str = "--np") -> None:
    """Refuse a rank count that is not >= 1 or beyond :func:`rank_bound` (InputError naming ``option``)."""
    if ranks < 1:
        raise InputError(f"{option}: must be an integer >= 1, got {ranks}")
    bound = rank_bound(oversubscribe)
    if ranks > bound:
        if oversubscribe:
            raise InputError(f"{option}: {ranks} ranks is beyond the ceiling of {MAX_RANKS} (also with --oversubscribe)")
        cores = usable_cores()
        raise InputError(f"{option}: {ranks} ranks is beyond the bound of {bound} ({OVERSUBSCRIBE_FACTOR} per usable "
                         f"core, {cores} core{'s' if cores != 1 else ''} here); pass --oversubscribe to run more "
                         f"(up to {MAX_RANKS})")


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


def _launch_command(fold_run: Path, run_file: Path, ranks: int,
                    resume: bool = False) -> tuple[list[str], dict[str, str]]:
    env = dict(os.environ)
    tail = [str(run_file)] + (["--resume"] if resume else [])
    if ranks == 1:
        return [str(fold_run)] + tail, env
    mpirun = shutil.which("mpirun") or shutil.which("mpiexec")
    if mpirun is None:
        raise PyfoldError("--np > 1 needs mpirun (Open MPI) on PATH")
    if hasattr(os, "geteuid") and os.geteuid() == 0:  # Open MPI refuses root without these
        env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
        env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    return [mpirun, "-np", str(ranks), "--oversubscribe", str(fold_run)] + tail, env


#: Process groups of fold_run / mpirun still running (killed at interpreter exit).
_LIVE: set[subprocess.Popen] = set()
_LIVE_LOCK = threading.Lock()


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - a recycled group id of another user
        return False
    return True


def terminate_group(proc: subprocess.Popen, grace: float = TERMINATE_GRACE) -> None:
    """Terminate the whole process group (session) ``proc`` leads and wait for it:
    SIGTERM, then SIGKILL after ``grace`` seconds. The leader is reaped; the group
    counts as gone when no member is left (zombies of ranks already reparented to
    init are waited for at most 5 s more)."""
    pgid = proc.pid
    try:
        for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(pgid, sig)
            except ProcessLookupError:
                return
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline:
                proc.poll()  # reaps the leader, so an exited leader leaves the group
                if not _group_alive(pgid):
                    return
                time.sleep(0.02)
    finally:
        try:
            proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:  # pragma: no cover - unkillable (D state)
            pass
        with _LIVE_LOCK:
            _LIVE.discard(proc)


@atexit.register
def _terminate_live_groups() -> None:
    with _LIVE_LOCK:
        live = list(_LIVE)
    for proc in live:
        terminate_group(proc)


def _stream(pipe, sink: deque, echo) -> None:
    for line in iter(pipe.readline, ""):
        sink.append(line.rstrip("\n"))
        echo(line.rstrip("\n"))
    pipe.close()


def _execute(command: list[str], env: dict[str, str], n_steps: int,
             pass_fds: tuple[int, ...] = (), strain_rate: float = 0.0,
             progress_every: float | None = None) -> tuple[int, list[str]]:
    """Run fold_run in its own session; its PROGRESS lines drive a rich progress bar
    on a terminal, or plain progress lines every ``progress_every`` seconds
    (:mod:`pyfold.progress`) when stderr is a file or a pipe; other lines are shown.
    ``pass_fds`` are inherited by it (the destination's lock: held as long as
    fold_run / mpirun lives, also if pyfold is killed).

    Any exception while it runs (KeyboardInterrupt, a signal turned into an
    exception by :mod:`pyfold.cli`) terminates its whole process group (mpirun and
    every rank), waits for it, and propagates.

    Returns the exit code and the last lines it printed (stdout and stderr).
    """
    from rich.console import Console

    console = Console(stderr=True)
    if console.is_terminal:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        display = Progress(TextColumn("fold_run"), BarColumn(), TextColumn("{task.completed}/{task.total} steps"),
                           TextColumn("t = {task.fields[t]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                           console=console, transient=False)
        with display:
            task = display.add_task("run", total=n_steps, t="0")
            return _follow(command, env, pass_fds,
                           lambda s: display.console.print(s, markup=False, highlight=False),
                           lambda step, total, t: display.update(task, completed=step, total=total, t=f"{t:.6g}"))
    from pyfold.progress import PlainProgress, default_interval

    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    interval = progress_every if progress_every is not None else default_interval()
    with PlainProgress(say, n_steps, strain_rate, interval) as plain:
        return _follow(command, env, pass_fds, say, plain.update)


def _follow(command: list[str], env: dict[str, str], pass_fds: tuple[int, ...], show, on_progress
            ) -> tuple[int, list[str]]:
    """Start fold_run, pass its PROGRESS lines to ``on_progress(step, total, t)`` and
    every other line to ``show``; see :func:`_execute`."""
    tail: deque[str] = deque(maxlen=40)
    proc = None
    err_thread = None
    try:
        proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                bufsize=1, start_new_session=True, pass_fds=pass_fds)
        with _LIVE_LOCK:
            _LIVE.add(proc)
        err_thread = threading.Thread(target=_stream, args=(proc.stderr, tail, show), daemon=True)
        err_thread.start()
        for line in iter(proc.stdout.readline, ""):
            line = line.rstrip("\n")
            fields = line.split()
            if len(fields) == 4 and fields[0] == "PROGRESS":
                try:
                    on_progress(int(fields[1]), int(fields[2]), float(fields[3]))
                    continue
                except ValueError:
                    pass
            tail.append(line)
            show(line)
        rc = proc.wait()
    except BaseException:
        if proc is not None:
            terminate_group(proc)
        raise
    finally:
        if proc is not None:
            if proc.returncode is not None and _group_alive(proc.pid):
                terminate_group(proc)  # ranks left behind by an mpirun that exited
            with _LIVE_LOCK:
                _LIVE.discard(proc)
        if err_thread is not None:
            err_thread.join(timeout=10)
    return rc, list(tail)


def _cause(tail: list[str]) -> str:
    lines = [t for t in tail if t.strip() and not t.startswith("PROGRESS")]
    errors = [t for t in lines if "error" in t.lower() or "fail" in t.lower()] or lines
    return "\n".join(errors[-5:]) if errors else "(no message)"


def _status(path: Path) -> str | None:
    """The root attribute ``status`` of a run file (None: none, or not readable as HDF5)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            status = f.attrs.get("status")
    except OSError:
        return None
    if status is None:
        return None
    return (status.decode(errors="replace") if isinstance(status, bytes) else str(status)).strip()


def _check_output_folder(out: Path) -> list[Path]:
    """``-o``'s folder is created with its parents when missing (as ``report --out`` and
    ``main --out`` do) and must take new files (probed: permissions, read-only mounts).
    A path through an existing file is refused. Returns the folders created, outermost
    first (:func:`_remove_if_empty` takes them away again if the run never starts)."""
    folder = out.parent
    created: list[Path] = []
    if not folder.is_dir():
        if folder.exists() or any(p.exists() and not p.is_dir() for p in folder.parents):
            raise InputError(f"-o: cannot write {out}: {next(p for p in [folder, *folder.parents] if p.exists())} "
                             "is a file, not a folder")
        missing = [p for p in [folder, *folder.parents] if not p.exists()]
        for path in reversed(missing):
            try:
                path.mkdir()
            except FileExistsError:
                continue
            except OSError as exc:
                _remove_if_empty(created)
                raise InputError(f"-o: cannot write {out}: cannot create the folder {path} "
                                 f"({exc.strerror or exc}); choose a writable location") from None
            created.append(path)
    try:
        fd, probe = tempfile.mkstemp(prefix=".pyfold-write-test-", dir=folder)
    except OSError as exc:
        raise InputError(f"-o: cannot write {out}: the folder {folder} does not take new files "
                         f"({exc.strerror or exc}); choose a writable location") from None
    os.close(fd)
    os.unlink(probe)
    return created


def _remove_if_empty(folders: list[Path]) -> None:
    """Remove the folders ``-o`` created (innermost first) that are still empty."""
    for path in reversed(folders):
        try:
            path.rmdir()
        except OSError:
            return


def _output_path(args: argparse.Namespace) -> Path:
    """``-o`` (default: the scene's name with ``.h5``); refused when empty or without a run-file suffix."""
    if args.output is not None and args.output == "":
        raise InputError("-o: empty path; name the run file to write (e.g. -o run.h5), or leave -o out for the "
                         "scene's name with .h5")
    out = Path(args.output) if args.output is not None else Path(Path(args.scene).stem + ".h5")
    if out.suffix.lower() not in RUN_SUFFIXES:
        raise InputError(f"-o: {out} must end in {', '.join(RUN_SUFFIXES)} (the run writes its XDMF to "
                         f"{out.with_suffix('.xmf').name} and {out.name}{PARTIAL_SUFFIX} beside it), got "
                         f"{out.suffix or 'no suffix'!r}")
    return out


def _shown(path: Path) -> str:
    """``path``, and where it points when it is a symbolic link."""
    if path.is_symlink():
        return f"{path} (a symbolic link to {os.readlink(path)})"
    return str(path)


def _plan_output(args: argparse.Namespace, out: Path) -> tuple[Path, Path, Path | None]:
    """Check what lies at and beside ``out`` (under its lock, before any work).

    A symbolic link at an output name counts as an existing file: refused without
    ``--force``; with it the link itself is replaced, its target never written.
    Returns ``(partial, xmf, resume_from)``; ``resume_from`` is the file ``--resume``
    continues (``partial``, or a failed ``out``), None for a new run.
    """
    partial = out.with_name(out.name + PARTIAL_SUFFIX)
    xmf = out.with_suffix(".xmf")
    for path in (out, partial, xmf, xdmf_data_path(xmf)):
        if path.exists() and not path.is_symlink() and not path.is_file():
            raise InputError(f"-o: {path} exists and is not a file")

    resume_from = None
    if args.resume:
        if os.path.lexists(partial):
            resume_from = partial
            if os.path.lexists(out) and not args.force:
                raise InputError(f"-o: {_shown(out)} exists; resuming {partial.name} would replace it when complete: "
                                 "pass --force to allow that")
        elif os.path.lexists(out):
            status = None if out.is_symlink() else _status(out)
            if not out.is_symlink() and status is None:
                raise InputError(f"--resume: nothing to resume: {out} is not a run file with a status and there is "
                                 f"no {partial.name}")
            # failed, or complete (status ok: extended when the scene asks for a later end,
            # pyfold.extend.plan); its XDMF beside it is the run's own
            resume_from = out
        else:
            raise InputError(f"--resume: nothing to resume: neither {partial} nor a failed {out} exists")
        if resume_from.is_symlink():
            raise InputError(f"--resume: {_shown(resume_from)} is a symbolic link; a run continues only a regular "
                             f"file (never writing through a link): resume the file itself with -o "
                             f"{os.path.realpath(resume_from)}")
        for view in (xmf, xdmf_data_path(xmf)):
            if os.path.lexists(view) and not args.force and resume_from is partial and not os.path.lexists(out):
                raise InputError(f"-o: {_shown(view)} exists (the run writes its XDMF there); pass --force to "
                                 "replace it")
        return partial, xmf, resume_from

    if os.path.lexists(out) and not args.force:
        raise InputError(f"-o: {_shown(out)} exists; pass --force to replace it (it stays intact until the new run "
                         "is complete)")
    for view in (xmf, xdmf_data_path(xmf)):
        if os.path.lexists(view) and not args.force:
            raise InputError(f"-o: {_shown(view)} exists (the run writes its XDMF there, beside {out.name}); pass "
                             "--force to replace it, or choose another -o")
    if os.path.lexists(partial) and not args.force:
        raise InputError(f"-o: {_shown(partial)} exists: an interrupted run of {out.name}; pass --resume to continue "
                         "it from its last checkpoint, or --force to start again")
    return partial, xmf, None


def _identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of ``path`` itself (not of a link's target); None when absent."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def _create_new(path: Path) -> tuple[int, int]:
    """Create ``path`` as a new empty file (never through a link, never an existing
    file); its identity tells later whether the file there is still this one."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise InputError(f"-o: cannot write {path}: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
    finally:
        os.close(fd)
    return st.st_dev, st.st_ino


def _unlink_if_ours(path: Path, identity: tuple[int, int] | None) -> None:
    """Remove ``path`` only if it is still the file this process created."""
    if identity is not None and _identity(path) == identity:
        path.unlink(missing_ok=True)


def run(args: argparse.Namespace) -> int:
    check_ranks(args.np, getattr(args, "oversubscribe", False))
    if not hasattr(args, "resume"):
        args.resume = False
    if getattr(args, "progress_every", None) is not None:
        from pyfold.progress import check_interval

        check_interval(args.progress_every)
    out = _output_path(args)
    check_name_length(out, (PARTIAL_SUFFIX, LOCK_SUFFIX), "-o")
    created = _check_output_folder(out)
    try:
        partial = out.with_name(out.name + PARTIAL_SUFFIX)
        refuse_input_as_output(Path(args.scene), (out, partial, out.with_suffix(".xmf"),
                                                  xdmf_data_path(out.with_suffix(".xmf")), lock_path(out)),
                               "-o", "scene file")
        argv = getattr(args, "argv", None) or ([args.scene, "-o", str(out), "--np", str(args.np)]
                                              + (["--force"] if args.force else [])
                                              + (["--resume"] if args.resume else []))
        cli = command_line(["pyfold", "run", *argv])
        with acquire(out, "-o", command=cli) as lock:
            return _run_locked(args, out, cli, lock.fd)
    finally:
        _remove_if_empty(created)  # a run that never started leaves no new empty folders


def run_scene(scene: Path, out: Path, ranks: int = 1, log=None):
    """Run a scene with the direct simulation (``pyfold run``); returns the result file.

    With ``log`` (a file open for writing), ``pyfold run`` is started instead as a child
    Python process in its own session, its output going to ``log``, and the
    :class:`subprocess.Popen` is returned at once: the caller waits for it and stops it
    (SIGTERM: ``pyfold run`` then stops its fold_run and keeps the partial file). The
    main job runs its seeds this way, several at a time.
    """
    if log is not None:
        argv = [sys.executable, "-m", "pyfold.cli", "run", str(scene), "-o", str(out), "--np", str(ranks)]
        return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
    from pyfold.cli import main as cli_main

    argv = ["run", str(scene), "-o", str(out), "--np", str(ranks)]
    status = cli_main(argv)
    if status == 2:
        raise InputError(f"scene {scene} was rejected (see the message above)")
    if status != 0:
        raise PyfoldError(f"the direct simulation of {scene} failed (status {status}); partial results in {out}")
    return out


def _run_locked(args: argparse.Namespace, out: Path, cli: str, lock_fd: int | None) -> int:
    """The run, with the destination ``out`` locked (``lock_fd`` is given to fold_run)."""
    from pyfold.scene import load_scene

    partial, xmf, resume_from = _plan_output(args, out)
    resolved = load_scene(args.scene)
    for warning in resolved.warnings:
        print(f"pyfold run: warning: {warning}", file=sys.stderr)
    fold_run = find_fold_run()
    command, env = _launch_command(fold_run, partial, args.np, resume=resume_from is not None)
    resume_hint = command_line(["pyfold", "run", Path(args.scene), "-o", Path(out), "--resume"])

    if resume_from is None:
        from pyfold.run_input import write_run_file
        from pyfold.scene.initial import initial_state

        initial = initial_state(resolved)
        if os.path.lexists(partial):  # --force: start again; a link is removed, its target untouched
            partial.unlink()
        created = _create_new(partial)
        try:
            write_run_file(partial, resolved, initial, cli)
        except BaseException as exc:
            _unlink_if_ours(partial, created)  # half-written by this process: nothing to resume
            if isinstance(exc, OSError):
                raise InputError(f"-o: cannot write {partial}: {exc}") from None
            raise
        n_steps = resolved.n_steps
    else:
        from pyfold.extend import plan as plan_extension
        from pyfold.extend import rewrite_setup
        from pyfold.integrity import refuse, verify_path
        from pyfold.run_input import read_setup

        # Every dataset is verified before fold_run continues the file: it reads back only
        # /setup, /initial and the checkpoint, and would carry a damaged record into an "ok" run.
        refuse(resume_from, verify_path(resume_from), "refusing to resume from it (continue from an intact copy, "
               "or start again with --force)")
        try:
            setup = read_setup(resume_from)
            extension = plan_extension(resume_from, resolved, Path(args.scene), partial=resume_from == partial)
        except (OSError, KeyError) as exc:
            raise InputError(f"--resume: {resume_from} is not a readable run file: {exc}") from None
        n_steps = extension.resolved.n_steps if extension.extends else int(setup.resolved.get("n_steps",
                                                                                              resolved.n_steps))
        reader = open_elsewhere(resume_from)
        if reader:
            raise InputError(f"--resume: {resume_from} is open in {reader}, which holds HDF5's lock on it; the file "
                             "is not damaged. Close it there (a dataset from pyfold.open_run: ds.close(); "
                             "an h5py.File: f.close()), then run this command again")
        if resume_from != partial:
            os.replace(resume_from, partial)  # a failed or complete OUT.h5: continued as OUT.h5.partial
        if extension.extends:
            rewrite_setup(partial, extension.resolved)
            resolved = extension.resolved
            print(f"pyfold run: extending {partial} from t_end = {extension.recorded_t_end:g} to "
                  f"{extension.t_end:g} ({n_steps} steps), from its last checkpoint", file=sys.stderr)
        else:
            print(f"pyfold run: resuming {partial} from its last checkpoint", file=sys.stderr)
    try:
        rc, tail = _execute(command, env, n_steps, pass_fds=(lock_fd,) if lock_fd is not None else (),
                            strain_rate=resolved.shear_rate, progress_every=getattr(args, "progress_every", None))
    except BaseException:
        if partial.exists():
            print(f"pyfold run: interrupted; the run so far is kept in {partial}; continue it with: {resume_hint}",
                  file=sys.stderr)
        raise

    if rc == 2:
        reader = open_elsewhere(partial) if "temporarily unavailable" in _cause(tail) else None
        if reader:  # opened by a reader after the check above: locked, not damaged
            raise InputError(f"fold_run could not open {partial}: it is open in {reader}, which holds HDF5's lock "
                             "on it; the file is not damaged. Close it there (ds.close(), f.close()), then continue "
                             f"with: {resume_hint}")
        raise InputError(f"fold_run rejected the run file {partial} (kept for inspection):\n{_cause(tail)}")
    complete = _identity(partial)
    try:
        return _finish(args, out, partial, xmf, rc, tail, resolved, resume_hint, renamed=False)
    except KeyboardInterrupt:
        if complete is None or _identity(out) != complete:
            raise  # not yet in place: an interrupted run, OUT.h5.partial kept
        # OUT.h5 is complete: the signal does not undo that; the few steps left run to their end
        # (a further signal is ignored by pyfold.cli's handler while this one is handled)
        print(f"pyfold run: interrupted after {out} was complete; finishing its XDMF and summary", file=sys.stderr)
        return _finish(args, out, partial, xmf, rc, tail, resolved, resume_hint, renamed=True)


def _finish(args: argparse.Namespace, out: Path, partial: Path, xmf: Path, rc: int, tail: list[str], resolved,
            resume_hint: str, renamed: bool) -> int:
    """After fold_run: the status of a crash, the rename to ``out`` (unless ``renamed``),
    the XDMF, and the summary or the failure."""
    from pyfold.run_results import run_summary, write_xdmf

    if not renamed:
        if rc != 0:
            failed = [ln.strip().split("fold_run: ", 1)[1] for ln in tail
                      if ln.strip().startswith("fold_run: failed:")]
            _mark_failed(partial, rc, failed[-1] if failed else "")
        if os.path.lexists(out) and not args.force:  # appeared while we ran: never overwrite it
            raise PyfoldError(f"{out} appeared during the run; the results stay in {partial}")
        os.replace(partial, out)  # a link at OUT.h5 is replaced, its target untouched
    written, no_xdmf = None, None
    try:
        written = write_xdmf(out, xmf)  # atomic: a link at xmf is replaced, its target untouched
    except PyfoldError as exc:  # e.g. a full disk: the run file is the result and is kept; exit 1 below
        no_xdmf = exc
        print(f"pyfold run: warning: no XDMF written: {exc}", file=sys.stderr)
    if rc != 0:
        cause = _cause(tail)
        try:
            import h5py

            with h5py.File(out, "r"):
                readable = True
        except OSError:
            readable = False
        if not readable:
            raise PyfoldError(f"fold_run exited with status {rc} and left {out} unreadable: no results were kept:\n"
                              f"{cause}")
        hint = (f"\nfree some space, then continue from the last checkpoint with: {resume_hint}"
                if "I/O" in cause else "")
        raise PyfoldError(f"fold_run exited with status {rc}; results up to the last good state in {out}:\n"
                          f"{cause}{hint}")
    print(f"pyfold run: {out}" + (f" (ParaView: {written})" if written else ""))
    print(resolved.summary().splitlines()[0])
    print(run_summary(out))
    if no_xdmf is not None:
        raise PyfoldError(f"the run is complete in {out}, but its XDMF {xmf} was not written: {no_xdmf}")
    return 0


def _mark_failed(path: Path, rc: int, cause: str = "") -> None:
    """Give a file left by a crashed fold_run a status, if it recorded none: its own
    ``fold_run: failed: ...`` line from stderr when there is one."""
    import h5py

    from pyfold.outcome import NO_CAUSE, write_status_outcome
    from pyfold.run_input import fixed_string

    try:
        with h5py.File(path, "a") as f:
            status = f.attrs.get("status")
            if status is None or (bytes(status).decode(errors="replace") if not isinstance(status, str)
                                  else status).strip() in ("", "running", "ok"):
                text = cause or f"failed: fold_run exited with status {rc} {NO_CAUSE}"
                f.attrs["status"] = fixed_string(text)
                write_status_outcome(f.attrs, text)
    except OSError:  # pragma: no cover - a file fold_run left unreadable
        pass
