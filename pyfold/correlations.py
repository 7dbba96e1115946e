"""Published C_I correlations and values, the one place pyfold states them.

Moulding codes pick the Folgar-Tucker interaction coefficient from a correlation
in the product ``phi * beta`` (volume fraction times aspect ratio); pyfold's
studies and reports plot their fitted ``C_I`` beside these
(docs/physics.md#c_i-correlations, docs/physics.md#published-c_i-values):

* Bay (1991):                 ``C_I = 0.0184 exp(-0.7148 phi beta)``
* Phan-Thien et al. (2002):   ``C_I = 0.03 (1 - exp(-0.224 phi beta))``
* Folgar & Tucker (1984), Couette experiments: three points; Meyer et al. (2020), SPH,
  three points; Salahuddin et al. (2012), lattice-Boltzmann, an order of magnitude.
* pyfold's own fluid-coupled table (data/ci_fluid_coupled.csv, written by
  studies/interaction_coefficient/ci_fluid_series.py) and its weighted straight-line fit in
  ``phi * beta`` per closure (:func:`fluid_coupled_fit`, :func:`fluid_coupled_ci`), quoted by
  ``pyfold report`` inside the table's beta and range of ``phi * beta`` only.

Concentration measures of a fibre population (``n`` fibres per unit volume, length
``L``, diameter ``d``, ``beta = L/d``; cylinders without caps):

    phi = n (pi/4) d^2 L = (pi/4) n L^3 / beta^2,    n L^2 d = n L^3 / beta.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np


def volume_fraction(n_l3: float, beta: float) -> float:
    """``phi = (pi/4) n L^3 / beta^2`` of cylinders of aspect ratio ``beta`` (caps ignored)."""
    return math.pi / 4.0 * float(n_l3) / float(beta) ** 2


def phi_beta(n_l3: float, beta: float) -> float:
    """``phi beta = (pi/4) n L^3 / beta``, the variable of the C_I correlations."""
    return volume_fraction(n_l3, beta) * float(beta)


def n_l2d(n_l3: float, beta: float) -> float:
    """``n L^2 d = n L^3 / beta`` (the concentration of Sundararajakumar & Koch 1997)."""
    return float(n_l3) / float(beta)


def bay_1991(phi_b):
    """Bay (1991), PhD thesis, UIUC: ``C_I = 0.0184 exp(-0.7148 phi beta)``."""
    return 0.0184 * np.exp(-0.7148 * np.asarray(phi_b, dtype=float))


def phan_thien_2002(phi_b):
    """Phan-Thien, Fan, Tanner & Zheng (2002), JNNFM 103:251: ``C_I = 0.03 (1 - exp(-0.224 phi beta))``."""
    return 0.03 * (1.0 - np.exp(-0.224 * np.asarray(phi_b, dtype=float)))


#: name -> (function of phi*beta, citation)
CORRELATIONS = {
    "Bay 1991": (bay_1991, "Bay (1991), PhD thesis, University of Illinois: 0.0184 exp(-0.7148 phi beta)"),
    "Phan-Thien 2002": (phan_thien_2002,
                        "Phan-Thien, Fan, Tanner & Zheng (2002), J. Non-Newtonian Fluid Mech. 103:251: "
                        "0.03 (1 - exp(-0.224 phi beta))"),
}


@dataclasses.dataclass(frozen=True)
class PublishedValue:
    """A published C_I at a concentration ``phi_beta`` (NaN when the source does not give it)."""

    source: str
    method: str
    phi_beta: float
    ci: float


#: Folgar & Tucker (1984), J. Reinf. Plast. Compos. 3:98, Couette experiments.
FOLGAR_TUCKER_1984 = (
    PublishedValue("Folgar & Tucker 1984", "Couette experiment", 0.16, 0.0038),
    PublishedValue("Folgar & Tucker 1984", "Couette experiment", 1.28, 0.0081),
    PublishedValue("Folgar & Tucker 1984", "Couette experiment", 2.56, 0.0165),
)

#: Meyer, Saburow, Hohberg, Hrymak, Henning & Kärger (2020), J. Compos. Sci. 4:77: SPH direct
#: simulation of beta = 10 fibres, Folgar-Tucker fit (values from the authors' data files).
MEYER_2020 = (
    PublishedValue("Meyer et al. 2020", "SPH simulation, beta 10, Folgar-Tucker fit", 0.05, 0.0026),
    PublishedValue("Meyer et al. 2020", "SPH simulation, beta 10, Folgar-Tucker fit", 0.5, 0.0043),
    PublishedValue("Meyer et al. 2020", "SPH simulation, beta 10, Folgar-Tucker fit", 1.5, 0.011),
)

#: Salahuddin, Wu & Aidun (2012), J. Fluid Mech. 692: lattice-Boltzmann, semi-dilute, beta = 16-72:
#: C_I of order 1e-4 (an order of magnitude, no concentration dependence given here).
SALAHUDDIN_2012_ORDER = 1.0e-4

#: Range of published C_I values from experiments and simulations
#: (docs/physics.md#published-c_i-values): about 1e-4 (lattice-Boltzmann, Salahuddin,
#: Wu & Aidun 2012) to 3e-2 (the Phan-Thien plateau).
PUBLISHED_RANGE = (1.0e-4, 3.0e-2)


def correlations_at(phi_b: float) -> dict[str, float]:
    """Each correlation's C_I at ``phi_b`` (name -> value)."""
    return {name: float(fn(phi_b)) for name, (fn, _) in CORRELATIONS.items()}


# --------------------------------------------------------------------------- pyfold's own table

#: The fluid-coupled table written by studies/interaction_coefficient/ci_fluid_series.py --write-data
FLUID_COUPLED_FILE = "ci_fluid_coupled.csv"


def _data_folder():
    from pathlib import Path

    installed = Path(__file__).resolve().parent / "data"  # a non-editable install (meson.build)
    return installed if installed.is_dir() else Path(__file__).resolve().parents[1] / "data"


def fluid_coupled_table(path=None) -> list[dict]:
    """The rows of data/ci_fluid_coupled.csv: per (beta, n L^3, model, closure, estimator) the
    ensemble C_I and its errors (stat, settings, shape, total), from
    studies/interaction_coefficient/ci_fluid_series.py (its docstring gives the method)."""
    import csv

    path = path or _data_folder() / FLUID_COUPLED_FILE
    with open(path, encoding="utf-8") as f:
        reader = csv.DictReader(line for line in f if not line.startswith("#"))
        rows = []
        for r in reader:
            rows.append({k: (v if k in ("model", "closure", "estimator") else float(v)) for k, v in r.items()})
    return rows


@dataclasses.dataclass(frozen=True)
class LinearFit:
    """``C_I = c0 + c1 phi beta`` by weighted least squares over the table's points, with the
    covariance of (c0, c1) from the points' total errors and the range of phi beta it covers."""

    closure: str
    estimator: str
    model: str
    beta: float
    c0: float
    c1: float
    cov: tuple[tuple[float, float], tuple[float, float]]
    phi_beta_range: tuple[float, float]
    chi2: float  # of the fit, with len(points) - 2 degrees of freedom
    points: int

    def __call__(self, phi_b: float) -> tuple[float, float]:
        """(C_I, its standard error) at ``phi_b``: ``c0 + c1 phi_b`` and ``sqrt(g^T cov g)``, ``g = (1, phi_b)``."""
        x = float(phi_b)
        (v00, v01), (_, v11) = self.cov
        return self.c0 + self.c1 * x, math.sqrt(max(v00 + 2.0 * x * v01 + x * x * v11, 0.0))


def fluid_coupled_fit(closure: str = "ibof", estimator: str = "trajectory", model: str = "stokes",
                      rows: list[dict] | None = None, beta: float | None = None) -> LinearFit:
    """The linear fit in phi*beta of the table's C_I of ``closure`` and ``estimator`` ("trajectory":
    the Folgar-Tucker fit to a2(t) from the isotropic start; "steady": the rate regression over
    the stationary window; closure "closure-free" with the runs' own a4) at aspect ratio ``beta``
    (needed when the table has several: C_I is not a function of phi*beta alone). Weighted by
    1/total_err^2: ``(X^T W X) c = X^T W y``, ``cov = (X^T W X)^-1``."""
    rows = fluid_coupled_table() if rows is None else rows
    betas = sorted({r["beta"] for r in rows})
    if beta is None and len(betas) > 1:
        raise ValueError(f"beta: the table has beta {', '.join(f'{b:g}' for b in betas)}; name the one to fit")
    if beta is not None:
        rows = [r for r in rows if r["beta"] == beta]
        if not rows:
            raise ValueError(f"beta: {beta:g} is not in the table (it has beta {', '.join(f'{b:g}' for b in betas)})")
    sel = [r for r in rows if r["closure"] == closure and r["estimator"] == estimator and r["model"] == model]
    if len(sel) < 2:
        raise ValueError(f"closure, estimator: {closure!r}/{estimator!r} has {len(sel)} point(s) in the table; "
                         f"2 or more are needed (closures: {sorted({r['closure'] for r in rows})})")
    x = np.array([r["phi_beta"] for r in sel])
    y = np.array([r["ci"] for r in sel])
    w = 1.0 / np.array([r["total_err"] for r in sel]) ** 2
    X = np.stack([np.ones_like(x), x], axis=1)
    cov = np.linalg.inv(X.T @ (w[:, None] * X))
    c = cov @ (X.T @ (w * y))
    chi2 = float(np.sum(w * (y - X @ c) ** 2))
    return LinearFit(closure=closure, estimator=estimator, model=model, beta=float(sel[0]["beta"]),
                     c0=float(c[0]), c1=float(c[1]), cov=((float(cov[0, 0]), float(cov[0, 1])),
                                                           (float(cov[1, 0]), float(cov[1, 1]))),
                     phi_beta_range=(float(x.min()), float(x.max())), chi2=chi2, points=len(sel))


#: Closures the report quotes from the fluid-coupled fit (trajectory estimator; closure-free: steady)
FLUID_COUPLED_QUOTED = (("ibof", "trajectory"), ("orw3", "trajectory"), ("fec", "trajectory"),
                        ("closure-free", "steady"))
#: Relative distance in beta within which the table's beta counts as the scene's
BETA_MATCH = 0.05


def fluid_coupled_ci(beta: float, phi_b: float, rows: list[dict] | None = None) -> tuple[dict, str]:
    """pyfold's own fluid-coupled C_I at (``beta``, ``phi_b``) from :func:`fluid_coupled_fit`: a dict
    "closure (estimator)" -> (C_I, standard error), and a sentence saying what it is or why it is
    not given (no table, another beta, phi_b outside the table's range: no extrapolation)."""
    try:
        rows = fluid_coupled_table() if rows is None else rows
    except OSError:
        return {}, "pyfold fluid-coupled fit: no table (data/ci_fluid_coupled.csv)"
    betas = sorted({r["beta"] for r in rows if r["model"] == "stokes"})
    match = [b for b in betas if math.isfinite(beta) and abs(beta - b) <= BETA_MATCH * b]
    if not match:
        return {}, (f"pyfold fluid-coupled fit: not for beta = {beta:.3g} (the table has beta "
                    f"{', '.join(f'{b:g}' for b in betas)})")
    values, span = {}, None
    for closure, est in FLUID_COUPLED_QUOTED:
        try:
            fit = fluid_coupled_fit(closure, est, rows=rows, beta=match[0])
        except ValueError:
            continue
        span = fit.phi_beta_range
        if fit.phi_beta_range[0] <= phi_b <= fit.phi_beta_range[1]:
            values[f"{closure} ({est})"] = fit(phi_b)
    if span is None:
        return {}, "pyfold fluid-coupled fit: the table has no fitted closure"
    where = (f"pyfold fluid-coupled fit (beta {match[0]:g}, phi beta {span[0]:.2f}-{span[1]:.2f}, linear in "
             "phi beta, data/ci_fluid_coupled.csv)")
    if not values:
        return {}, f"{where}: phi beta = {phi_b:.3g} is outside its range (not extrapolated)"
    return values, f"{where} at phi beta = {phi_b:.3g}: " + ", ".join(
        f"{k} {v:.2e} ± {e:.1e}" for k, (v, e) in values.items())
