"""The front of the analysis chain, shared by ``pyfold analyse``, ``pyfold report`` and
``pyfold main``: the closure names, a run opened and checked for a C_I estimate, the
output folder, and the rule that every variable of a results file says what it is.

    run file ─► :func:`open_checked_run` (format, /setup, /initial, status, records are
                orientation tensors) ─► :func:`check_closures` (names, dimension)
             ─► an estimator: :mod:`pyfold.trajectory_fit` (one run, ``pyfold
                analyse``) or :mod:`pyfold.report` (an ensemble of runs, ``pyfold
                report`` and ``pyfold main``)
             ─► results.nc checked by :func:`check_described`, figures, summary
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from pyfold.errors import InputError, PyfoldError


#: Closures fitted and judged by default (a representative spread: the classic
#: hybrid, the two best orthotropic fits, the exact closure for Jeffery flows).
DEFAULT_CLOSURES: tuple[str, ...] = ("exact", "fec", "ibof", "orw3", "hybrid", "quadratic")


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


def default_closures(dim: int) -> tuple[str, ...]:
    """:data:`DEFAULT_CLOSURES` defined in dimension ``dim`` (in 2-D the
    orthotropic fits IBOF/ORW3 are not defined: the others are used instead of failing)."""
    from pyfold.closures import available

    return tuple(c for c in DEFAULT_CLOSURES if c == "exact" or c in available(dim))


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
    from pyfold.run_input import check_format
    from pyfold.run_results import open_run

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
        from pyfold.integrity import held_by_writer

        held = held_by_writer(run_path, exc)
        if held is not None:
            raise held from None
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


def velocity_gradient_of(run_path: Path) -> np.ndarray:
    """The imposed velocity gradient ``L_ij = ∂u_i/∂x_j`` [1/s] stored in a run file."""
    from pyfold.run_input import read_setup

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
