"""Command lines that a shell runs exactly as given.

Study scripts write ``pyfold run`` commands for a batch scheduler (one command per
line, each line run by ``sh``), print commands for the user to copy, and record the
command that made an output file. Every such line is built here from an argument
list: :func:`shlex.join` quotes each argument, so a path holding spaces, quotes,
``;``, ``$(...)`` or backticks reaches the program as one argument, byte for byte,
and is never run as shell code.
"""
from __future__ import annotations

import os
import shlex
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

from pyfold.errors import InputError

#: Characters that end a line for ``sh``, ``sed -n Np`` and a scheduler's line-per-task
#: array: a job file holds one command per line, so no argument of a job may contain one.
LINE_BREAKS = ("\n", "\r")

Argument = str | os.PathLike


def path_argument(path: os.PathLike | str) -> str:
    """A path as a command-line argument that no option parser mistakes for an option.

    A relative path starting with ``-`` gets ``./`` in front (the same file);
    every other path is returned unchanged.
    """
    text = os.fspath(path)
    return "./" + text if text.startswith("-") else text


def command_line(argv: Iterable[Argument]) -> str:
    """The shell line that runs ``argv`` exactly.

    Parameters
    ----------
    argv : iterable of str or path-like
        The program and its arguments. Path-like items go through
        :func:`path_argument`; strings are taken as they are.

    Returns
    -------
    str
        ``shlex.join`` of the arguments: ``sh -c`` on it runs the program with
        exactly these arguments. An argument holding a line break is quoted
        correctly but spans lines; :func:`job_line` refuses it.
    """
    return shlex.join(path_argument(a) if isinstance(a, os.PathLike) else str(a) for a in argv)


def pyfold_executable() -> str:
    """The ``pyfold`` that generated lines call.

    The launcher beside the running interpreter (the venv's own), so that a batch
    job running a generated line needs no PATH set-up; where the interpreter has no
    launcher beside it (pyfold imported from a source tree), plain ``pyfold``, found
    on PATH when the line runs.
    """
    launcher = Path(sys.executable).parent / "pyfold"
    return str(launcher) if launcher.is_file() else "pyfold"


def check_single_line(option: str, path: os.PathLike | str) -> None:
    """Refuse a path that a job file of one command per line cannot hold.

    Raises
    ------
    InputError
        ``path`` contains a line break; the message names ``option``.
    """
    text = os.fspath(path)
    if any(c in text for c in LINE_BREAKS):
        raise InputError(f"{option}: {text!r} contains a line break; the generated job file holds one "
                         "command per line, so a path may hold any character except a line break (\\n, \\r)")


def job_line(args: Iterable[Argument]) -> str:
    """One line of a job file: ``pyfold`` (:func:`pyfold_executable`) with ``args``.

    Raises
    ------
    InputError
        An argument contains a line break (the line would be split into two jobs).
    """
    argv = [pyfold_executable(), *args]
    for a in argv:
        check_single_line("job argument", a)
    return command_line(argv)


def write_job_file(path: Path, lines: Iterable[str]) -> Path:
    """Write ``lines`` (from :func:`job_line`), one per line, to ``path``; returns ``path``."""
    path.write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return path


def git_revision(folder: os.PathLike | str) -> str:
    """The short hash of the git commit checked out at ``folder``, or ``"unknown"``
    outside a git checkout or without git: recorded beside the command line that made a
    study's output file."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(folder), check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
