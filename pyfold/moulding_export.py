"""Fitted orientation-model parameters in the form moulding codes take (JSON or TOML).

Written by ``pyfold analyse RUN.h5 --model ... --export FILE`` and ``pyfold fit-ci ...
--export FILE``; the suffix chooses the format (``.json`` or ``.toml``). Layout::

    format = "pyfold.orientation_parameters"
    format_version = "1.0"
    creator = "pyfold 0.x (git ...)"
    [source]            # where the numbers come from
    kind = "run" | "steady_a11"
    ...                 # run: file, physics (hydrodynamics_reason), dim, strain range, xi;
                        # steady_a11: a11, xi, flow
    [[fits]]
    model = "folgar-tucker" | "rsc" | "ard-rsc" | "iard" | "mrd"
    closure = "ibof"
    residual_rms = ...  # of the a2 fit (absent for fit-ci)
    [fits.parameters.C_I]
    value = ...
    stderr = ...        # linearised standard error (absent for fit-ci: an exact inversion)
    fitted = true       # false: held at the value shown
    at_bound = false

Symbols are the usual ones of the moulding literature and codes: Folgar-Tucker
``C_I``; RSC ``C_I``, ``kappa``; ARD-RSC ``b1`` ... ``b5``, ``kappa``; iARD ``C_I``,
``C_M``; MRD ``C_I``, ``D1``, ``D2``, ``D3``; every model also ``lambda`` (the shape
factor xi). The closure each fit used is part of it: a parameter set is valid
with that closure only.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pyfold.errors import InputError
from pyfold.files import atomic_output

if TYPE_CHECKING:
    from pyfold.model_fit import ModelFit

FORMAT = "pyfold.orientation_parameters"
FORMAT_VERSION = "1.0"
#: Export suffixes and their formats.
SUFFIXES = {".json": "json", ".toml": "toml"}
#: pyfold field name -> symbol in the export.
SYMBOLS = {"ci": "C_I", "kappa": "kappa", "b1": "b1", "b2": "b2", "b3": "b3", "b4": "b4", "b5": "b5",
           "cm": "C_M", "d1": "D1", "d2": "D2", "d3": "D3", "xi": "lambda"}
#: model option name -> model name in the export.
MODEL_NAMES = {"ft": "folgar-tucker", "rsc": "rsc", "ard-rsc": "ard-rsc", "iard": "iard", "mrd": "mrd"}


def check_export_path(text: str) -> Path:
    """``--export``: a new ``.json`` or ``.toml`` file in a folder that exists (InputError otherwise)."""
    path = Path(text)
    if path.suffix.lower() not in SUFFIXES:
        raise InputError(f"--export: {path} must end in {' or '.join(SUFFIXES)}, got {path.suffix or 'no suffix'!r}")
    if os.path.lexists(path):
        raise InputError(f"--export: {path} exists; remove it or choose another name (an export never "
                         "replaces a file)")
    if not path.parent.is_dir():
        raise InputError(f"--export: the folder {path.parent} does not exist")
    return path


def _number(x: float) -> float | str:
    """A finite float, or its text ("nan", "inf": JSON and TOML readers differ on those)."""
    x = float(x)
    return x if math.isfinite(x) else str(x)


def run_source(ds, run_path: Path) -> dict:
    """The ``[source]`` table of fits to a run: file, physics, strain range, xi."""
    t = np.asarray(ds["time"].values, dtype=float)
    rate = float(ds.attrs.get("shear_rate", float("nan")))
    return {"kind": "run", "file": str(run_path), "physics": str(ds.attrs.get("hydrodynamics_reason", "")),
            "dim": int(ds.sizes["i"]), "strain_start": _number(rate * t[0]), "strain_end": _number(rate * t[-1]),
            "records": int(t.size), "xi": _number(ds.attrs.get("xi", float("nan")))}


def fit_entry(fit: ModelFit) -> dict:
    """One ``[[fits]]`` entry of a model fit."""
    params = {}
    for name, value in fit.values.items():
        entry = {"value": _number(value), "fitted": name in fit.fitted}
        if name in fit.fitted:
            entry["stderr"] = _number(fit.stderr.get(name, float("nan")))
            entry["at_bound"] = bool(fit.at_bound.get(name, False))
        params[SYMBOLS.get(name, name)] = entry
    return {"model": MODEL_NAMES[fit.model], "closure": fit.closure, "success": fit.success,
            "residual_rms": _number(fit.residual_rms), "parameters": params}


def document(fits: list[dict], source: dict) -> dict:
    """The whole export (see the module docstring)."""
    from pyfold.run_input import creator

    return {"format": FORMAT, "format_version": FORMAT_VERSION, "creator": creator(), "source": source,
            "fits": fits}


def write_document(path: Path, doc: dict) -> None:
    """Write ``doc`` as JSON or TOML by ``path``'s suffix (atomically: never half-written)."""
    kind = SUFFIXES[path.suffix.lower()]
    if kind == "json":
        text = json.dumps(doc, indent=2) + "\n"
    else:
        import tomli_w

        text = tomli_w.dumps(doc)
    with atomic_output(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")


def write_export(path: Path, fits: list[ModelFit], source: dict) -> None:
    """Export model fits (``pyfold analyse --model ... --export``)."""
    write_document(path, document([fit_entry(f) for f in fits], source))


def read_export(path: Path) -> dict:
    """Read an export back (JSON or TOML by suffix)."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    if SUFFIXES.get(path.suffix.lower()) == "toml":
        import tomllib

        return tomllib.loads(text)
    return json.loads(text)
