"""``pyfold demo``: the macro layer alone (Folgar–Tucker per closure, C_I fit on synthetic data)."""
from __future__ import annotations

import argparse
from pathlib import Path

from pyfold.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/demo", help="folder for figures and data (default: out/demo)")


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: must be a folder, got the file {out}")
    from pyfold import demo

    demo.main(out)
    return 0
