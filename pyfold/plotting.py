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

__all__ = ["plot_a2_histories", "plot_fit", "DEFAULT_COMPONENTS"]

#: Components shown by default: flow (11), shear (12), gradient (22) and
#: vorticity (33) directions of a simple shear u = (gamma_dot y, 0, 0).
DEFAULT_COMPONENTS: tuple[tuple[int, int], ...] = ((0, 0), (0, 1), (1, 1), (2, 2))


def _label(i: int, j: int) -> str:
    return f"$a_{{{i + 1}{j + 1}}}$"


def _save(fig: Figure, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120)
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
