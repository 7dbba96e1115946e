"""Command-line entry point: ``pyfold <command> ...``.

Each command lives in ``pyfold/commands/<name>.py`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``. Exit status: 0 success,
2 bad input (argument or scene; the message names the key and the allowed
range), 1 any other failure (solver blow-up, I/O, a library that cannot be loaded
for lack of memory under ``ulimit -v``: :mod:`pyfold.memory`), with the cause
printed; interrupted: 130 (SIGINT, Ctrl-C), 143 (SIGTERM), 129 (SIGHUP), i.e. 128 + the
signal number. While a command runs, these three signals raise
:class:`Interrupted` (a KeyboardInterrupt) in the main thread, so every command
cleans up on the way out (``pyfold run`` terminates its fold_run / mpirun process
group and keeps the partial run file for ``--resume``).
"""
from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import signal
import sys
import threading
import warnings

from pyfold import __version__
from pyfold.errors import InputError, PyfoldError, PyfoldWarning
# Imported now, while memory lasts: it explains a library that could not be loaded for lack of it
from pyfold.memory import describe_load_failure

#: command name -> (module under pyfold.commands, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "main": ("main_job", "run the bundled default job: simulate an ensemble of seeds, report C_I per closure, "
                         "steady state, correlations and the closure ranking"),
    "validate": ("validate", "check a scene file completely and print it normalised"),
    "run": ("run", "run the direct simulation of a scene into an HDF5 run file"),
    "analyse": ("analyse", "fit C_I per closure and judge closures against a finished run's a4"),
    "fit-ci": ("fit_ci", "Folgar-Tucker C_I from a measured steady A11 in simple shear (Tucker's FitCI)"),
    "report": ("report", "C_I per closure with errors, steady state, correlations and closure ranking for a run "
                         "or an ensemble of seeds"),
    "sweep": ("sweep", "run a sweep of scenes (axes x seeds) locally or on Slurm, follow it, gather it into "
                       "one dataset"),
    "demo": ("demo", "macro layer only: Folgar-Tucker per closure and a C_I fit on synthetic data"),
}

EXIT_OK, EXIT_FAILURE, EXIT_INPUT = 0, 1, 2

#: Signals turned into :class:`Interrupted` while a command runs.
HANDLED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class Interrupted(KeyboardInterrupt):
    """A command was interrupted by a signal (``signum``); exit status 128 + signum."""

    def __init__(self, signum: int):
        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.signum = signum


_depth = 0  # nested main() calls (pyfold main runs `pyfold run` through main())


@contextlib.contextmanager
def _signals_raise():
    """Make SIGINT, SIGTERM and SIGHUP raise Interrupted (once: a second signal while
    the first is being handled is ignored, so the clean-up finishes), then restore
    the previous handlers. Only in the main thread of the outermost main()."""
    if _depth > 1 or threading.current_thread() is not threading.main_thread():
        yield
        return
    raised = []

    def handler(signum, frame):
        if raised:
            return
        raised.append(signum)
        raise Interrupted(signum)

    previous = {}
    for sig in HANDLED_SIGNALS:
        try:
            previous[sig] = signal.signal(sig, handler)
        except (ValueError, OSError):  # pragma: no cover
            pass
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old if old is not None else signal.SIG_DFL)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pyfold", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"pyfold {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        command = importlib.import_module(f"pyfold.commands.{module}")
        command_parser = sub.add_parser(name, help=help_text, description=help_text)
        command.add_arguments(command_parser)
        command_parser.set_defaults(_run=command.run)
    return parser


@contextlib.contextmanager
def _plain_warnings(command: str):
    """pyfold's own warnings (a trajectory leaving the orientation tensors, an
    eigenvalue crossing, ...) as one line each, ``pyfold CMD: warning: ...``, instead of
    Python's file:line form: they are messages to the user, not to a programmer."""
    original = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, PyfoldWarning):
            print(f"pyfold {command}: warning: {message}", file=sys.stderr if file is None else file)
        else:
            original(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = original


def _load_failure(exc: BaseException) -> bool:
    """An ImportError or MemoryError, or an OSError for want of memory: the import machinery
    meets ENOMEM as an OSError too (listing a package's folder under a low ``ulimit -v``)."""
    return not isinstance(exc, OSError) or exc.errno == errno.ENOMEM


def main(argv: list[str] | None = None) -> int:
    global _depth
    try:
        parser = build_parser()  # imports every command module, and with them numpy, xarray, ...
    except (ImportError, MemoryError, OSError) as exc:
        if not _load_failure(exc):
            raise
        words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
        command = words[0] if words and words[0] in COMMANDS else None
        print(f"pyfold{' ' + command if command else ''}: failed: {describe_load_failure(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    args = parser.parse_args(argv)
    _depth += 1
    try:
        with _signals_raise(), _plain_warnings(args.command):
            return int(args._run(args) or EXIT_OK)
    except InputError as exc:
        print(f"pyfold {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except PyfoldError as exc:
        print(f"pyfold {args.command}: failed: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except (ImportError, MemoryError, OSError) as exc:  # commands import numpy, JAX, h5py, ... lazily
        if _depth > 1 or not _load_failure(exc):
            raise
        print(f"pyfold {args.command}: failed: {describe_load_failure(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt as exc:
        if _depth > 1:  # the outer command cleans up and sets the status
            raise
        signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
        print(f"pyfold {args.command}: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
        return 128 + int(signum)
    finally:
        _depth -= 1


if __name__ == "__main__":  # pragma: no cover
    from pyfold.cli import main as _main  # the one module instance nested commands (pyfold main) call too

    sys.exit(_main())
