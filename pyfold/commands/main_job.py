"""``pyfold main``: the bundled default job of the README.

Every invocation writes a fresh, timestamped results folder under ``--out``
(``run-YYYYmmdd-HHMMSS``), assembled in a hidden temporary folder and renamed
into place only when complete, so an earlier result is never overwritten and
an interrupted job leaves no half-written folder. ``<out>/latest`` points to
the newest complete result.
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from pyfold.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/main", help="parent folder of the results (default: out/main)")


def run(args: argparse.Namespace) -> int:
    parent = Path(args.out)
    if parent.exists() and not parent.is_dir():
        raise InputError(f"--out: must be a folder (or not exist yet), got the file {parent}")
    parent.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("run-%Y%m%d-%H%M%S")
    final = parent / stamp
    suffix = 1
    while final.exists():
        suffix += 1
        final = parent / f"{stamp}-{suffix}"
    work = Path(tempfile.mkdtemp(prefix=".partial-", dir=parent))
    try:
        _job(work)
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


def _job(outdir: Path) -> None:
    """The job itself: until the direct simulation lands, the macro demo."""
    from pyfold import demo

    demo.main(outdir)
