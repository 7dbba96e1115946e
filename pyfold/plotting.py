"""Matplotlib figures of orientation histories and fits (files only, no display).

Figures are drawn on :class:`matplotlib.figure.Figure` with the Agg canvas
directly, so importing this module never changes the user's global backend and
works on headless machines (CI, clusters).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pyfold.files import atomic_output

__all__ = ["plot_a2_histories", "plot_fit", "plot_report_a2", "plot_closure_report", "plot_ci_vs_correlations",
           "DEFAULT_COMPONENTS", "closure_colour", "clipped_texts"]

#: Components shown by default: flow (11), shear (12), gradient (22) and
#: vorticity (33) directions of a simple shear u = (gamma_dot y, 0, 0).
DEFAULT_COMPONENTS: tuple[tuple[int, int], ...] = ((0, 0), (0, 1), (1, 1), (2, 2))


#: Colour of the closure-free estimate (the runs' own a4) in every figure.
EXACT_COLOUR = "0.25"
#: Line styles of the published C_I correlations (drawn in black, so no closure colour is reused).
CORRELATION_STYLES = ("--", "-.", ":", (0, (5, 1, 1, 1)))


def closure_colour(name: str) -> str:
    """The one colour of a closure in every figure of ``pyfold analyse`` and ``pyfold report``:
    the default closures first (:data:`pyfold.run_checks.DEFAULT_CLOSURES`), then the other
    registered ones alphabetically, on matplotlib's 20-colour qualitative map."""
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    from pyfold.closures import CLOSURES
    from pyfold.run_checks import DEFAULT_CLOSURES

    if name == "exact":
        return to_hex(EXACT_COLOUR)
    order = [c for c in DEFAULT_CLOSURES if c != "exact"]
    order += sorted(c for c in CLOSURES if c not in order)
    k = order.index(name) if name in order else len(order)
    palette = colormaps["tab10"].colors + colormaps["tab20b"].colors
    return to_hex(palette[k % len(palette)])


def clipped_texts(fig: Figure) -> list[str]:
    """The visible, non-empty texts of ``fig`` that reach outside it (drawn once on Agg)."""
    from matplotlib.text import Text

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    box = fig.bbox
    out = []
    for text in fig.findobj(Text):
        if not text.get_visible() or not text.get_text().strip():
            continue
        ext = text.get_window_extent(renderer)
        if ext.x0 < box.x0 - 1 or ext.y0 < box.y0 - 1 or ext.x1 > box.x1 + 1 or ext.y1 > box.y1 + 1:
            out.append(text.get_text())
    return out


def _label(i: int, j: int) -> str:
    return f"$a_{{{i + 1}{j + 1}}}$"


def _save(fig: Figure, path, dpi: int = 120) -> Path:
    """Write ``fig`` as PNG; a text reaching outside the figure (:func:`clipped_texts`)
    makes the saved image grow to hold every text instead of cutting it off."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tight = {"bbox_inches": "tight", "pad_inches": 0.05} if clipped_texts(fig) else {}
    with atomic_output(path) as tmp:  # whole or absent: never a truncated PNG
        fig.savefig(tmp, dpi=dpi, **tight)
    return path


def plot_a2_histories(
    strain: np.ndarray,
    histories: Mapping[str, np.ndarray],
    path,
    components: Sequence[tuple[int, int]] = DEFAULT_COMPONENTS,
    title: str = "",
    xlabel: str = r"shear strain $\dot\gamma t$",
) -> Path:
    """One panel per component ``a_ij`` versus strain, one line per history.

    Parameters
    ----------
    strain : array (nt,)
    histories : mapping name -> array (nt, d, d)
        E.g. one Folgar--Tucker solution per closure.
    path : str or Path
        Output PNG file.
    """
    d = next(iter(histories.values())).shape[-1]
    components = [(i, j) for i, j in components if i < d and j < d]
    fig = Figure(figsize=(3.2 * len(components), 3.4), layout="constrained")
    axes = fig.subplots(1, len(components), squeeze=False)[0]
    for ax, (i, j) in zip(axes, components):
        for name, a2 in histories.items():
            ax.plot(strain, np.asarray(a2)[:, i, j], label=name, lw=1.3)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(_label(i, j))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, frameon=False)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_fit(
    t: np.ndarray,
    data_a2: np.ndarray,
    model_a2: np.ndarray,
    path,
    components: Sequence[tuple[int, int]] = DEFAULT_COMPONENTS,
    title: str = "",
    xlabel: str = "time [s]",
) -> Path:
    """Measured ``a_ij(t)`` (markers) against the fitted model (lines) and residuals.

    Parameters
    ----------
    t : array (nt,)
    data_a2, model_a2 : arrays (nt, d, d)
    path : str or Path
        Output PNG file.
    """
    d = data_a2.shape[-1]
    components = [(i, j) for i, j in components if i < d and j < d]
    fig = Figure(figsize=(7.0, 6.0), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    for k, (i, j) in enumerate(components):
        colour = f"C{k}"
        top.plot(t, data_a2[:, i, j], "o", ms=2.5, color=colour, alpha=0.6, label=f"data {_label(i, j)}")
        top.plot(t, model_a2[:, i, j], "-", color=colour, lw=1.4, label=f"fit {_label(i, j)}")
        bottom.plot(t, data_a2[:, i, j] - model_a2[:, i, j], ".", ms=2.5, color=colour)
    top.set_ylabel("orientation tensor component")
    top.legend(fontsize=7, ncol=2, frameon=False)
    top.grid(alpha=0.3)
    bottom.axhline(0.0, color="k", lw=0.8)
    bottom.set_ylabel("data - fit")
    bottom.set_xlabel(xlabel)
    bottom.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


# --------------------------------------------------------------------------- report figures (pyfold.report)


def plot_report_a2(dns: Mapping[int, tuple[np.ndarray, np.ndarray]], strain_ft: np.ndarray,
                   predictions: Mapping[str, np.ndarray], ci_used: Mapping[str, float], onsets: Sequence[float],
                   path, fit_window: tuple[float, float] | None = None, provenance: str = "",
                   notes: Sequence[str] = ()) -> Path:
    """Simulated ``a2`` per seed (thin grey) and their mean (black) against Folgar--Tucker
    at each closure's C_I (coloured), with the steady-state onsets (dotted).

    Parameters
    ----------
    dns : mapping seed -> (strain (nt,), a2 (nt, d, d))
    strain_ft : array (np,)
    predictions : mapping closure -> a2 (np, d, d)
    ci_used : mapping closure -> C_I of its prediction
    onsets : strains where each run's stationary window starts
    path : output PNG
    fit_window : strains of the trajectory fit of C_I (shaded, labelled)
    provenance : physics model, resolution and strain range (a line under the title)
    notes : lines under it (where Folgar-Tucker departs from the data past the fit window)
    """
    first = next(iter(dns.values()))
    d = first[1].shape[-1]
    components = [(0, 0), (1, 1), (0, 1)] + ([(2, 2)] if d == 3 else [])
    fig = Figure(figsize=(3.3 * len(components), 4.2), layout="constrained")
    axes = fig.subplots(1, len(components), squeeze=False)[0]
    same_grid = len({len(s) for s, _ in dns.values()}) == 1
    for ax, (i, j) in zip(axes, components):
        for strain, a2 in dns.values():
            ax.plot(strain, a2[:, i, j], color="0.6", lw=0.5, alpha=0.7)
        if same_grid and len(dns) > 1:
            strain = first[0]
            ax.plot(strain, np.mean([a2[:, i, j] for _, a2 in dns.values()], axis=0), "k", lw=1.3,
                    label=f"simulation, mean of {len(dns)} seeds")
        elif len(dns) == 1:
            ax.lines[-1].set(color="k", lw=1.0, alpha=1.0, label="simulation")
        for name, a2 in predictions.items():
            ax.plot(strain_ft, a2[:, i, j], color=closure_colour(name), lw=1.1,
                    label=f"FT {name}, trajectory-fitted C_I = {ci_used[name]:.2g}")
        if fit_window is not None:
            ax.axvspan(*fit_window, color="tab:olive", alpha=0.12, lw=0,
                       label=f"fit window, strain {fit_window[0]:.3g}-{fit_window[1]:.3g}")
        for x in onsets:
            ax.axvline(x, color="0.4", lw=0.6, ls=":")
        ax.set_xlabel(r"shear strain $\dot\gamma t$")
        ax.set_ylabel(_label(i, j))
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 6), fontsize=7, frameon=False)
    title = "Direct simulation (grey: seeds) vs Folgar-Tucker at each closure's C_I; dotted: steady-state onsets"
    fig.suptitle("\n".join([title, *([provenance] if provenance else []), *notes]), fontsize=8)
    return _save(fig, path)


def plot_closure_report(errors: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
                        ci: Mapping[str, tuple[float, float]], correlations: Mapping[str, float], ranking,
                        path, provenance: str = "") -> Path:
    """Left: each closure's ``a4:D`` error against the simulation's ``a4`` over strain
    (mean over seeds), labelled with its rank. Right: C_I ± error per closure ("exact":
    the runs' own a4) with the published correlations at the scene's phi beta.

    Parameters
    ----------
    errors : mapping closure -> [(strain, error) per run]
    ci : mapping closure -> (C_I, error): the trajectory fit, for "exact" the rate regression
    correlations : mapping name -> C_I at the scene's phi beta
    ranking : sequence of pyfold.ensemble.RankedEntry
    path : output PNG
    provenance : physics model, resolution and strain range (a line under the title)
    """
    fig = Figure(figsize=(11, 3.9), layout="constrained")
    left, right = fig.subplots(1, 2)
    rank = {e.name: e.rank for e in ranking}
    for k, (name, series) in enumerate(errors.items()):
        strain = series[0][0]
        if all(len(s) == len(strain) for s, _ in series):
            e = np.mean([v for _, v in series], axis=0)
        else:
            strain, e = series[0]
        left.semilogy(strain, np.maximum(e, 1e-16), lw=1.0, color=closure_colour(name),
                      label=f"{rank.get(name, '?')}. {name}")
    left.set_xlabel(r"shear strain $\dot\gamma t$")
    left.set_ylabel(r"$\|(\mathrm{closure}(a_2) - a_4):D\| / \|a_4:D\|$")
    left.grid(alpha=0.3, which="both")
    if errors:
        left.legend(fontsize=7, frameon=False, title="rank. closure", title_fontsize=7, loc="lower right")
    names = list(ci)
    x = np.arange(len(names))
    values = np.array([ci[n][0] for n in names])
    errs = np.array([ci[n][1] for n in names])
    colours = [closure_colour(n) for n in names]
    right.bar(x, values, yerr=np.where(np.isfinite(errs), errs, 0.0), capsize=3, color=colours)
    for k, (name, value) in enumerate(correlations.items()):
        right.axhline(value, color="k", ls=CORRELATION_STYLES[k % len(CORRELATION_STYLES)], lw=1.0,
                      label=f"{name}: {value:.2g}")
    right.axhline(0.0, color="k", lw=0.6)
    right.set_xticks(x, ["exact\n(own a4,\nrate regr.)" if n == "exact" else n for n in names], rotation=30)
    right.set_ylabel("C_I: trajectory fit per closure\n(exact: rate regression)")
    right.set_yscale("symlog", linthresh=1e-4)
    right.grid(alpha=0.3, axis="y")
    if correlations:
        right.legend(fontsize=7, frameon=False, loc="lower left")
    title = "Closures against the simulation's own a4 (left); C_I per closure and published correlations (right)"
    fig.suptitle("\n".join([title, *([provenance] if provenance else [])]), fontsize=8)
    return _save(fig, path)


def plot_ci_vs_correlations(phi_beta: float, ci: Mapping[str, tuple[float, float]], path,
                            provenance: str = "") -> Path:
    """The published C_I correlations and Folgar & Tucker's (1984) measurements against
    phi beta (pyfold.correlations), with this report's C_I per closure at the scene's
    phi beta (symmetric-log axis: a negative C_I is shown as such)."""
    from pyfold import correlations as corr

    fig = Figure(figsize=(6.4, 4.4), layout="constrained")
    ax = fig.subplots()
    pb = np.linspace(0.0, 5.0, 201)
    for k, (name, (fn, _)) in enumerate(corr.CORRELATIONS.items()):
        ax.plot(pb, fn(pb), color="k", ls=CORRELATION_STYLES[k % len(CORRELATION_STYLES)], lw=1.1, label=name)
    ft = corr.FOLGAR_TUCKER_1984
    ax.plot([v.phi_beta for v in ft], [v.ci for v in ft], "ks", ms=5, label=ft[0].source)
    ax.axhspan(*corr.PUBLISHED_RANGE, color="tab:green", alpha=0.07, label="published range")
    if np.isfinite(phi_beta):
        names = list(ci)
        offsets = (np.arange(len(names)) - (len(names) - 1) / 2) * 0.03
        for k, name in enumerate(names):
            value, err = ci[name]
            ax.errorbar(phi_beta + offsets[k], value, yerr=err if np.isfinite(err) else None, fmt="o", ms=4,
                        capsize=2, color=closure_colour(name),
                        label=f"this report: {'exact (own a4, rate regression)' if name == 'exact' else name + ' (trajectory fit)'}")
        ax.axvline(phi_beta, color="0.5", lw=0.6, ls=":")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.set_xlabel(r"$\phi\beta$")
    ax.set_ylabel(r"$C_I$")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6.5, frameon=False, ncol=2, loc="lower right")
    ax.set_title("\n".join(["C_I: correlations, measurements, and this report", *([provenance] if provenance else [])]),
                 fontsize=8 if provenance else 10)
    return _save(fig, path)
