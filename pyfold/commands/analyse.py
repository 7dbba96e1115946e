"""``pyfold analyse RUN.h5``: fit C_I per closure and judge closures on a finished run."""
from __future__ import annotations

import argparse
from pathlib import Path

from pyfold.errors import InputError
from pyfold.pipeline import DEFAULT_CLOSURES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_file", metavar="RUN.h5", help="result of `pyfold run`")
    parser.add_argument("--out", default=None, help="folder for figures and results.nc (default: RUN_analysis/)")
    parser.add_argument("--closures", default=",".join(DEFAULT_CLOSURES),
                        help="comma-separated closures (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    from pyfold import pipeline

    run_path = Path(args.run_file)
    if not run_path.is_file():
        raise InputError(f"RUN.h5: no such file: {run_path}")
    closures = tuple(c.strip() for c in args.closures.split(",") if c.strip())
    if not closures:
        raise InputError("--closures: give at least one closure name")
    out = Path(args.out) if args.out else run_path.with_name(run_path.stem + "_analysis")
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: must be a folder, got the file {out}")
    chain = pipeline.fit_and_compare(run_path, out, closures=closures)
    pipeline.results_dataset(chain).to_netcdf(out / "results.nc", engine="h5netcdf")
    print(f"pyfold analyse: figures and results.nc in {out}")
    return 0
