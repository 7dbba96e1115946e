"""``pyfold fit-ci --a11 A11 (--beta BETA | --xi XI) [--closure NAME] [--export FILE]``: Tucker's FitCI.

The Folgar-Tucker interaction coefficient ``C_I`` whose steady state in simple shear
``u = (gamma_dot y, 0, 0)`` has the measured flow-direction component ``A11``, with
the given closure (:func:`pyfold.fit.fit_ci_to_steady_a11`: Brent's method on the
steady ``a11(C_I)``, which falls monotonically in ``C_I``). This is Tucker's
``fitCI.m`` (Fiber Orientation Tools, companion to Tucker 2022, *Fundamentals of
Fiber Orientation*), whose example gives ``A11 = 0.8261 -> C_I = 0.0054`` with IBOF
and ``xi = 1``. The steady state does not depend on the shear rate.

The shape factor is ``--xi`` directly, or ``xi = (beta^2 - 1)/(beta^2 + 1)`` from
the aspect ratio ``--beta`` (a slender fibre: ``beta >> 1``, ``xi -> 1``; Tucker's
example uses ``xi = 1``). ``--export`` writes the result as moulding codes take it
(:mod:`pyfold.moulding_export`).

Exit status 2 (naming the option and its range): ``A11`` outside (0.34, 0.99), an
aspect ratio <= 0, ``xi`` outside [-1, 1], an unknown closure or one not defined in
3-D, an ``A11`` the closure cannot reach for ``C_I`` in the search bracket
(1e-3, 0.5) of :func:`pyfold.fit.fit_ci_to_steady_a11`.
"""
from __future__ import annotations

import argparse
import math

from pyfold.errors import InputError

#: Closure used when ``--closure`` is not given (Tucker's FitCI example).
DEFAULT_CLOSURE = "ibof"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--a11", type=float, required=True,
                        help="measured steady A11 in simple shear (flow direction), in (0.34, 0.99)")
    shape = parser.add_mutually_exclusive_group()
    shape.add_argument("--beta", type=float, default=None, help="fibre aspect ratio L/d (xi = (beta^2-1)/(beta^2+1))")
    shape.add_argument("--xi", type=float, default=None, help="shape factor lambda in [-1, 1] (default 1)")
    parser.add_argument("--closure", default=DEFAULT_CLOSURE, help="closure (default: %(default)s)")
    parser.add_argument("--export", default=None, metavar="FILE.json|FILE.toml",
                        help="write C_I for moulding codes to FILE (see docs/moulding.md)")


def shape_factor(beta: float | None, xi: float | None) -> float:
    """``xi`` from ``--beta`` or ``--xi`` (default 1), checked."""
    if beta is not None:
        if not (math.isfinite(beta) and beta > 0):
            raise InputError(f"--beta: must be a finite aspect ratio > 0, got {beta!r}")
        return (beta**2 - 1.0) / (beta**2 + 1.0)
    if xi is None:
        return 1.0
    if not (math.isfinite(xi) and -1.0 <= xi <= 1.0):
        raise InputError(f"--xi: must lie in [-1, 1], got {xi!r}")
    return float(xi)


def run(args: argparse.Namespace) -> int:
    from pyfold.closures import available
    from pyfold.fit import fit_ci_to_steady_a11, steady_state_a2
    from pyfold.kinematics import simple_shear
    from pyfold.models import FolgarTucker
    from pyfold.moulding_export import check_export_path, document, write_document

    xi = shape_factor(args.beta, args.xi)
    closure = args.closure.strip().lower()
    if closure not in available(3):
        raise InputError(f"--closure: {args.closure!r} is not a 3-D closure; allowed: {', '.join(available(3))}")
    export = check_export_path(args.export) if args.export else None
    try:  # it checks the range of A11 (the one bound, in pyfold.fit)
        ci = fit_ci_to_steady_a11(args.a11, closure, xi)
    except InputError as exc:
        raise InputError(f"--a11: {exc}") from None
    a2 = steady_state_a2(FolgarTucker(ci=ci, xi=xi, closure=closure), simple_shear(1.0))
    print(f"pyfold fit-ci: C_I = {ci:.6g} (Folgar-Tucker, closure {closure}, xi = {xi:.6g}): steady A11 = "
          f"{a2[0, 0]:.6f}, A22 = {a2[1, 1]:.6f}, A33 = {a2[2, 2]:.6f}, A12 = {a2[0, 1]:.6f} in simple shear")
    if export is not None:
        source = {"kind": "steady_a11", "flow": "simple shear u = (gamma_dot y, 0, 0), steady state",
                  "a11": float(args.a11), "xi": xi}
        if args.beta is not None:
            source["beta"] = float(args.beta)
        fit = {"model": "folgar-tucker", "closure": closure,
               "parameters": {"C_I": {"value": ci, "fitted": True},
                              "lambda": {"value": xi, "fitted": False}}}
        write_document(export, document([fit], source))
        print(f"pyfold fit-ci: written to {export}")
    return 0
