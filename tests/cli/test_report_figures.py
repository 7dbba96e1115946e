"""The figures of `pyfold report` and `pyfold analyse` say what they show: one colour per
closure in every figure, the closure bars labelled as the trajectory fits they are, the
fit window marked with the departure note, the physics model under the title, and no
text cut off at the figure's edge."""
from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.image import imread

from pyfold import plotting, run_checks, trajectory_fit
from pyfold.ensemble import RankedEntry

MODEL = "Jeffery kinematics + contacts (collision strategy), no hydrodynamic interactions; strain 0-400"


@pytest.fixture
def captured(monkeypatch):
    figures = {}
    save = plotting._save

    def keep(fig, path, **kw):
        figures[path.name] = fig
        return save(fig, path, **kw)

    monkeypatch.setattr(plotting, "_save", keep)
    return figures


def _lines(fig, word):
    return [line for ax in fig.axes for line in ax.get_lines() if word in line.get_label()]


def _report_figures(tmp_path, captured):
    strain = np.linspace(0.0, 400.0, 801)
    a2 = np.tile(np.diag([0.7, 0.1, 0.2]), (801, 1, 1))
    strain_ft = np.linspace(0.0, 400.0, 256)
    prediction = {c: np.tile(np.diag([0.75, 0.08, 0.17]), (256, 1, 1)) for c in ("fec", "ibof", "hybrid")}
    plotting.plot_report_a2({1: (strain, a2), 2: (strain, a2)}, strain_ft, prediction,
                            {c: 2.5e-4 for c in prediction}, [150.0, 180.0], tmp_path / "a2_dns_vs_fitted_ft.png",
                            fit_window=(0.0, 104.0), provenance=MODEL,
                            notes=["past the fit window (strain > 104) Folgar-Tucker departs from the data: ibof by "
                                   "up to 0.11 (strain 400)"])
    errors = {c: [(strain, np.full(801, 0.2 + k))] for k, c in enumerate(("ibof", "fec", "hybrid"))}
    ranking = [RankedEntry(rank=k + 1, name=c, mean=0.2 + k, error=0.01, n=2, p_next=0.03, better_than_next=True)
               for k, c in enumerate(("ibof", "fec", "hybrid"))]
    shown = {"exact": (-1.9e-4, 1e-5), "fec": (2.8e-4, 1e-5), "ibof": (2.5e-4, 1e-5), "hybrid": (2.2e-2, 2e-3)}
    plotting.plot_closure_report(errors, shown, {"Bay 1991": 1.5e-2, "Phan-Thien 2002": 2e-3}, ranking,
                                 tmp_path / "closures_vs_dns.png", provenance=MODEL)
    plotting.plot_ci_vs_correlations(0.31, shown, tmp_path / "ci_vs_correlations.png", provenance=MODEL)
    return captured


def test_report_figures_colour_each_closure_alike_and_label_the_fits(tmp_path, captured):
    figs = _report_figures(tmp_path, captured)
    a2_fig, closure_fig, ci_fig = (figs[n] for n in ("a2_dns_vs_fitted_ft.png", "closures_vs_dns.png",
                                                     "ci_vs_correlations.png"))
    for name in ("fec", "ibof", "hybrid"):
        colour = plotting.closure_colour(name)
        assert {to_hex(line.get_color()) for line in _lines(a2_fig, f"FT {name},")} == {colour}
        assert {to_hex(line.get_color()) for line in _lines(closure_fig, f". {name}")} == {colour}
        marks = [c for c in ci_fig.axes[0].containers if c.get_label().startswith(f"this report: {name}")]
        assert {to_hex(c.lines[0].get_color()) for c in marks} == {colour}
    bars = closure_fig.axes[1].patches
    assert [to_hex(b.get_facecolor()) for b in bars] == [plotting.closure_colour(c)
                                                          for c in ("exact", "fec", "ibof", "hybrid")]
    # the bars are trajectory fits (the closure-free one a rate regression), and say so
    ylabel = closure_fig.axes[1].get_ylabel()
    assert "trajectory fit" in ylabel and "exact: rate regression" in ylabel
    assert all("trajectory-fitted" in line.get_label() for line in _lines(a2_fig, "FT "))
    # distinct colours for distinct closures
    names = ["exact", *run_checks.DEFAULT_CLOSURES[1:]]
    assert len({plotting.closure_colour(c) for c in names}) == len(names)


def test_the_fit_window_the_departure_and_the_model_are_on_the_a2_figure(tmp_path, captured):
    fig = _report_figures(tmp_path, captured)["a2_dns_vs_fitted_ft.png"]
    for ax in fig.axes:
        spans = [p for p in ax.patches if p.get_label().startswith("fit window, strain 0-104")]
        assert len(spans) == 1
        ext = spans[0].get_bbox()  # in data x (axvspan spans the axes in y)
        assert ext.x0 == 0.0 and ext.x1 == 104.0
    title = fig._suptitle.get_text()
    assert MODEL in title and "past the fit window (strain > 104)" in title
    for name in ("closures_vs_dns.png", "ci_vs_correlations.png"):
        fig = captured[name]
        text = fig._suptitle.get_text() if fig._suptitle is not None else fig.axes[0].get_title()
        assert MODEL in text, name


def test_no_text_is_cut_off(tmp_path, captured):
    """Each saved PNG holds every text: the figure leaves none outside, or the image grew to
    hold it (a deliberately long label checks that the growth happens)."""
    figs = _report_figures(tmp_path, captured)
    for name, fig in figs.items():
        if plotting.clipped_texts(fig):
            h, w = imread(tmp_path / name).shape[:2]
            assert w > fig.bbox.width or h > fig.bbox.height, name
    fig = Figure(figsize=(3, 2))
    ax = fig.subplots()
    ax.set_xlabel("a label far too long for a figure three inches wide, which a plain save would cut off")
    assert plotting.clipped_texts(fig)
    plotting._save(fig, tmp_path / "long.png", dpi=100)
    assert imread(tmp_path / "long.png").shape[1] > 300


def test_analyse_figures_use_the_same_colours_and_labels(tmp_path, monkeypatch):
    figs = []
    monkeypatch.setattr(trajectory_fit, "_save_figure", lambda fig, path: figs.append(fig))
    t = np.linspace(0.0, 10.0, 21)
    a2 = np.tile(np.diag([0.6, 0.2, 0.2]), (21, 1, 1))
    ds = xr.Dataset({"a2": (("time", "i", "j"), a2)}, coords={"time": t})
    names = ["exact", "ibof", "fec"]
    fits = xr.Dataset({"ci": ("closure", [1e-4, 2e-4, 3e-4]), "ci_stderr": ("closure", [1e-5] * 3),
                       "a2_fit": (("closure", "time", "i", "j"), np.stack([a2] * 3)),
                       "admissible": ("closure", np.ones(3, np.int8)), "success": ("closure", np.ones(3, np.int8)),
                       "inadmissible_time": ("closure", [np.nan] * 3)}, coords={"closure": names})
    errors = xr.Dataset({"error_contracted": (("closure", "time"), np.full((2, 21), 0.2))},
                        coords={"closure": ["ibof", "fec"]})
    L = np.zeros((3, 3))
    L[0, 1] = 1.0
    trajectory_fit._figures(ds, fits, errors, L, tmp_path, [MODEL])
    a2_fig, closure_fig = figs
    for name in ("ibof", "fec"):
        colour = plotting.closure_colour(name)
        assert {to_hex(line.get_color()) for line in _lines(a2_fig, f"FT {name},")} == {colour}
        assert {to_hex(line.get_color()) for line in closure_fig.axes[0].get_lines()
                if line.get_label() == name} == {colour}
    assert [to_hex(b.get_facecolor()) for b in closure_fig.axes[1].patches] == [plotting.closure_colour(c)
                                                                                 for c in names]
    assert closure_fig.axes[1].get_ylabel() == "C_I (trajectory fit)"
    assert MODEL in a2_fig._suptitle.get_text() and MODEL in closure_fig._suptitle.get_text()
