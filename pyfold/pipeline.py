"""The multi-scale chain of ``pyfold analyse``, and the checks every consumer of a run shares.

    scene ─► direct simulation (fold_run) ─► a2(t), a4(t)
          ─► fit C_I of Folgar–Tucker per closure by trajectory fits through the ODE
             (and with the simulation's own a4)
          ─► closures judged against the simulation's a4
          ─► figures, a NetCDF of the results, a text summary

The trajectory fits run in :mod:`pyfold.fast_fit` (fixed-step RK4 on padded record
counts: one compiled program per closure and size class, kept by JAX's persistent
cache, so a second process fits a run in seconds). The main job and ``pyfold report``
use :mod:`pyfold.report` instead (rate regressions over the stationary part of an
ensemble of long runs, with the closures' a4 or the run's own); both
share :func:`run_scene`, :func:`open_checked_run`, :func:`check_closures` and the
run readers here.

Why fit with several closures: the fitted ``C_I`` depends on the closure used
(docs/physics.md#the-fitted-c_i-depends-on-the-closure), so the table reports one value per closure, plus the value
obtained with the "exact" closure (the simulation's own ``a4``), which isolates
what the fibre–fibre interactions do from what a closure approximation does.
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from pyfold.errors import InputError, PyfoldError
from pyfold.files import atomic_output

#: Closures fitted and judged by default (a representative spread: the classic
#: hybrid, the two best orthotropic fits, the exact closure for Jeffery flows).
DEFAULT_CLOSURES: tuple[str, ...] = ("exact", "fec", "ibof", "orw3", "hybrid", "quadratic")

#: Folgar–Tucker starting guess of C_I for every fit (order of the published
#: values, docs/physics.md#published-c_i-values); bounds C_I >= 0 come from pyfold.fit.
CI_START = 1e-3

#: Per-record solver diagnostics of a Stokes run that the summary reports; each is a
#: variable fold_run writes (``fortran/io/fold_output.f90``; a test checks the names
#: against a real run, so a renamed record cannot drop out of the summary unseen).
STOKES_SUMMARY_RECORDS: tuple[str, ...] = ("stokes_iterations", "stokes_residual", "rigidity_max")


@dataclass
class ChainResult:
    """What :func:`fit_and_compare` produced."""

    run_path: Path
    fits: xr.Dataset
    closure_errors: xr.Dataset
    figures: list[Path] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)  # --force overrides, shown in every output


def check_closures(closures: str | Sequence[str], dim: int | None = None) -> tuple[str, ...]:
    """The closure names of ``--closures``, checked before any work (simulation or fit).

    ``closures`` is the comma-separated text of the option or a sequence of names.
    Every name must be ``"exact"`` (the run's own a4) or a registered closure
    (:data:`pyfold.closures.CLOSURES`, case-insensitive); with ``dim``, one defined in
    that dimension. Returns the names, stripped, lower-case, each once, in order.
    The one rule for closure names of ``pyfold analyse`` and ``pyfold main``.

    Raises
    ------
    InputError
        ``--closures: ...`` naming the bad names and the allowed ones.
    """
    from pyfold.closures import CLOSURES, NOT_PROVIDED, available

    items = closures.split(",") if isinstance(closures, str) else list(closures)
    names = tuple(dict.fromkeys(str(c).strip().lower() for c in items if str(c).strip()))
    if not names:
        raise InputError("--closures: give at least one closure name")
    for name in names:
        if name in NOT_PROVIDED:
            raise InputError(f"--closures: {name!r}: {NOT_PROVIDED[name]}")
    known = ("exact", *sorted(CLOSURES)) if dim is None else ("exact", *available(dim))
    unknown = [n for n in names if n not in known]
    if unknown:
        where = "" if dim is None else f" in {dim}-D"
        kind = "unknown closure" if all(n not in CLOSURES for n in unknown) else "closure not defined"
        raise InputError(f"--closures: {kind}{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}"
                         f"{where}; allowed{where}: {', '.join(known)}")
    return names


#: Variables of /setup/resolved and /initial the fit needs (beyond the records).
_SETUP_NEEDED = ("dim", "velocity_gradient", "family_names")


def orientation_tolerance(dtype, n_particles: int) -> float:
    """Admissible deviation of a recorded ``a2 = <p p>`` from an orientation tensor.

    The mean of ``n`` unit dyads in floating point of precision ``eps`` has its trace
    within ``n eps`` of 1 (summation round-off, worst case) and eigenvalues no lower
    than about that below 0; ten times that, and never below ``1e-10``.
    """
    eps = float(np.finfo(np.dtype(dtype) if np.issubdtype(np.dtype(dtype), np.floating) else np.float64).eps)
    return max(1e-10, 10.0 * max(int(n_particles), 1) * eps)


def check_orientation_records(a2: np.ndarray, times: np.ndarray, n_particles: int, source: str = "a2") -> None:
    """Refuse records that are not orientation tensors: finite, symmetric, trace 1 and
    positive semi-definite within :func:`orientation_tolerance`; names the first bad
    record (index and time) and what is wrong with it."""
    a2 = np.asarray(a2)
    tol = orientation_tolerance(a2.dtype, n_particles)
    values = a2.astype(np.float64)
    finite = np.all(np.isfinite(values), axis=(1, 2))
    safe = np.where(finite[:, None, None], values, np.eye(values.shape[-1]) / values.shape[-1])
    asym = np.max(np.abs(safe - np.swapaxes(safe, 1, 2)), axis=(1, 2))
    trace = np.trace(safe, axis1=1, axis2=2)
    low = np.linalg.eigvalsh(0.5 * (safe + np.swapaxes(safe, 1, 2))).min(axis=1)
    bad = ~finite | (asym > tol) | (np.abs(trace - 1.0) > tol) | (low < -tol)
    if not np.any(bad):
        return
    k = int(np.flatnonzero(bad)[0])
    if not finite[k]:
        why = "contains NaN or infinity"
    elif asym[k] > tol:
        why = f"is not symmetric (|a_ij - a_ji| up to {asym[k]:.3g})"
    elif abs(trace[k] - 1.0) > tol:
        why = f"has trace {trace[k]:.12g}, not 1"
    else:
        why = f"is not positive semi-definite (smallest eigenvalue {low[k]:.3g})"
    raise InputError(f"{source}: record {k} (t = {float(times[k]):.6g}) {why}: not an orientation tensor <p p> "
                     f"(tolerance {tol:.2g} for {n_particles} particles in {a2.dtype} records); the run file is "
                     "damaged or was not written by fold_run, refusing to fit it")


def open_checked_run(run_path: Path, allow_failed: bool = False, command: str = "pyfold analyse") -> xr.Dataset:
    """Open a run for the C_I fit, refusing what cannot be fitted meaningfully.

    Refused (:class:`InputError`): not a run file, no ``/setup`` (or an incomplete
    one), no ``/initial``, fewer than two whole records of ``a2``/``a4``, an outcome
    other than ``completed`` (status ``"ok"``; :mod:`pyfold.outcome`) unless
    ``allow_failed`` (then a loud warning on stderr and only the records up to the last
    good state, ``steps_done``), and any
    record of ``a2`` that is not an orientation tensor (:func:`check_orientation_records`)
    or an ``a4`` that is not finite. ``command`` names the caller in the warning.
    """
    import h5py

    from pyfold.outcome import outcome_of
    from pyfold.run_file import check_format
    from pyfold.runs import open_run

    run_path = Path(run_path)
    try:
        with h5py.File(run_path, "r") as f:
            check_format(f, run_path)
            setup = f.get("setup")
            if not isinstance(setup, h5py.Group) or not isinstance(setup.get("resolved"), h5py.Group):
                raise InputError(f"{run_path}: no /setup/resolved group: the scene and its resolved values are "
                                 "missing (not written by `pyfold run`, or damaged); nothing to fit against")
            missing = [k for k in ("scene_toml", "scene_json") if k not in setup]
            missing += [f"resolved/{k}" for k in _SETUP_NEEDED if k not in setup["resolved"]]
            if missing:
                raise InputError(f"{run_path}: /setup is incomplete, missing {', '.join('/setup/' + m for m in missing)}")
            if not isinstance(f.get("initial"), h5py.Group) or "xi" not in f["initial"]:
                raise InputError(f"{run_path}: no /initial/xi (the particles' Jeffery shape factor the fit needs)")
    except (OSError, RuntimeError, KeyError, ValueError, IndexError, TypeError) as exc:  # damaged metadata
        raise InputError(f"{run_path}: damaged: cannot read it as a run file: {' '.join(str(exc).split())}") from None

    ds = open_run(run_path)
    status = ds.attrs.get("status")
    outcome = outcome_of(ds.attrs)
    if "a2" not in ds or "a4" not in ds or "time" not in ds.dims:
        raise InputError(f"{run_path}: no records (no a2/a4 over time): fold_run wrote no results (status "
                         f"{status!r}); nothing to fit")
    if outcome is None or not outcome.completed:
        if not allow_failed:
            raise InputError(f"{run_path}: the run did not finish: status {status!r}. Its records end at the "
                             "failure and may be wrong before it; refusing to fit them (give --allow-failed to fit "
                             "the records up to the last good state anyway)")
        steps = ds.attrs.get("steps_done")
        dt = ds.attrs.get("dt")
        if steps is not None and dt is not None:
            t_good = float(steps) * float(dt)
            keep = np.asarray(ds["time"].values) <= t_good * (1.0 + 1e-9) + 1e-300
            ds = ds.isel(time=np.flatnonzero(keep))
        else:
            t_good = float("nan")
        print(f"{command}: WARNING: {run_path} did not finish (status {status!r}); --allow-failed: fitting only "
              f"the {ds.sizes['time']} records up to the last good state (step {steps}, t = {t_good:.6g}). "
              "The fitted C_I describes a run that blew up: treat it with suspicion.", file=sys.stderr)
    n_records = ds.sizes.get("time", 0)
    if n_records < 2:
        raise InputError(f"{run_path}: {'no records' if n_records == 0 else 'only one record'} of a2 over time "
                         f"(status {status!r}): fitting C_I needs at least 2")
    n_particles = ds.sizes.get("particle", 0) or int(np.sum(ds.attrs.get("family_count", 0)))
    check_orientation_records(ds["a2"].values, ds["time"].values, n_particles, source=f"{run_path}: a2")
    if not np.all(np.isfinite(ds["a4"].values)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(ds["a4"].values.reshape(n_records, -1)), axis=1))[0])
        raise InputError(f"{run_path}: a4: record {bad} (t = {float(ds['time'].values[bad]):.6g}) contains NaN or "
                         "infinity; refusing to fit")
    return ds


def check_output_folder(out: Path) -> Path:
    """Make sure the results folder ``--out`` can be written, before any fitting:
    create it (with its parents) and write and remove a probe file in it."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: must be a folder, got the file {out}")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out: cannot create the folder {out}: {exc.strerror or exc}") from exc
    try:
        with tempfile.NamedTemporaryFile(dir=out, prefix=".pyfold-write-test-"):
            pass
    except OSError as exc:
        raise InputError(f"--out: cannot write in the folder {out}: {exc.strerror or exc}") from exc
    return out


def run_scene(scene: Path, out: Path, ranks: int = 1, log=None):
    """Run a scene with the direct simulation (``pyfold run``); returns the result file.

    With ``log`` (a file open for writing), ``pyfold run`` is started instead as a child
    Python process in its own session, its output going to ``log``, and the
    :class:`subprocess.Popen` is returned at once: the caller waits for it and stops it
    (SIGTERM: ``pyfold run`` then stops its fold_run and keeps the partial file). The
    main job runs its seeds this way, several at a time.
    """
    if log is not None:
        import subprocess

        argv = [sys.executable, "-m", "pyfold.cli", "run", str(scene), "-o", str(out), "--np", str(ranks)]
        return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
    from pyfold.cli import main as cli_main

    argv = ["run", str(scene), "-o", str(out), "--np", str(ranks)]
    status = cli_main(argv)
    if status == 2:
        raise InputError(f"scene {scene} was rejected (see the message above)")
    if status != 0:
        raise PyfoldError(f"the direct simulation of {scene} failed (status {status}); partial results in {out}")
    return out


def velocity_gradient_of(run_path: Path) -> np.ndarray:
    """The imposed velocity gradient ``L_ij = ∂u_i/∂x_j`` [1/s] stored in a run file."""
    from pyfold.run_file import read_setup

    G = np.asarray(read_setup(run_path).resolved["velocity_gradient"], dtype=np.float64)
    return G


def shape_factor_of(ds: xr.Dataset) -> float:
    """The single Jeffery shape factor ξ of the run's fibres (one family required)."""
    xi = np.unique(np.round(np.asarray(ds["particle_xi"].values), 12))
    if xi.size != 1:
        raise InputError(
            f"particle_xi: the C_I fit needs one fibre shape (one value of xi), the run has {xi.size}: {xi}"
        )
    return float(xi[0])


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
        return fit_ci_rk4(name, t, a2, L, xi, a4=a4 if name == "exact" else None, ci_start=CI_START)

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


def stokes_summary(run_path: Path) -> str:
    """Summary lines of a Stokes run: effective viscosity and solver records."""
    from pyfold.runs import open_run

    from pyfold.provenance import provenance_of

    ds = open_run(run_path)
    lines = [f"Stokes run {run_path.name}: status {ds.attrs.get('status', '?')}"]
    if "time" in ds.dims and ds.sizes["time"] > 1 and "particle_xi" in ds:
        xi = float(np.max(np.abs(np.asarray(ds["particle_xi"].values))))
        lines.append("  " + provenance_of(run_path, np.asarray(ds["time"].values), velocity_gradient_of(run_path),
                                          xi).line())
    if "effective_viscosity" in ds:
        eta = np.asarray(ds["effective_viscosity"].values)
        eta_f = float(ds.attrs.get("viscosity", 1.0))
        lines.append(f"  effective viscosity / fluid viscosity: mean {np.nanmean(eta) / eta_f:.4f} "
                     f"(min {np.nanmin(eta) / eta_f:.4f}, max {np.nanmax(eta) / eta_f:.4f})")
    missing = [name for name in STOKES_SUMMARY_RECORDS if name not in ds]
    if missing:
        raise PyfoldError(f"{run_path}: not a complete Stokes run file, records {missing} are missing")
    for name in STOKES_SUMMARY_RECORDS:
        values = np.asarray(ds[name].values)
        lines.append(f"  {name}: median {np.nanmedian(values):.3g}, max {np.nanmax(values):.3g}")
    return "\n".join(lines)


#: long_name and units of the variables and coordinates of ``pyfold analyse``'s results.nc
#: that the fit and the closure check leave undescribed.
_DESCRIPTIONS: dict[str, tuple[str, str]] = {
    "closure": ("closure of Folgar-Tucker ('exact': the run's own a4)", ""),
    "judged_closure": ("closure judged against the run's own a4", ""),
    "time": ("time of the run's records", "s"),
    "i": ("first index of a2 (x flow, y gradient, z vorticity)", ""),
    "j": ("second index of a2", ""),
    "k": ("third index of a4", ""),
    "l": ("fourth index of a4", ""),
    "component": ("component (i, j) of the error (f(a2) - a4):D", ""),
    "success": ("fit converged on an admissible trajectory (1) or not (0)", "1"),
    "admissible": ("fitted a2 stays in the orientation tensors (1) or leaves them (0; the C_I is then NaN)", "1"),
    "mean_error_full": ("time mean of ||f(a2) - a4||_F / ||a4||_F", "1"),
    "mean_error_contracted": ("time mean of ||(f(a2) - a4):D||_F / ||a4:D||_F", "1"),
}


def check_described(ds: xr.Dataset) -> xr.Dataset:
    """Fill ``long_name``/``units`` from :data:`_DESCRIPTIONS` where missing, then make sure
    every variable and coordinate has both (a results file must say what each number is)."""
    for name, var in ds.variables.items():
        if name in _DESCRIPTIONS:
            long_name, units = _DESCRIPTIONS[name]
            var.attrs.setdefault("long_name", long_name)
            var.attrs.setdefault("units", units)
    missing = [str(n) for n, v in ds.variables.items() if "long_name" not in v.attrs or "units" not in v.attrs]
    if missing:
        raise PyfoldError(f"results: variables without long_name/units: {', '.join(missing)} (a defect of pyfold)")
    return ds


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
