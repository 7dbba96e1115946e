"""Command-line options that several ``pyfold`` sub-commands share, declared once."""
from __future__ import annotations

import argparse

#: Options that let a command read runs that did not finish or whose checksums fail
#: (``pyfold analyse``, ``pyfold report``): name -> help text. Both are off by default,
#: and the command then refuses such a run (exit 2, naming the cause).
RUN_TOLERANCE_OPTIONS = {
    "--allow-failed": ('use a run whose status is not "ok" (a blown-up or killed run) up to its last good '
                       "state, with a warning"),
    "--allow-damaged": ("use the intact part of a run file whose checksums fail (refused by default, exit 2 "
                        "naming the damaged datasets): records from the first damaged chunk on and other "
                        "damaged datasets are left out, with a warning naming them"),
}


def add_run_tolerance_options(parser: argparse.ArgumentParser) -> None:
    """Add :data:`RUN_TOLERANCE_OPTIONS` as on/off options (``args.allow_failed``,
    ``args.allow_damaged``)."""
    for name, text in RUN_TOLERANCE_OPTIONS.items():
        parser.add_argument(name, action="store_true", help=text)
