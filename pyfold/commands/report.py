"""``pyfold report RUN.h5 [RUN2.h5 ...]``: the main job's report for any run or ensemble of runs.

The runs must be one scene apart from the seed (compared on the scene and resolved
values stored in each run's ``/setup``); each is checked as ``pyfold analyse``
checks it (:func:`pyfold.run_checks.open_checked_run`: status ``"ok"`` unless
``--allow-failed``, records that are orientation tensors, every dataset matching its
checksum unless ``--allow-damaged``, ...). Everything is
checked before any analysis, exit status 2 naming the file and the cause.

Output folder (``--out``, default ``<first run>_report/`` beside the first run,
as ``pyfold analyse`` defaults to ``RUN_analysis/``): created if missing; a folder
that already holds report files is refused unless ``--force`` replaces them. The
files are assembled in a hidden folder and moved in when complete
(:func:`pyfold.report.write_report`). The folder is locked for the report's life
(``DIR.lock`` beside it, :mod:`pyfold.destination`): a second ``pyfold report`` or
``pyfold main`` with the same ``--out`` is refused (exit 2) naming the holder.
"""
from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from pyfold.errors import InputError
from pyfold.run_checks import DEFAULT_CLOSURES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_files", metavar="RUN.h5", nargs="+",
                        help="results of `pyfold run`: one run, or several seeds of one scene")
    parser.add_argument("--out", default=None,
                        help="folder for the figures, results.nc and summary (default: <first RUN>_report/)")
    parser.add_argument("--closures", default=None,
                        help="comma-separated closures; 'exact' is the runs' own a4 (default: "
                             f"{','.join(DEFAULT_CLOSURES)}, those defined in the runs' dimension)")
    parser.add_argument("--allow-failed", action="store_true",
                        help="use runs whose status is not \"ok\" up to their last good state, with a warning")
    parser.add_argument("--force", action="store_true",
                        help="replace the report files already in --out; and report on runs the estimators do not "
                             "fit (particles without orientation, strain shorter than one Jeffery period: refused "
                             "by default, exit 2), the outputs then carrying the warning")
    parser.add_argument("--allow-damaged", action="store_true",
                        help="use the intact part of run files whose checksums fail (refused by default, exit 2 "
                             "naming the damaged datasets), with a warning naming them")


def run(args: argparse.Namespace) -> int:
    from pyfold.integrity import tolerate_damage

    with tolerate_damage(getattr(args, "allow_damaged", False)):
        return _report(args)


def _report(args: argparse.Namespace) -> int:
    from pyfold import report

    from pyfold.destination import acquire, make_parent

    paths = [Path(p) for p in args.run_files]
    if args.out == "":
        raise InputError("--out: empty path; name the report folder (or leave --out out for <first RUN>_report)")
    out = Path(args.out) if args.out else paths[0].with_name(paths[0].stem + "_report")
    make_parent(out, "--out")  # where its lock file goes (the folder itself is made by the report)
    with acquire(out, "--out", command="pyfold report ... --out " + shlex.quote(str(out))):
        rep, _ = report.report(paths, out, args.closures, allow_failed=args.allow_failed, force=args.force,
                               progress=lambda text: print(f"pyfold report: {text}", flush=True))
    print("\n".join(report.summary_lines(rep)))
    print(f"pyfold report: figures, results.nc and summary in {out}")
    return 0
