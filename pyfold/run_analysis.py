"""What the report measures on each run of an ensemble and across them (``pyfold report``, ``pyfold main``).

    run files ─► one scene apart from the seed (:func:`check_same_scene`)
              ─► per run (:func:`analyse_run`): stationary part (MSER-5 onset, drift
                 test), C_I by rate regression with the run's own a4 and with each
                 closure's a4; closure errors a4:D against the run's a4
                 (:func:`attach_closure_errors`)
              ─► across the runs: the closure ranking of one run
                 (:func:`rank_one_run`; several: :func:`pyfold.ensemble.rank_paired`),
                 effect sizes and equivalence (:func:`ranking_equivalence`), how far
                 Folgar-Tucker departs from the runs (:func:`ft_departure`), how the
                 state changes after the fit window (:func:`measure_redistribution`)

:mod:`pyfold.report` composes these with the trajectory fits of :mod:`pyfold.fast_fit`
into the report's outputs. Closures are evaluated on a fixed shape
(:data:`CLOSURE_RECORDS` records per run, thinned and padded): one compiled program per
closure, kept by JAX's persistent cache (:mod:`pyfold._jax`).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Sequence

import numpy as np
import xarray as xr

from pyfold.errors import InputError

#: Records per run on which closures are evaluated: a longer run is thinned to every
#: k-th record (the rate regression gives the same C_I at record spacings 0.1 to 0.5,
#: tests/cross/test_ci_methods.py), a shorter one padded; one compiled shape.
CLOSURE_RECORDS = 1024
#: Fewest records a stationary window must hold for the estimators (ci_rate_regression
#: needs 8 interior records; blocking errors need 16 samples).
MIN_WINDOW_RECORDS = 16
#: Significance level of the closure ranking (Holm-adjusted neighbour tests).
RANK_LEVEL = 0.05
#: Scene keys that may differ between the runs of one ensemble: the seed, and the
#: free texts (``title``/``description`` often name the seed).
SEED_KEYS = ("numerics.seed", "title", "description", "resolved/seed")
#: Resolved keys that explain the scene in prose (its warnings, why a model or a preset's
#: numerics were chosen): what they explain is recorded as resolved values, compared
#: key by key, and their wording may change between versions without changing the scene.
PROSE_KEYS = ("resolved/scene_warnings", "resolved/numerics_preset_reason", "resolved/hydrodynamics_reason")


# --------------------------------------------------------------------------- one scene


def scene_fingerprint(run_path: Path) -> dict[str, object]:
    """What makes the scene of a run: the normalised scene stored in ``/setup/scene_json``
    and every resolved value in ``/setup/resolved`` (``resolved/<name>``), without the
    seed and the free texts (:data:`SEED_KEYS`) and the prose that explains them
    (:data:`PROSE_KEYS`). The verbatim TOML is not compared (comments and layout may differ)."""
    from pyfold.fingerprint import setup_keys
    from pyfold.run_input import read_setup

    setup = read_setup(run_path)
    keys = setup_keys(setup.scene, setup.resolved)
    return {k: v for k, v in keys.items() if k not in SEED_KEYS and k not in PROSE_KEYS}


def _same(a, b) -> bool:
    if isinstance(a, float) or isinstance(b, float) or isinstance(a, list) or isinstance(b, list):
        try:
            x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
            return x.shape == y.shape and bool(np.all((x == y) | (np.isnan(x) & np.isnan(y))))
        except (TypeError, ValueError):
            return a == b
    return a == b


def check_same_scene(paths: Sequence[Path]) -> list[int]:
    """Refuse runs of different scenes; returns the seed of each run.

    Raises
    ------
    InputError
        Naming the first run that differs from the first one, the differing key
        (e.g. ``particles[0].count``) and both values; or two runs with the same seed
        (the same realisation twice would shrink the error bars falsely).
    """
    from pyfold.run_input import read_setup

    reference = scene_fingerprint(paths[0])
    for path in paths[1:]:
        other = scene_fingerprint(path)
        for key in sorted(set(reference) | set(other)):
            if key not in reference or key not in other or not _same(reference[key], other[key]):
                raise InputError(
                    f"{path}: a different scene than {paths[0]}: key {key!r} is "
                    f"{other.get(key, '<missing>')!r} there and {reference.get(key, '<missing>')!r} in {paths[0]} "
                    "(an ensemble must be one scene, only the seed may differ)")
    seeds = [int(read_setup(p).resolved["seed"]) for p in paths]
    for k, seed in enumerate(seeds):
        if seed in seeds[:k]:
            raise InputError(f"{paths[k]}: the same seed {seed} as {paths[seeds.index(seed)]}: the same realisation "
                             "twice is not an independent sample")
    return seeds


# --------------------------------------------------------------------------- per run


@dataclasses.dataclass
class RunAnalysis:
    """What the report measures on one run."""

    path: Path
    seed: int
    t: np.ndarray  # record times [s]
    a2: np.ndarray  # (nt, d, d)
    onset_time: float  # start of the stationary part (MSER-5, not inside the first Jeffery period; NaN: none) [s]
    stationary: bool
    steady_message: str
    window: tuple[float, float]  # times used by the estimators [s]
    ci: dict[str, float]  # closure name ("exact": the run's own a4) -> C_I
    ci_stderr: dict[str, float]
    error_t: np.ndarray  # closure errors' times (thinned records) [s]
    error_contracted: dict[str, np.ndarray]  # judged closure -> a4:D error at error_t
    error_mean: dict[str, float]  # time mean over the window
    error_stderr: dict[str, float]  # blocking s.e. of that mean
    drift: dict[str, tuple[float, float]]  # diagonal of a2: slope and s.e. over the last half of the window [1/s]
    thinned: tuple | None = None  # (a2, a4) at error_t, until the closure errors are computed


def _thin_pad(n: int) -> tuple[np.ndarray, int]:
    """Indices of at most CLOSURE_RECORDS records (every k-th, the last kept), and k."""
    k = max(1, math.ceil(n / CLOSURE_RECORDS))
    idx = np.arange(0, n, k)
    return idx, k


def _padded(x: np.ndarray) -> np.ndarray:
    """``x`` (n, ...) padded to CLOSURE_RECORDS rows by repeating its last row."""
    if len(x) == CLOSURE_RECORDS:
        return x
    return np.concatenate([x, np.repeat(x[-1:], CLOSURE_RECORDS - len(x), axis=0)])


_CLOSURE_JIT: dict[tuple[str, int], object] = {}


def closure_a4(name: str, a2: np.ndarray) -> np.ndarray:
    """``closure(a2)`` for (n <= CLOSURE_RECORDS) records, on the fixed padded shape."""
    from pyfold._jax import jax, jnp
    from pyfold.closures import get_closure

    d = a2.shape[-1]
    key = (name, d)
    if key not in _CLOSURE_JIT:
        _CLOSURE_JIT[key] = jax.jit(jax.vmap(get_closure(name, d)))
    return np.asarray(_CLOSURE_JIT[key](jnp.asarray(_padded(a2))))[: len(a2)]


def stationary_window(t: np.ndarray, a2: np.ndarray, earliest: float = -math.inf):
    """The steady-state verdict of a run and the window the estimators use.

    The window starts at the MSER-5 onset (:func:`pyfold.steady_state.detect_steady_state`),
    but not before ``earliest`` [s] (one Jeffery period from the start: before the first
    flip of the orbits no state is steady, whatever MSER finds in a short record), when at
    least :data:`MIN_WINDOW_RECORDS` records follow it, else at the middle of the run; the
    verdict (``stationary``, ``message``) is reported either way. Returns
    ``(steady, window, onset_time)`` with the onset after that bound.
    """
    from pyfold.steady_state import detect_steady_state

    steady = detect_steady_state(t, a2)
    start = steady.onset_index
    onset = float(steady.onset_time)
    if onset < earliest:
        start = min(int(np.searchsorted(t, earliest)), len(t) - 1)
        onset = float(t[start])
    if len(t) - start < MIN_WINDOW_RECORDS:
        start = len(t) // 2
    return steady, (float(t[start]), float(t[-1])), onset


def analyse_run(path: Path, ds: xr.Dataset, seed: int, closures: Sequence[str], L: np.ndarray,
                xi: float) -> RunAnalysis:
    """Steady state and C_I per closure of one checked run (closure errors: :func:`attach_closure_errors`)."""
    from pyfold.ci_estimators import ci_rate_regression

    t_all = np.asarray(ds["time"].values, dtype=np.float64)
    a2_all = np.asarray(ds["a2"].values, dtype=np.float64)
    a4_all = np.asarray(ds["a4"].values, dtype=np.float64)
    if len(t_all) < 4 * MIN_WINDOW_RECORDS // 2:
        raise InputError(f"{path}: {len(t_all)} records; the report needs at least {4 * MIN_WINDOW_RECORDS // 2} "
                         "(steady-state detection and a rate regression over its window)")
    from pyfold.provenance import jeffery_period_strain, shear_rate_of

    t_period = jeffery_period_strain(xi) / shear_rate_of(L)
    steady, window, onset = stationary_window(t_all, a2_all, float(t_all[0]) + t_period)
    message = steady.message
    stationary = bool(steady.stationary)
    if float(t_all[0]) + t_period > float(t_all[-1]):
        message = (f"the run ends inside the first Jeffery period ({t_period:.4g} s), before the orbits have flipped "
                   f"once: no steady state can be judged (MSER-5 alone would put an onset at t = "
                   f"{steady.onset_time:.4g} s); the estimators use its second half. " + message)
        onset, stationary = math.nan, False
    elif onset > float(steady.onset_time):
        message = (f"MSER-5 onset at t = {steady.onset_time:.4g} s lies inside the first Jeffery period "
                   f"({t_period:.4g} s), before the orbits have flipped once: moved to t = {onset:.4g} s. " + message)
    idx, _ = _thin_pad(len(t_all))
    t, a2, a4 = t_all[idx], a2_all[idx], a4_all[idx]
    d = a2.shape[-1]
    L = np.asarray(L, dtype=np.float64)[:d, :d]
    ci, ci_se = {}, {}
    judged = [c for c in closures if c != "exact"]
    a4_closure = {name: closure_a4(name, a2) for name in judged}
    if len(t) - np.searchsorted(t, window[0]) < MIN_WINDOW_RECORDS:
        window = (float(t[len(t) // 2]), float(t[-1]))
    for name in closures:
        r = ci_rate_regression(t, a2, a4 if name == "exact" else a4_closure[name], L, xi, window=window)
        ci[name], ci_se[name] = r.ci, r.stderr
    labels = ("x", "y", "z")[:d]
    slope, slope_se = np.asarray(steady.drift_slope), np.asarray(steady.drift_stderr)
    drift = {f"a_{labels[i]}{labels[i]}": (float(slope[i, i]), float(slope_se[i, i])) for i in range(d)}
    return RunAnalysis(path=path, seed=seed, t=t_all, a2=a2_all, onset_time=onset,
                       stationary=stationary, steady_message=message, window=window, ci=ci,
                       ci_stderr=ci_se, error_t=t, error_contracted={}, error_mean={}, error_stderr={}, drift=drift,
                       thinned=(a2, a4))


def attach_closure_errors(runs: Sequence[RunAnalysis], judged: Sequence[str], L: np.ndarray) -> None:
    """The a4:D error of every judged closure against each run's own a4
    (:func:`pyfold.closure_check.closure_errors`, one call for all runs: each closure is
    compiled and traced once), and its time mean and blocking s.e. over the run's window."""
    from pyfold.closure_check import closure_errors
    from pyfold.steady_state import blocking_stderr

    if judged:
        a2 = np.concatenate([_padded(r.thinned[0]) for r in runs])
        a4 = np.concatenate([_padded(r.thinned[1]) for r in runs])
        data = xr.Dataset({"a2": (("time", "i", "j"), a2), "a4": (("time", "i", "j", "k", "l"), a4)},
                          coords={"time": np.arange(len(a2), dtype=float)})
        errs = np.asarray(closure_errors(data, list(judged), velocity_gradient=L)["error_contracted"]
                          .sel(closure=list(judged)).values)
        for k, r in enumerate(runs):
            inside = (r.error_t >= r.window[0]) & (r.error_t <= r.window[1])
            for c, name in enumerate(judged):
                e = errs[c, k * CLOSURE_RECORDS: k * CLOSURE_RECORDS + len(r.error_t)]
                r.error_contracted[name] = e
                r.error_mean[name] = float(np.mean(e[inside]))
                r.error_stderr[name] = float(blocking_stderr(e[inside])[0])
    for r in runs:
        r.thinned = None


# --------------------------------------------------------------------------- across the runs


def fibre_concentration(ds: xr.Dataset, run_path: Path, dim: int) -> tuple[float, float, float]:
    """``(beta, n L^3, phi beta)`` of the run's single fibre family (NaN where undefined:
    2-D, or not one family of fibres); ``phi beta`` by :func:`pyfold.correlations.phi_beta`."""
    from pyfold.correlations import phi_beta
    from pyfold.run_input import read_setup

    res = read_setup(run_path).resolved
    shapes = np.atleast_1d(res["family_shape"])
    if dim != 3 or shapes.size != 1 or int(shapes[0]) != 1:
        return math.nan, math.nan, math.nan
    length = float(np.atleast_1d(res["family_length"])[0])
    beta = float(np.atleast_1d(res["family_aspect_ratio"])[0])
    count = float(np.atleast_1d(res["family_count"])[0])
    volume = float(np.prod(np.asarray(res["cell_lengths"], dtype=float)[:3]))
    n_l3 = count * length**3 / volume
    return beta, n_l3, phi_beta(n_l3, beta)


def rank_one_run(run: RunAnalysis, judged: Sequence[str]) -> list:
    """Ranking of closures on a single run: neighbours compared by the blocking standard
    error of the time mean of their paired error difference over the window (normal
    approximation), Holm-adjusted like :func:`pyfold.ensemble.rank_paired`."""
    from scipy import stats

    from pyfold.ensemble import RankedEntry, holm
    from pyfold.steady_state import blocking_stderr

    inside = (run.error_t >= run.window[0]) & (run.error_t <= run.window[1])
    order = sorted(judged, key=lambda c: run.error_mean[c])
    raw = []
    for a, b in zip(order[:-1], order[1:]):
        diff = run.error_contracted[b][inside] - run.error_contracted[a][inside]
        se = blocking_stderr(diff)[0]
        mean = float(np.mean(diff))
        raw.append(0.0 if se == 0.0 and mean != 0.0 else (1.0 if se == 0.0 else float(2 * stats.norm.sf(abs(mean / se)))))
    adjusted = holm(raw)
    rows = []
    for i, name in enumerate(order):
        p = adjusted[i] if i < len(adjusted) else math.nan
        rows.append(RankedEntry(rank=i + 1, name=name, mean=run.error_mean[name], error=run.error_stderr[name], n=1,
                                p_next=p, better_than_next=bool(math.isfinite(p) and p < RANK_LEVEL)))
    return rows


def measure_redistribution(runs: Sequence[RunAnalysis], early_end: float) -> dict[str, object]:
    """How the simulated state changes from the start (strain up to ``early_end`` [s]: the
    trajectory-fit window) to the stationary windows: ``|a2 - I/d|`` (Frobenius) and the
    diagonal of a2, means over the runs. Words in the summary follow these numbers."""
    def mean_over(select):
        values = []
        for r in runs:
            inside = select(r)
            values.append(np.mean(r.a2[inside], axis=0))
        return np.mean(values, axis=0)

    early = mean_over(lambda r: r.t <= early_end)
    late = mean_over(lambda r: (r.t >= r.window[0]) & (r.t <= r.window[1]))
    d = early.shape[-1]
    spread = lambda a: float(np.linalg.norm(a - np.eye(d) / d))  # noqa: E731
    return {"early_end": early_end, "early": early, "late": late, "anisotropy_early": spread(early),
            "anisotropy_late": spread(late)}


def ft_departure(runs: Sequence[RunAnalysis], pred_t: np.ndarray, pred: np.ndarray, fit_end: float,
               gamma_dot: float) -> tuple[float, float, float]:
    """Largest component-wise |a2_FT - a2_simulation| (simulation: mean over the runs,
    interpolated onto the prediction times) inside the fit window and after it, and the
    strain of the latter (NaN when the runs end with the window)."""
    d = pred.shape[-1]
    sim = np.mean([np.stack([[np.interp(pred_t, r.t, r.a2[:, i, j]) for j in range(d)] for i in range(d)])
                   .transpose(2, 0, 1) for r in runs], axis=0)
    gap = np.max(np.abs(pred - sim).reshape(len(pred_t), -1), axis=1)
    inside = pred_t <= fit_end * (1.0 + 1e-12)
    within = float(np.max(gap[inside])) if np.any(inside) else math.nan
    if np.all(inside):
        return within, math.nan, math.nan
    k = int(np.argmax(np.where(inside, -np.inf, gap)))
    return within, float(gap[k]), float(pred_t[k] * gamma_dot)


def ranking_equivalence(runs: Sequence[RunAnalysis], ranking) -> dict[str, object]:
    """Effect size and equivalence verdict (:func:`pyfold.seed_checks.equivalence`) of
    every closure in the ranking against the next one."""
    from pyfold.seed_checks import equivalence
    from pyfold.steady_state import blocking_stderr

    out = {}
    for a, b in zip(ranking[:-1], ranking[1:]):
        if len(runs) > 1:
            out[a.name] = equivalence(a.mean, [r.error_mean[b.name] - r.error_mean[a.name] for r in runs])
        else:
            r = runs[0]
            inside = (r.error_t >= r.window[0]) & (r.error_t <= r.window[1])
            diff = r.error_contracted[b.name][inside] - r.error_contracted[a.name][inside]
            out[a.name] = equivalence(a.mean, mean_difference=float(np.mean(diff)),
                                      stderr=float(blocking_stderr(diff)[0]))
    return out
