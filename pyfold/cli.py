"""Command-line entry point: ``pyfold <command> ...``.

Each command lives in ``pyfold/commands/<name>.py`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``. Exit status: 0 success,
2 bad input (argument or scene; the message names the key and the allowed
range), 1 any other failure (solver blow-up, I/O), with the cause printed.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from pyfold import __version__
from pyfold.errors import InputError, PyfoldError

#: command name -> (module under pyfold.commands, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "main": ("main_job", "run the bundled default job: simulate, fit C_I, compare closures, write figures"),
    "validate": ("validate", "check a scene file completely and print it normalised"),
    "run": ("run", "run the direct simulation of a scene into an HDF5 run file"),
    "analyse": ("analyse", "fit C_I per closure and judge closures against a finished run's a4"),
    "demo": ("demo", "macro layer only: Folgar-Tucker per closure and a C_I fit on synthetic data"),
}

EXIT_OK, EXIT_FAILURE, EXIT_INPUT = 0, 1, 2


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


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or EXIT_OK)
    except InputError as exc:
        print(f"pyfold {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except PyfoldError as exc:
        print(f"pyfold {args.command}: failed: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
