"""Orientation-model parameters for moulding codes, fitted to a run: ``pyfold analyse RUN.h5 --model ...``.

``--model ft|rsc|ard-rsc|iard|mrd`` (comma-separated for several) fits each model's
parameters to the run's ``a2(t)`` with :func:`pyfold.fit.fit_parameters`
(Levenberg-Marquardt through the ODE solve, linearised standard errors, bounds of
:data:`pyfold.fit.DEFAULT_BOUNDS`), for each closure of ``--closures`` (default here
``ibof``: a moulding code runs a closure, not the simulation's own ``a4``), under the
run's own velocity gradient and Jeffery shape factor ``xi`` (:func:`pyfold.run_results.open_run`).

Fitted parameters (:data:`MODEL_FITS`; ``--params`` names others):

* ``ft``: Folgar-Tucker ``C_I``;
* ``rsc``: ``C_I`` and the slow-down ``kappa`` (Wang, O'Gara & Tucker 2008);
* ``ard-rsc``: ``b1``, ``b3`` and ``kappa`` (Phelps & Tucker 2009), ``b2 = b4 = b5 = 0``:
  from one flow the five ``b`` are not separately determined (their fit errors say so
  when ``--params b1,b2,b3,b4,b5,kappa`` is asked for);
* ``iard``: ``C_I`` and ``C_M`` (Tseng, Chang & Hsu 2016);
* ``mrd``: ``C_I``, ``D2``, ``D3`` with ``D1 = 1`` (the scale of ``D`` is ``C_I``'s); in 2-D
  ``C_I``, ``D2`` (:data:`PLANAR_PARAMS`).

``--export FILE.json`` or ``FILE.toml`` writes them in the form moulding codes take
(:func:`pyfold.moulding_export.write_export`): per model and closure, each
parameter under its usual symbol with its standard error.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pyfold.errors import InputError

#: model option name -> (class name in pyfold.models, parameters fitted, fixed starting values)
MODEL_FITS: dict[str, tuple[str, tuple[str, ...], dict[str, float]]] = {
    "ft": ("FolgarTucker", ("ci",), {"ci": 1e-3}),
    "rsc": ("RSC", ("ci", "kappa"), {"ci": 1e-3, "kappa": 0.5}),
    "ard-rsc": ("ARDRSC", ("b1", "b3", "kappa"), {"b1": 1e-3, "b2": 0.0, "b3": 1e-3, "b4": 0.0, "b5": 0.0,
                                                  "kappa": 0.5}),
    "iard": ("IARD", ("ci", "cm"), {"ci": 1e-3, "cm": 0.5}),
    "mrd": ("MRD", ("ci", "d2", "d3"), {"ci": 1e-3, "d1": 1.0, "d2": 0.8, "d3": 0.15}),
}
#: Default fitted parameters that differ in 2-D (planar MRD has ``diag(D1, D2)`` only).
PLANAR_PARAMS: dict[str, tuple[str, ...]] = {"mrd": ("ci", "d2")}
#: Closure of the model fits when ``--closures`` is left at its default.
DEFAULT_MODEL_CLOSURE = "ibof"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--model``, ``--params`` and ``--export`` of ``pyfold analyse``."""
    parser.add_argument("--model", default=None, metavar="NAME[,NAME...]",
                        help="fit orientation models for moulding codes instead of C_I per closure: "
                             + "|".join(MODEL_FITS) + f" (with --closures, default {DEFAULT_MODEL_CLOSURE})")
    parser.add_argument("--params", default=None, metavar="P[,P...]",
                        help="with one --model: the parameters to fit (default: see docs/moulding.md)")
    parser.add_argument("--export", default=None, metavar="FILE.json|FILE.toml",
                        help="with --model: write the fitted parameters for moulding codes to FILE")


def check_models(text: str) -> tuple[str, ...]:
    """The model names of ``--model`` (InputError naming the bad ones and the allowed)."""
    names = tuple(dict.fromkeys(n.strip().lower() for n in text.split(",") if n.strip()))
    bad = [n for n in names if n not in MODEL_FITS]
    if not names or bad:
        raise InputError(f"--model: {', '.join(map(repr, bad)) or 'empty'}: allowed {', '.join(MODEL_FITS)} "
                         "(comma-separated)")
    return names


def check_params(text: str | None, models: tuple[str, ...]) -> tuple[str, ...] | None:
    """The parameter names of ``--params`` (one model only; each a float field of it)."""
    if text is None:
        return None
    if len(models) != 1:
        raise InputError(f"--params: applies to one --model, got {len(models)} ({', '.join(models)})")
    allowed = [*MODEL_FITS[models[0]][2], "xi"]
    names = tuple(dict.fromkeys(n.strip().lower() for n in text.split(",") if n.strip()))
    bad = [n for n in names if n not in allowed]
    if not names or bad:
        raise InputError(f"--params: {', '.join(map(repr, bad)) or 'empty'} for --model {models[0]}: allowed "
                         f"{', '.join(allowed)}")
    return names


@dataclass(frozen=True)
class ModelFit:
    """One model fitted with one closure."""

    model: str  # option name (MODEL_FITS)
    closure: str
    values: dict[str, float]  # every parameter of the model (fitted and fixed)
    fitted: tuple[str, ...]
    stderr: dict[str, float]  # fitted parameters only
    at_bound: dict[str, bool]
    residual_rms: float
    success: bool
    message: str


def fit_model(ds, model: str, closure: str, params: tuple[str, ...] | None = None) -> ModelFit:
    """Fit ``model`` (a :data:`MODEL_FITS` name) with ``closure`` to the run ``ds`` (from
    :func:`pyfold.run_results.open_run`: its ``velocity_gradient`` and ``xi`` attributes are used)."""
    import pyfold.models as models
    from pyfold.fit import fit_parameters

    cls_name, default_params, start = MODEL_FITS[model]
    if "xi" not in ds.attrs:
        raise InputError("--model: the run's families have different shape factors xi; a single-xi model "
                         "cannot describe it")
    dim = int(ds.sizes["i"])
    fields = dict(start)
    fields["xi"] = float(ds.attrs["xi"])
    instance = getattr(models, cls_name)(**fields, closure=closure if closure != "exact" else "ibof", dim=dim)
    if dim == 2:
        default_params = PLANAR_PARAMS.get(model, default_params)
    fitted = tuple(params or default_params)
    result = fit_parameters(ds, instance, params=fitted, closure=closure)
    values = {name: float(np.asarray(getattr(result.model, name))) for name in fields}
    return ModelFit(model=model, closure=closure, values=values, fitted=fitted,
                    stderr={k: float(v) for k, v in result.stderr.items()},
                    at_bound={k: bool(v) for k, v in result.at_bound.items()},
                    residual_rms=float(result.residual_rms), success=bool(result.success), message=result.message)


def describe(fit: ModelFit) -> str:
    """One line: model, closure, each fitted value ± its error (bounds marked), fixed values."""
    parts = []
    for name in fit.fitted:
        mark = " (on its bound)" if fit.at_bound.get(name) else ""
        err = fit.stderr.get(name, float("nan"))
        # a parameter the records do not constrain (e.g. iARD's C_M once C_I sits on 0)
        # has no finite linearised error
        error = f"± {err:.2g}" if np.isfinite(err) else "(not determined by the records)"
        parts.append(f"{name} = {fit.values[name]:.4g} {error}{mark}")
    fixed = [f"{k} = {v:.4g}" for k, v in fit.values.items() if k not in fit.fitted]
    status = "" if fit.success else f"  FIT FAILED: {fit.message}"
    return (f"{fit.model} / {fit.closure}: " + ", ".join(parts) + (f"; fixed {', '.join(fixed)}" if fixed else "")
            + f"; rms residual {fit.residual_rms:.3g}{status}")


def run(args: argparse.Namespace, default_closures: str) -> int:
    """``pyfold analyse RUN.h5 --model ...``: check everything, fit, print, export."""
    from pyfold import run_checks
    from pyfold.files import regular_file
    from pyfold.moulding_export import check_export_path, run_source, write_export

    models = check_models(args.model)
    params = check_params(args.params, models)
    closures_text = DEFAULT_MODEL_CLOSURE if args.closures == default_closures else args.closures
    closures = run_checks.check_closures(closures_text)
    export = check_export_path(args.export) if args.export else None
    run_path = Path(args.run_file)
    regular_file(run_path, "RUN.h5")
    ds = run_checks.open_checked_run(run_path, allow_failed=args.allow_failed)  # the analyse checks
    closures = run_checks.check_closures(closures, dim=int(ds.sizes["i"]))
    fits = []
    for model in models:
        for closure in closures:
            fit = fit_model(ds, model, closure, params)
            print(f"pyfold analyse: {describe(fit)}", flush=True)
            fits.append(fit)
    if export is not None:
        write_export(export, fits, run_source(ds, run_path))
        print(f"pyfold analyse: parameters for moulding codes in {export}")
    failed = [f for f in fits if not f.success]
    if failed:
        print(f"pyfold analyse: {len(failed)} of {len(fits)} fits failed (see above)", file=sys.stderr)
        return 1
    return 0
