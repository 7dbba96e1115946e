"""``pyfold analyse RUN.h5``: fit C_I per closure and judge closures on a finished run.

Everything is checked before the fit starts (exit status 2, the message names the
cause): the closure names; the run file (a pyfold run with ``/setup`` and
``/initial``, at least two records, root ``status = "ok"`` unless
``--allow-failed``, every ``a2`` record an orientation tensor, a finite ``a4``,
every dataset matching its checksum unless ``--allow-damaged``: see
:func:`pyfold.run_results.open_run`); unless ``--force``, that the estimator applies (particles
with an orientation, a strain of at least one Jeffery period:
:func:`pyfold.provenance.applicability_problems`); and that ``--out`` can be created
and written. Without ``--closures``, the default closures defined in the run's
dimension are fitted (in 2-D those without IBOF/ORW3).

The fits are :func:`pyfold.trajectory_fit.fit_ci_per_closure` (fixed-step RK4 on padded
record counts, :mod:`pyfold.fast_fit`, one closure per core at a time): their programs
are kept, exported and compiled, in the per-user JAX cache (:mod:`pyfold._jax`), so only
the first analysis on a machine traces and compiles them.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from pyfold import model_fit
from pyfold.commands._options import add_run_tolerance_options
from pyfold.files import atomic_output, regular_file
from pyfold.run_checks import DEFAULT_CLOSURES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_file", metavar="RUN.h5", help="result of `pyfold run`")
    parser.add_argument("--out", default=None, help="folder for figures and results.nc (default: RUN_analysis/)")
    parser.add_argument("--closures", default=None,
                        help=f"comma-separated closures (default: {','.join(DEFAULT_CLOSURES)}, those defined in the "
                             "run's dimension)")
    parser.add_argument("--force", action="store_true",
                        help="fit even when the estimator does not apply: particles without orientation (spheres, "
                             "disks) or a strain shorter than one Jeffery period of the particles (refused by "
                             "default, exit 2); the outputs then carry the warning")
    add_run_tolerance_options(parser)  # --allow-failed, --allow-damaged
    model_fit.add_arguments(parser)  # --model, --params, --export: orientation models for moulding codes


def run(args: argparse.Namespace) -> int:
    from pyfold.integrity import tolerate_damage

    with tolerate_damage(getattr(args, "allow_damaged", False)):
        if getattr(args, "model", None) is not None:
            default = ",".join(DEFAULT_CLOSURES)
            if args.closures is None:  # left at its default: the model fit's own default closure
                args.closures = default
            return model_fit.run(args, default_closures=default)
        return _analyse(args)


def _analyse(args: argparse.Namespace) -> int:
    from pyfold import run_checks, trajectory_fit

    run_path = Path(args.run_file)
    regular_file(run_path, "RUN.h5")  # a folder, FIFO or device: refused before HDF5 opens it
    from pyfold import provenance

    closures = run_checks.check_closures(args.closures) if args.closures is not None else None
    ds = run_checks.open_checked_run(run_path, allow_failed=args.allow_failed)
    dim = ds.sizes["i"]
    closures = run_checks.check_closures(run_checks.default_closures(dim) if closures is None else closures, dim=dim)
    L = run_checks.velocity_gradient_of(run_path)
    xi = run_checks.shape_factor_of(ds)
    t = ds["time"].values
    warnings = provenance.enforce(provenance.applicability_problems(run_path, t, L, xi), args.force,
                                  "pyfold analyse")
    where = provenance.provenance_of(run_path, t, L, xi)
    out = Path(args.out) if args.out else run_path.with_name(run_path.stem + "_analysis")
    run_checks.check_output_folder(out)
    chain = trajectory_fit.fit_and_compare(run_path, out, closures=closures, run=ds, provenance=where, warnings=warnings)
    with atomic_output(out / "results.nc") as tmp:
        trajectory_fit.results_dataset(chain, where).to_netcdf(tmp, engine="h5netcdf")
    print(f"pyfold analyse: figures and results.nc in {out}")
    return 0
