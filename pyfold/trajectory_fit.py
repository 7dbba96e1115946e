"""The C_I estimate of ``pyfold analyse``: trajectory fits of Folgar–Tucker to one run.

    run file ─► checks (:mod:`pyfold.run_checks`)
             ─► fit C_I of Folgar–Tucker per closure by trajectory fits through the ODE
                (and with the simulation's own a4)
             ─► closures judged against the simulation's a4
             ─► figures, a NetCDF of the results, a text summary

The trajectory fits run in :mod:`pyfold.fast_fit` (fixed-step RK4 on padded record
counts: one compiled program per closure and size class, kept by JAX's persistent
cache, so a second process fits a run in seconds). The main job and ``pyfold report``
use :mod:`pyfold.report` on an ensemble of runs: the same fit over the first Jeffery
periods of each run, beside rate regressions over the stationary part; both start from
the checks of :mod:`pyfold.run_checks`.

Why fit with several closures: the fitted ``C_I`` depends on the closure used
(docs/physics.md#the-fitted-c_i-depends-on-the-closure), so the table reports one value per closure, plus the value
obtained with the "exact" closure (the simulation's own ``a4``), which isolates
what the fibre–fibre interactions do from what a closure approximation does.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from pyfold.files import atomic_output
from pyfold.run_checks import (DEFAULT_CLOSURES, check_closures, check_described, open_checked_run, shape_factor_of,
                               velocity_gradient_of)


@dataclass
class ChainResult:
    """What :func:`fit_and_compare` produced."""

    run_path: Path
    fits: xr.Dataset
    closure_errors: xr.Dataset
    figures: list[Path] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)  # --force overrides, shown in every output


def fit_ci_per_closure(ds: xr.Dataset, L: np.ndarray, closures: Sequence[str], xi: float) -> xr.Dataset:
    """Fit Folgar–Tucker's ``C_I`` to the run's ``a2(t)`` once per closure.

    The trajectory fit over every record (:func:`pyfold.fast_fit.fit_ci_rk4`: the least
    squares of :func:`pyfold.fit.fit_parameters`, solved by fixed-step RK4 on padded
    shapes, so that the compiled programs are re-used across runs and processes).
    Returns a Dataset over ``closure`` with ``ci``, ``ci_stderr``, ``residual_rms``,
    ``success``, ``admissible``, ``inadmissible_time``, ``ci_step_error``, ``rk4_step``
    and the fitted ``a2_fit(closure, time, i, j)``. A fit whose trajectory leaves the
    orientation tensors has ``success = 0``, ``admissible = 0`` and ``ci`` NaN; its
    message in the ``fit_messages`` attribute names the record, step and cause.
    """
    from pyfold.fast_fit import fit_ci_rk4

    dim = ds.sizes["i"]
    t = np.asarray(ds["time"].values, dtype=np.float64)
    a2 = np.asarray(ds["a2"].values, dtype=np.float64)
    a4 = np.asarray(ds["a4"].values, dtype=np.float64) if "exact" in closures else None
    L = np.asarray(L, dtype=np.float64)[:dim, :dim]

    def fit(name):
        return fit_ci_rk4(name, t, a2, L, xi, a4=a4 if name == "exact" else None)

    # The fits are independent: on several cores they run (and, in a first process,
    # compile) side by side; JAX releases the interpreter lock while it compiles and runs.
    workers = min(len(closures), _cores())
    if workers > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers, thread_name_prefix="pyfold-fit") as pool:
            fits = list(pool.map(fit, closures))
    else:
        fits = [fit(name) for name in closures]
    out = xr.Dataset(
        {
            "ci": ("closure", [f.ci for f in fits], {"units": "1", "long_name": "fitted Folgar-Tucker C_I"}),
            "ci_stderr": ("closure", [f.stderr for f in fits], {"units": "1", "long_name": "standard error of C_I"}),
            "residual_rms": ("closure", [f.residual_rms for f in fits],
                             {"units": "1", "long_name": "RMS of a2 residuals at the optimum"}),
            "success": ("closure", np.array([f.success for f in fits], dtype=np.int8),
                        {"long_name": "fit converged on an admissible trajectory (1) or not (0)"}),
            "admissible": ("closure", np.array([f.admissible for f in fits], dtype=np.int8),
                           {"long_name": "fitted a2 stays in the orientation tensors (1) or leaves them (0; "
                                         "ci is then NaN, see fit_messages)"}),
            "inadmissible_time": ("closure", [f.inadmissible_time for f in fits],
                                  {"units": "s", "long_name": "first record time at which the fitted a2 leaves "
                                                              "the orientation tensors (NaN: never)"}),
            "ci_step_error": ("closure", [f.step_error for f in fits],
                              {"units": "1", "long_name": "estimated shift of C_I by the RK4 step (Richardson)"}),
            "rk4_step": ("closure", [f.step for f in fits],
                         {"units": "1", "long_name": "RK4 step of the fit, in units of 1/shear rate"}),
            "a2_fit": (("closure", "time", "i", "j"), np.stack([f.a2 for f in fits]),
                       {"units": "1", "long_name": "a2 of Folgar-Tucker at the fitted C_I"}),
        },
        coords={"closure": list(closures), "time": t},
    )
    out.attrs["xi"] = xi
    out.attrs["model"] = ("Folgar-Tucker (Folgar & Tucker 1984), C_I fitted over every record (fixed-step RK4, "
                          "pyfold.fast_fit), xi from the run's fibres")
    out.attrs["fit_messages"] = "; ".join(f"{f.closure}: {f.message}" for f in fits)
    return out


def fit_and_compare(run_path: Path, outdir: Path, closures: Sequence[str] = DEFAULT_CLOSURES,
                    quiet: bool = False, run: xr.Dataset | None = None, allow_failed: bool = False,
                    provenance=None, warnings: Sequence[str] = ()) -> ChainResult:
    """The macro half of the chain on a finished run: fits, closure test, figures.

    ``run``: the run already opened by :func:`open_checked_run` (else it is opened
    and checked here, with ``allow_failed``). Closure names are checked first.
    ``provenance`` (:class:`pyfold.provenance.Provenance`) and ``warnings`` are shown in
    the figures and the table.
    """
    closures = check_closures(closures)
    ds = run if run is not None else open_checked_run(run_path, allow_failed=allow_failed)
    closures = check_closures(closures, dim=ds.sizes["i"])
    L = velocity_gradient_of(run_path)
    xi = shape_factor_of(ds)
    seconds = {}
    judged = [c for c in closures if c != "exact"]
    # the closure errors do not depend on the fits: computed beside them
    from concurrent.futures import ThreadPoolExecutor

    def timed(key, fn, *args):
        t0 = time.perf_counter()
        out = fn(*args)
        seconds[key] = time.perf_counter() - t0
        return out

    with ThreadPoolExecutor(1, thread_name_prefix="pyfold-errors") as side:
        pending = side.submit(timed, "closure_errors", _closure_errors_padded, ds, judged, L)
        fits = timed("fit", fit_ci_per_closure, ds, L, closures, xi)
        errors = pending.result()
    result = ChainResult(run_path=run_path, fits=fits, closure_errors=errors, seconds=seconds,
                         warnings=list(warnings))
    t0 = time.perf_counter()
    notes = [provenance.line()] if provenance is not None else []
    result.figures = _figures(ds, fits, errors, L, outdir, notes + list(warnings))
    seconds["figures"] = time.perf_counter() - t0
    if not quiet:
        print("\n".join(notes + list(warnings) + [summary_table(fits, errors)]))
    return result


def _cores() -> int:
    """Cores this process may run on."""
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no sched_getaffinity (macOS)
        return max(1, os.cpu_count() or 1)


def _closure_errors_padded(ds: xr.Dataset, judged: Sequence[str], L: np.ndarray) -> xr.Dataset:
    """:func:`pyfold.closure_check.closure_errors` of the run's records, evaluated on the
    records padded (last record repeated) to the size class of :func:`pyfold.fast_fit.padded_size`,
    so that each closure's compiled evaluation is the same program for every run (the
    persistent cache keeps it); the padding is cut off and the time means recomputed."""
    from pyfold.closure_check import closure_errors
    from pyfold.fast_fit import padded_size

    n = ds.sizes["time"]
    extra = padded_size(n) - n
    a2 = np.asarray(ds["a2"].values, dtype=np.float64)
    a4 = np.asarray(ds["a4"].values, dtype=np.float64)
    t = np.asarray(ds["time"].values, dtype=np.float64)
    data = xr.Dataset({"a2": (("time", "i", "j"), np.concatenate([a2, np.repeat(a2[-1:], extra, axis=0)])),
                       "a4": (("time", "i", "j", "k", "l"), np.concatenate([a4, np.repeat(a4[-1:], extra, axis=0)]))},
                      coords={"time": np.concatenate([t, t[-1] + np.arange(1, extra + 1)])})
    errors = closure_errors(data, list(judged), velocity_gradient=L).isel(time=slice(0, n))
    errors["mean_error_full"] = errors["error_full"].mean("time")
    errors["mean_error_contracted"] = errors["error_contracted"].mean("time")
    return errors


def summary_table(fits: xr.Dataset, errors: xr.Dataset) -> str:
    """Plain-text table: C_I per closure and the closure's a4:D error against the run."""
    lines = [f"{'closure':<10} {'C_I':>11} {'± s.e.':>10} {'a2 RMS':>9} {'a4:D error':>11}"]
    for name in fits["closure"].values:
        ci = float(fits["ci"].sel(closure=name))
        se = float(fits["ci_stderr"].sel(closure=name))
        rms = float(fits["residual_rms"].sel(closure=name))
        err = (f"{float(errors['mean_error_contracted'].sel(closure=name)):11.2e}"
               if name in errors["closure"].values else f"{'(data)':>11}")
        admissible = int(fits["admissible"].sel(closure=name)) if "admissible" in fits else 1
        if not admissible:
            # no C_I: the fitted trajectory left the orientation tensors (fit_messages says where)
            t_bad = float(fits["inadmissible_time"].sel(closure=name))
            lines.append(f"{name:<10} {'failed':>11} {'':>10} {'':>9} {err}  (a2 left the admissible set "
                         f"at t = {t_bad:.4g} s)")
            continue
        flag = "" if int(fits["success"].sel(closure=name)) else "  (fit did not converge)"
        if not flag and ci <= 0.0:
            flag = "  (on its bound C_I >= 0: a bound, not a measurement)"
        lines.append(f"{name:<10} {ci:11.3e} {se:10.1e} {rms:9.1e} {err}{flag}")
    lines.append("a4:D error: time mean of ||(closure(a2) - a4):D|| / ||a4:D|| against the simulation's own a4")
    return "\n".join(lines)


def _save_figure(fig, path: Path) -> None:
    """Save with fixed margins, or grown to hold every text when one would be cut off
    (:func:`pyfold.plotting.clipped_texts`)."""
    from pyfold.plotting import clipped_texts

    tight = {"bbox_inches": "tight", "pad_inches": 0.05} if clipped_texts(fig) else {}
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=130, **tight)


def _figures(ds: xr.Dataset, fits: xr.Dataset, errors: xr.Dataset, L: np.ndarray, outdir: Path,
             notes: Sequence[str] = ()) -> list[Path]:
    import textwrap

    from matplotlib.figure import Figure

    from pyfold.plotting import closure_colour

    below = [textwrap.fill(n, 190) for n in notes]

    outdir.mkdir(parents=True, exist_ok=True)
    rate = float(np.sqrt(2.0 * np.sum((0.5 * (L + L.T)) ** 2))) or 1.0
    strain = np.asarray(ds["time"].values) * rate
    a2 = np.asarray(ds["a2"].values)
    paths = []

    # Fixed margins, not layout="constrained": the constrained layout measures every
    # text extent in extra draws, half the cost of the figures.
    fig = Figure(figsize=(10, 3.6 + 0.15 * len(below)))
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.14, top=0.88 - 0.035 * len(below), wspace=0.28)
    axes = fig.subplots(1, 3)
    for ax, (i, j) in zip(axes, [(0, 0), (1, 1), (0, 1)]):
        ax.plot(strain, a2[:, i, j], "k.", ms=3, label="direct simulation")
        for name in fits["closure"].values:
            curve = fits["a2_fit"].sel(closure=name).values[:, i, j]
            if "admissible" in fits and not int(fits["admissible"].sel(closure=name)):
                # drawn only up to the first record outside the admissible set, dotted,
                # and labelled as failed: it is not a fit
                t_bad = float(fits["inadmissible_time"].sel(closure=name))
                shown = np.asarray(ds["time"].values) <= t_bad
                ax.plot(strain[shown], curve[shown], ":", lw=1.0, color=closure_colour(str(name)),
                        label=f"FT {name}: failed, a2 inadmissible at γ̇t={t_bad * rate:.3g}")
                continue
            ax.plot(strain, curve, lw=1.2, color=closure_colour(str(name)),
                    label=f"FT {name}, trajectory-fitted C_I={float(fits['ci'].sel(closure=name)):.2g}")
        ax.set_xlabel("shear strain γ̇t")
        ax.set_ylabel(f"a{i + 1}{j + 1}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, frameon=False)
    fig.suptitle("\n".join(["Direct simulation vs Folgar–Tucker with the C_I fitted over every record "
                            f"(strain {strain[0]:.3g}–{strain[-1]:.3g}), per closure", *below]), fontsize=8)
    paths.append(outdir / "a2_dns_vs_fitted_ft.png")
    _save_figure(fig, paths[-1])

    fig = Figure(figsize=(10, 3.8 + 0.15 * len(below)))
    fig.subplots_adjust(left=0.08, right=0.99, bottom=0.22, top=0.88 - 0.035 * len(below), wspace=0.22)
    left, right = fig.subplots(1, 2)
    for name in errors["closure"].values:
        left.semilogy(strain, np.maximum(errors["error_contracted"].sel(closure=name).values, 1e-16), lw=1.2,
                      label=name, color=closure_colour(str(name)))
    left.set_xlabel("shear strain γ̇t")
    left.set_ylabel("||(closure(a2) − a4):D|| / ||a4:D||")
    left.grid(alpha=0.3, which="both")
    if len(errors["closure"]):
        left.legend(fontsize=7, frameon=False)
    names = list(fits["closure"].values)
    right.bar(range(len(names)), fits["ci"].values, yerr=fits["ci_stderr"].values, capsize=3,
              color=[closure_colour(str(n)) for n in names])
    for k, name in enumerate(names):
        if "admissible" in fits and not int(fits["admissible"].sel(closure=name)):
            # ci is NaN (no bar): say why at its place
            right.text(k, 0.0, "failed\n(a2 left the\nadmissible set)", ha="center", va="bottom", fontsize=7,
                       color="C3")
    right.set_xlim(-0.6, len(names) - 0.4)  # a NaN bar takes no room otherwise
    right.set_xticks(range(len(names)), names, rotation=30)
    right.set_ylabel("C_I (trajectory fit)")
    right.grid(alpha=0.3, axis="y")
    fig.suptitle("\n".join(["Closures against the simulation's own a4 (left); C_I per closure by trajectory fit "
                            "(right)", *below]), fontsize=8)
    paths.append(outdir / "closures_vs_dns.png")
    _save_figure(fig, paths[-1])
    return paths


#: Name of the C_I to use in analyse's results.nc (attribute ``recommended_ci``), as in the report's.
RECOMMENDED_CI = "ci_recommended"


def results_dataset(chain: ChainResult, provenance=None) -> xr.Dataset:
    """One Dataset with the fits (over ``closure``) and the closure errors (over
    ``judged_closure``: the data-driven "exact" closure is fitted, not judged).

    The trajectory-fitted C_I is ``ci_recommended`` (attribute ``recommended_ci``), every
    variable has ``long_name`` and ``units``, and the attributes name the physics model,
    resolution and strain range (``provenance``: :class:`pyfold.provenance.Provenance`)."""
    errors = chain.closure_errors.rename(closure="judged_closure")
    fits = chain.fits.rename(ci=RECOMMENDED_CI, ci_stderr=RECOMMENDED_CI + "_stderr")
    fits[RECOMMENDED_CI].attrs.update(long_name="Folgar-Tucker C_I by trajectory fit over every record (the C_I to "
                                      "use with that closure)", recommended="yes")
    out = xr.merge([fits, errors], join="outer", compat="override")
    out.attrs.update(format="pyfold.chain", format_version="2.0", run=str(Path(chain.run_path).resolve()),
                     recommended_ci=RECOMMENDED_CI, warnings=json.dumps(chain.warnings))
    if provenance is not None:
        out.attrs.update(provenance.attrs())
    return check_described(out)
