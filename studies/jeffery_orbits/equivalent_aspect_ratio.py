"""Equivalent aspect ratio of a finite (flat-ended) cylinder from the Stokes solver.

Question
    A rigid cylinder of aspect ratio beta = L/d in simple shear follows a Jeffery orbit
    with the period T = (2 pi / gamma_dot)(beta_e + 1/beta_e) of a spheroid of a smaller
    *equivalent* aspect ratio beta_e (docs/physics.md#equivalent-aspect-ratio-of-a-finite-cylinder).
    Which beta_e does pyfold's fictitious-domain FFT Stokes solver give for beta = 3 ... 20,
    how well is it converged in resolution (voxels per diameter) and cell size, and
    where does it fall beside the three published rules
      Cox (1971, J. Fluid Mech. 45:625, slender-body theory, asymptotic in 1/ln beta,
        so meant for large beta): beta_e = 1.24 beta / sqrt(ln beta);
      Harris & Pittman (1975, J. Colloid Interface Sci. 50:280, empirical fit to
        measured periods of rods): beta_e = 1.14 beta^0.844;
      Zhang, Smith, Jack & Montgomery-Smith (2011, J. Manuf. Sci. Eng. 133:051002,
        doi:10.1115/1.4004831, cubic fit to their finite-element periods of cylinders):
        beta_e = 0.000035 beta^3 - 0.00467 beta^2 + 0.764 beta + 0.404
      (the same forms as pyfold.kinematics.equivalent_aspect_ratio; the Zhang
      coefficients agree with the fiberoripy implementation)?

Method
    Stokes flow has no memory, so the in-plane orbit is dtheta/dt = omega(theta), omega
    the solver's rigid rotation rate at a FIXED orientation theta (angle from the flow
    direction in the flow-gradient plane) and T = int_0^{2 pi} dtheta / |omega(theta)|,
    as in studies/stokes_validation/jeffery_period.py. Two exact symmetries of a centred
    body in a rectangular cell with zero Lees-Edwards offset cut the orbit to a quarter:
    omega(theta + pi) = omega(theta) (p and -p are the same body) and
    omega(-theta) = omega(theta) (mirror x -> -x reverses both the rotation and the
    shear); the second was checked to 1e-9 relative on the solver (beta = 5, 40^3 and
    beta = 8, 96^3). So T = 4 int_0^{pi/2} dtheta/|omega|.
    The integrand peaks near theta = 0, where the particle spends most of its time, and
    omega(theta) carries voxelisation wiggles (jeffery_period.py: >= 48 equispaced
    orientations per orbit were needed at 3 voxels per diameter). The quadrature therefore
    uses Jeffery's own angle: theta = arctan(tan(phi) / b), b = the Harris & Pittman estimate
    (b = beta for a spheroid), with phi equispaced on [0, pi/2] and the trapezoid rule.
    For an exact Jeffery orbit with b = beta_e the integrand in phi is constant (so the
    rule is exact for any count); otherwise it is smooth, even about 0 and pi/2, and the
    trapezoid rule is spectrally accurate; the nodes crowd where the time is spent.
    The quadrature error is estimated by repeating the rule on every other node.
    Then beta_e = (tau + sqrt(tau^2 - 4)) / 2 with tau = gamma_dot T / (2 pi).
    Checks carried along: a fit omega = -(gamma_dot/2)(a - lambda cos 2 theta) (the
    form of every axisymmetric body in unbounded shear, Bretherton 1962) whose residual
    measures what the cell and the voxels add; and a prolate SPHEROID of the same
    beta, d, cell and grid, whose exact beta_e = beta measures the method's own error
    and tests the extrapolation (its voxelisation error has the opposite sign to the
    cylinder's, so it cannot serve as a calibration factor).

Resolution, cell, rigidity
    Voxels per diameter vpd = 4, 6, 8 (cubic voxels, h = d / vpd; even, so that the
    aligned body's surface falls on voxel faces at every resolution: with odd and even
    vpd mixed, T is not monotone in h). The cubic cell is `cell` = 1.5 fibre lengths wide
    (rounded to an even voxel count; the tips of the aligned fibre pass half a length
    from their images). With three resolutions the observed order p solves
    (T1 - T2)/(T2 - T3) = (h1^p - h2^p)/(h2^p - h3^p) and the Richardson value is
    T3 + (T3 - T2)/((h2/h3)^p - 1); the discretisation error quoted is the larger of
    |T3 - T_inf| and |T3 - T2| (just |T3 - T2| when p is not in [0.5, 4]).
    Periodic images: a force-free particle is a stresslet; far away its images shift the
    ambient velocity gradient by O(stresslet / cell volume), T(c) = T_inf + A c^-3. The
    image study (one beta, one vpd, several cells c) reports T(c), the shift at the
    production cell against the largest cell, and the c^-3 extrapolation through the two
    largest cells; at c <= 3 the far-field law does not hold yet (docs/jeffery_orbits.md).
    Rigidity: the penalty kappa = 1e3 leaves a rigidity error ~ 1/kappa; the same orbit at
    kappa = 1e4 gives T(kappa -> inf) = T(1e4) + (T(1e4) - T(1e3)) / 9 and the effect.

Command
    nice -n 10 /work/main/.venv/bin/python studies/jeffery_orbits/equivalent_aspect_ratio.py
        [--large] [--betas 3 5 8] [--vpd 4 6 8] [--cell 1.5] [--nphi 12]
        [--image-beta 5] [--image-vpd 4] [--image-cells 1.5 2 3] [--kappas 1e4]
        [--no-spheroid] [--out out/jeffery_orbits] [--reanalyse out/jeffery_orbits/equivalent_aspect_ratio.nc]
    --large: beta = 3, 5, 8, 12, 20, nphi 24, image and rigidity studies at beta 8.
    --reanalyse: no solves; recompute the derived values, table and figure from a saved file.
Cost on 2 cores (one solve at a time, serial FFTW; CPU time, the machine at load 8-11)
    small (default; largest grid 96^3 = beta 8 at vpd 8): 13 orientations per orbit,
    3 betas x 3 resolutions x (cylinder, spheroid) + image (3 cells) + rigidity studies;
    a 96^3 orbit takes ~130 s CPU (~10 s and ~150 CG iterations per solve); the whole
    small form measured 611 s CPU (38 min wall at load 8-11).
    large: beta 20 at vpd 8 is a 240^3 grid (16x the voxels of 96^3, so ~3 CPU min per
    solve, 25 solves per orbit and shape): several CPU hours; not run (memory not measured).
Outputs (under --out)
    equivalent_aspect_ratio.nc   omega per node, T, beta_e per (shape, beta, vpd);
                                 Richardson values and errors; correlations; image and
                                 rigidity studies (xarray.open_dataset(path, engine="h5netcdf")).
    equivalent_aspect_ratio.md   the tables (also printed).
    equivalent_aspect_ratio.png  beta_e / beta against beta beside the three rules.
"""
from __future__ import annotations

import argparse
import datetime
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from pyfold.command_line import command_line, git_revision
from pyfold.kinematics import equivalent_aspect_ratio
from pyfold.native.stokes import Particles, StokesSettings, solve_particles

# Parameters
SMALL = dict(betas=[3.0, 5.0, 8.0], vpd=[4, 6, 8], cell=1.5, nphi=12, image_beta=5.0, image_vpd=4,
             image_cells=[1.5, 2.0, 3.0], kappas=[1.0e4])
LARGE = dict(betas=[3.0, 5.0, 8.0, 12.0, 20.0], vpd=[4, 6, 8], cell=1.5, nphi=24, image_beta=8.0, image_vpd=4,
             image_cells=[1.5, 2.0, 3.0], kappas=[1.0e4])
DIAMETER = 10e-6  # fibre diameter [m]; the Stokes problem is scale-free, T depends on gamma_dot only
SHEAR_RATE = 1.0  # [1/s]
ETA_F = 1.0  # fluid viscosity [Pa s]
KAPPA = 1.0e3  # viscosity contrast, the solver's default (rigidity residual reported)
TOL = 1.0e-6  # CG relative residual
#: per-orbit results written by `run`; everything else is recomputed by `analyse`
RAW_VARS = ("theta", "omega", "weight", "iterations", "rigidity", "period", "period_half_nodes", "bretherton_a",
            "bretherton_lambda", "bretherton_rms", "grid", "cell", "cpu_time", "image_period", "kappa_period")
ORDER_RANGE = (0.5, 4.0)  # accepted observed orders; outside, fall back to the finest difference


def _rule(name):
    """The published rule ``name`` of pyfold.kinematics (the one place the three are stated),
    as a NumPy function of beta."""
    return lambda beta: np.asarray(equivalent_aspect_ratio(np.asarray(beta, float), name), dtype=float)


#: Cox (1971), Harris & Pittman (1975), Zhang et al. (2011): beta -> beta_e
RULES = {name: _rule(name) for name in ("cox", "harris_pittman", "zhang")}
cox, harris_pittman, zhang = RULES["cox"], RULES["harris_pittman"], RULES["zhang"]


def beta_from_period(T, shear_rate: float = SHEAR_RATE):
    """Invert Jeffery's T = (2 pi / gamma_dot)(b + 1/b) for the root b >= 1 (NaN if tau < 2)."""
    tau = np.asarray(T, float) * shear_rate / (2 * np.pi)
    with np.errstate(invalid="ignore"):
        return np.where(tau >= 2, (tau + np.sqrt(np.maximum(tau**2 - 4, 0))) / 2, np.nan)


def jeffery_nodes(nphi: int, b: float):
    """Orientations theta_k = arctan(tan(phi_k) / b), phi_k = (pi/2) k / nphi, k = 0..nphi, and
    the trapezoid weights w_k (dtheta/dphi included) with T = 4 sum_k w_k / |omega_k|.

    Jeffery's orbit is tan theta = tan(phi) / beta_e with phi advancing uniformly in time
    (Jeffery 1922), so with b = beta_e the integrand dtheta/dphi / |omega| is constant."""
    phi = 0.5 * np.pi * np.arange(nphi + 1) / nphi
    theta = np.arctan2(np.sin(phi), b * np.cos(phi))
    dtheta_dphi = b / (b**2 * np.cos(phi) ** 2 + np.sin(phi) ** 2)
    w = np.full(nphi + 1, 0.5 * np.pi / nphi)
    w[[0, -1]] *= 0.5
    return theta, w * dtheta_dphi


def period(omega, weights) -> float:
    """T = 4 int_0^{pi/2} dtheta / |omega| by the trapezoid rule in Jeffery's angle."""
    return float(4 * np.sum(weights / np.abs(omega)))


def period_half(omega, theta_nodes_b: float, nphi: int) -> float:
    """The same rule on every other node (nphi/2 intervals): the quadrature-error estimate."""
    _, w2 = jeffery_nodes(nphi // 2, theta_nodes_b)
    return period(np.asarray(omega)[::2], w2)


def bretherton_fit(theta, omega, weights):
    """Least-squares fit omega = -(gamma_dot/2)(a - lam cos 2 theta), weighted by the time spent
    (weights / |omega|); returns a, lam and the weighted rms residual relative to gamma_dot/2."""
    wt = np.sqrt(weights / np.abs(omega))
    M = np.stack([-np.ones_like(theta), np.cos(2 * theta)], axis=1) * (SHEAR_RATE / 2)
    coef, *_ = np.linalg.lstsq(M * wt[:, None], omega * wt, rcond=None)
    res = omega - M @ coef
    rms = np.sqrt(np.sum(wt**2 * res**2) / np.sum(wt**2)) / (SHEAR_RATE / 2)
    return float(coef[0]), float(coef[1]), float(rms)


def observed_order(h, T):
    """Observed order p and Richardson value from three (h, T), h decreasing; (nan, nan) when
    the differences change sign or p falls outside ORDER_RANGE."""
    (h1, h2, h3), (T1, T2, T3) = h, T
    d12, d23 = T1 - T2, T2 - T3
    if d12 * d23 <= 0:
        return np.nan, np.nan
    ratio = d12 / d23
    f = lambda p: (h1**p - h2**p) / (h2**p - h3**p) - ratio  # noqa: E731
    lo, hi = ORDER_RANGE
    if f(lo) * f(hi) > 0:
        return np.nan, np.nan
    p = brentq(f, lo, hi, xtol=1e-10)
    return p, T3 + (T3 - T2) / ((h2 / h3) ** p - 1)


# Problem
def particle(shape: str, beta: float, theta: float, cell_length: float) -> Particles:
    """A cylinder (flat ends) or prolate spheroid of diameter DIAMETER and length beta*DIAMETER
    at the cell centre, axis in the flow-gradient plane at angle theta from the flow."""
    c = 0.5 * cell_length
    return Particles(x=[[c, c, c]], p=[[np.cos(theta), np.sin(theta), 0.0]], radius=0.5 * DIAMETER,
                     length=beta * DIAMETER, shape={"cylinder": "fibre", "spheroid": "spheroid"}[shape])


def grid_size(beta: float, vpd: int, cell: float) -> int:
    """Voxels per cell edge: cell * beta * vpd rounded to an EVEN count (cell = that many voxels of
    d/vpd). Even, so the particle centre sits on a voxel corner in every cell: with an odd count
    it would sit at a voxel centre and the voxelised body (hence T) would change with the cell
    for a reason that is not the periodic images (seen at vpd 3: 20.32 / 20.28 / 20.13 s for
    14 / 18 / 27 voxels)."""
    return max(2, 2 * int(round(cell * beta * vpd / 2)))


# Solver
def orbit(shape: str, beta: float, vpd: int, cell: float, nphi: int, settings: StokesSettings) -> dict:
    """Rotation rates on the quarter-orbit nodes and the period derived from them."""
    b = float(harris_pittman(beta)) if shape == "cylinder" else beta
    theta, w = jeffery_nodes(nphi, b)
    n = grid_size(beta, vpd, cell)
    h = DIAMETER / vpd
    Lc = n * h
    om, its, rig = np.empty(nphi + 1), np.empty(nphi + 1, int), np.empty(nphi + 1)
    t0 = time.process_time()
    for k, th in enumerate(theta):
        sol = solve_particles(particle(shape, beta, th, Lc), [Lc] * 3, (n, n, n), shear_rate=SHEAR_RATE,
                              settings=settings)
        om[k], its[k], rig[k] = sol.omega[0, 2], sol.iterations, sol.rigidity[0]
    cpu = time.process_time() - t0
    T = period(om, w)
    T_half = period_half(om, b, nphi)
    a, lam, rms = bretherton_fit(theta, om, w)
    print(f"  {shape:8s} kappa {settings.kappa:7.0f} beta {beta:5.1f} vpd {vpd} cell {n * h / (beta * DIAMETER):.3f} L ({n}^3): "
          f"T = {T:9.4f} s, beta_e = {float(beta_from_period(T)):7.4f}, quad. diff {T - T_half:+.1e} s, "
          f"CG its {its.min()}-{its.max()}, CPU {cpu:6.1f} s", flush=True)
    return dict(theta=theta, weight=w, omega=om, iterations=its, rigidity=rig, T=T, T_half=T_half, a=a, lam=lam,
                rms=rms, n=n, cell=n * h / (beta * DIAMETER), cpu=cpu)


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="beta 3..20, nphi 24, image study at beta 8")
    ap.add_argument("--betas", type=float, nargs="+")
    ap.add_argument("--vpd", type=int, nargs="+", help="voxels per diameter (>= 2), at least 2 values")
    ap.add_argument("--cell", type=float, help="cubic cell edge in fibre lengths, >= 1.2")
    ap.add_argument("--nphi", type=int, help="quarter-orbit intervals, even, >= 4")
    ap.add_argument("--image-beta", type=float)
    ap.add_argument("--image-vpd", type=int)
    ap.add_argument("--image-cells", type=float, nargs="*", help="cell sizes of the image study (none: skip)")
    ap.add_argument("--kappas", type=float, nargs="*", help="extra contrasts of the kappa study (none: skip)")
    ap.add_argument("--no-spheroid", action="store_true", help="skip the spheroid control")
    ap.add_argument("--out", type=Path, default=Path("out/jeffery_orbits"))
    ap.add_argument("--reanalyse", type=Path, help="recompute tables/figure from a saved .nc (no solves)")
    a = ap.parse_args(argv)
    base = LARGE if a.large else SMALL
    for key in base:
        if getattr(a, key) is None:
            setattr(a, key, base[key])
    if any(not b > 1.5 for b in a.betas):
        ap.error(f"--betas: every aspect ratio must be > 1.5 (Cox's rule diverges at 1), got {a.betas}")
    if len(a.vpd) < 2 or any(v < 2 for v in a.vpd) or len(set(a.vpd)) != len(a.vpd):
        ap.error(f"--vpd: need >= 2 distinct voxel counts per diameter, each >= 2, got {a.vpd}")
    if not a.cell >= 1.2:
        ap.error(f"--cell: the cell must be >= 1.2 fibre lengths (tips clear of the images), got {a.cell}")
    if a.nphi < 4 or a.nphi % 2:
        ap.error(f"--nphi: must be even and >= 4 (the error estimate halves it), got {a.nphi}")
    if a.image_cells and (any(c < 1.2 for c in a.image_cells) or len(a.image_cells) < 2):
        ap.error(f"--image-cells: need >= 2 sizes, each >= 1.2 lengths, got {a.image_cells}")
    if a.kappas and any(not KAPPA < k <= 1e8 for k in a.kappas):
        ap.error(f"--kappas: each must be in ({KAPPA:g}, 1e8], got {a.kappas}")
    if not a.image_beta > 1.5 or a.image_vpd < 2:
        ap.error(f"--image-beta > 1.5 and --image-vpd >= 2 required, got {a.image_beta}, {a.image_vpd}")
    a.vpd = sorted(a.vpd)
    return a


def discretisation(vpd, T):
    """(T_inf, error, order) from T at increasing vpd.

    Richardson with the observed order p on the three finest grids; the error quoted is the
    larger of the Richardson correction |T3 - T_inf| and the finest difference |T3 - T2|
    (p varies between betas and shapes, so the asymptotic range is not assured and the
    correction alone could be optimistic). Without a usable p: T3 and |T3 - T2|."""
    h = DIAMETER / np.asarray(vpd, float)
    p, T_inf = (np.nan, np.nan)
    if len(vpd) >= 3:
        p, T_inf = observed_order(h[-3:], T[-3:])
    finest = abs(T[-1] - T[-2])
    if np.isfinite(T_inf):
        return T_inf, max(abs(T[-1] - T_inf), finest), p
    return T[-1], finest, np.nan


def main(argv=None) -> int:
    a = _args(argv)
    if a.reanalyse is not None:
        import xarray as xr

        with xr.open_dataset(a.reanalyse, engine="h5netcdf") as ds:
            raw = ds.load()
        raw = raw[[v for v in RAW_VARS if v in raw]]
        for key, value in (("image_beta", a.image_beta), ("image_vpd", a.image_vpd)):
            raw.attrs.setdefault(key, value)
    else:
        raw = run(a)
    a.out.mkdir(parents=True, exist_ok=True)
    ds, table = analyse(raw)
    ds.to_netcdf(a.out / "equivalent_aspect_ratio.nc", engine="h5netcdf")
    (a.out / "equivalent_aspect_ratio.md").write_text(table)
    print(table)
    _figure(ds, a.out / "equivalent_aspect_ratio.png")
    return 0


def run(a):
    """Every solve of the study; returns the raw per-orbit results as an xarray.Dataset."""
    import xarray as xr

    settings = StokesSettings(eta_f=ETA_F, kappa=KAPPA, tol=TOL)
    shapes = ["cylinder"] + ([] if a.no_spheroid else ["spheroid"])
    betas, vpds = np.asarray(a.betas, float), np.asarray(a.vpd, int)
    # Run
    t_start = time.process_time()
    R = {(s, b, v): orbit(s, float(b), int(v), a.cell, a.nphi, settings) for s in shapes for b in betas for v in vpds}
    image = {(s, c): orbit(s, a.image_beta, a.image_vpd, c, a.nphi, settings)
             for c in a.image_cells or [] for s in shapes}
    ks = [KAPPA] + list(a.kappas or [])
    kap = {(s, k): orbit(s, a.image_beta, a.image_vpd, a.cell, a.nphi, StokesSettings(eta_f=ETA_F, kappa=k, tol=TOL))
           for k in ks[1:] for s in shapes}
    cpu = time.process_time() - t_start
    # Save (raw)
    get = lambda key: np.array([[[R[s, b, v][key] for v in vpds] for b in betas] for s in shapes])  # noqa: E731
    coords = dict(shape=shapes, beta=("beta", betas, {"units": "1", "long_name": "aspect ratio L/d"}),
                  vpd=("vpd", vpds, {"units": "1", "long_name": "voxels per diameter"}),
                  node=("node", np.arange(a.nphi + 1), {"long_name": "quarter-orbit node k (phi = pi k / (2 nphi))"}))
    dims3, dimsK = ("shape", "beta", "vpd"), ("shape", "beta", "vpd", "node")
    data = {name: _var(dimsK, get(name), *meta) for name, meta in NODE_VARIABLES.items()}
    data.update({name: _var(dims3, get(key), *meta) for name, (key, *meta) in ORBIT_VARIABLES.items()})
    if image:
        cells = np.array([image["cylinder", c]["cell"] for c in a.image_cells])
        coords["image_cell"] = ("image_cell", cells, {"units": "1", "long_name": "cell edge / particle length"})
        data["image_period"] = _var(("shape", "image_cell"), [[image[s, c]["T"] for c in a.image_cells]
                                                             for s in shapes], "s", "T of the image study")
    if len(ks) > 1:
        base = R.get((shapes[0], a.image_beta, a.image_vpd))
        Tk = [[(R[s, a.image_beta, a.image_vpd]["T"] if base is not None else
                orbit(s, a.image_beta, a.image_vpd, a.cell, a.nphi, settings)["T"]) if k == KAPPA else kap[s, k]["T"]
               for k in ks] for s in shapes]
        coords["kappa"] = ("kappa", np.array(ks), {"units": "1", "long_name": "viscosity contrast"})
        data["kappa_period"] = _var(("shape", "kappa"), Tk, "s", "T of the rigidity study")
    return xr.Dataset(data, coords=coords, attrs=dict(
        format="pyfold.study.equivalent_aspect_ratio", format_version="1.0",
        creator=f"pyfold {git_revision(Path(__file__).resolve().parent)}",
        created=datetime.datetime.now(datetime.timezone.utc).isoformat(), command=command_line(sys.argv),
        shear_rate=SHEAR_RATE, diameter=DIAMETER, eta_f=ETA_F, kappa_base=KAPPA, tol=TOL, nphi=a.nphi,
        cell_lengths=a.cell, image_beta=a.image_beta, image_vpd=a.image_vpd, fibre_ends=settings.fibre_ends,
        mixing=settings.mixing, derivative=settings.derivative, subsamples=settings.subsamples,
        cpu_time_total=cpu))


#: orbit() results saved per quarter-orbit node: name (also orbit()'s key) -> (units, long_name)
NODE_VARIABLES = {
    "theta": ("rad", "orientation from the flow direction"),
    "omega": ("1/s", "rotation rate omega_z at fixed orientation"),
    "weight": ("rad", "trapezoid weight in theta (T = 4 sum w/|omega|)"),
    "iterations": ("1", "CG iterations"),
    "rigidity": ("1", "rigidity residual of the particle"),
}
#: orbit() results saved once per orbit: name in the file -> (orbit()'s key, units, long_name)
ORBIT_VARIABLES = {
    "period": ("T", "s", "orbit period T"),
    "period_half_nodes": ("T_half", "s", "period from every other node"),
    "bretherton_a": ("a", "1", "fit omega = -(gd/2)(a - lam cos 2theta): a (1 unbounded)"),
    "bretherton_lambda": ("lam", "1", "fit omega = -(gd/2)(a - lam cos 2theta): lam"),
    "bretherton_rms": ("rms", "1", "time-weighted rms residual of that fit / (gd/2)"),
    "grid": ("n", "1", "voxels per cell edge"),
    "cell": ("cell", "1", "cell edge / particle length"),
    "cpu_time": ("cpu", "s", "CPU time of the orbit"),
}


def _var(dims, x, units, long_name, derived=False):
    attrs = {"units": units, "long_name": long_name}
    if derived:
        attrs["derived"] = 1  # recomputed by --reanalyse
    return (dims, np.asarray(x), attrs)


def analyse(raw):
    """Periods -> beta_e, Richardson values and errors, image and rigidity effects, the table."""
    shapes, betas, vpds = list(raw.shape.values), raw.beta.values, raw.vpd.values
    cell = float(raw.attrs["cell_lengths"])
    T = raw.period.values
    quad = np.abs(T - raw.period_half_nodes.values)  # error bound of the HALF rule; the full one is better
    be = beta_from_period(T)
    T_inf, T_err, order = (np.empty(T.shape[:2]) for _ in range(3))
    for i in range(T.shape[0]):
        for j in range(T.shape[1]):
            T_inf[i, j], T_err[i, j], order[i, j] = discretisation(vpds, T[i, j])
    be_inf = beta_from_period(T_inf)
    dbe_dT = SHEAR_RATE / (2 * np.pi) * be_inf**2 / np.maximum(be_inf**2 - 1, 1e-12)
    be_err = dbe_dT * (T_err + quad[..., -1])
    d2 = ("shape", "beta")
    data = dict(
        beta_e=_var(("shape", "beta", "vpd"), be, "1", "equivalent aspect ratio from T", True),
        period_extrapolated=_var(d2, T_inf, "s", "Richardson (or finest) period", True),
        period_disc_error=_var(d2, T_err, "s", "discretisation error estimate of T", True),
        period_quad_error=_var(d2, quad[..., -1], "s", "quadrature error bound (finest grid)", True),
        observed_order=_var(d2, order, "1", "observed order in h (nan: not monotone or outside 0.5..4)", True),
        beta_e_extrapolated=_var(d2, be_inf, "1", "beta_e from the extrapolated period", True),
        beta_e_error=_var(d2, be_err, "1", "error estimate of beta_e_extrapolated", True),
        **{f"beta_e_{k}": _var(("beta",), f(betas), "1", f"{k} rule", True) for k, f in RULES.items()},
    )
    img = kap = None
    if "image_period" in raw:
        # T(c) is not monotone at small c (beta 3) and decays more slowly than the far-field
        # c^-3 between 1.5 and 3 lengths (beta 5): no asymptotic fit is trusted. Reported: the
        # shift of T at the production cell relative to the largest cell studied, and the
        # c^-3 extrapolation through the two largest cells (the far-field law, an estimate).
        cells, Timg = raw.image_cell.values, raw.image_period.values
        c1, c2 = cells[-2], cells[-1]
        T_far = Timg[:, -1] + (Timg[:, -1] - Timg[:, -2]) / ((c2 / c1) ** 3 - 1)
        at_cell = np.array([np.interp(cell, cells, Ti) for Ti in Timg])
        img = dict(cells=cells, T=Timg, T_inf=T_far, vs_largest=at_cell / Timg[:, -1] - 1, effect=at_cell / T_far - 1)
        data["image_period_inf"] = _var(("shape",), T_far, "s", "c^-3 extrapolation through the two largest cells", True)
        data["image_effect_vs_largest"] = _var(("shape",), img["vs_largest"], "1",
                                               f"T(cell {cell}) / T(largest cell) - 1", True)
        data["image_effect"] = _var(("shape",), img["effect"], "1", f"T(cell {cell}) / T_inf - 1", True)
    if "kappa_period" in raw:
        ks, Tk = raw.kappa.values, raw.kappa_period.values
        # rigidity error ~ 1/kappa: T = T_inf + B / kappa through the two stiffest contrasts
        T_kinf = Tk[:, -1] + (Tk[:, -1] - Tk[:, -2]) / (ks[-1] / ks[-2] - 1)
        kap = dict(kappas=ks, T=Tk, T_inf=T_kinf, effect=Tk[:, 0] / T_kinf - 1)
        data["kappa_period_inf"] = _var(("shape",), T_kinf, "s", "T extrapolated in 1/kappa", True)
        data["kappa_effect"] = _var(("shape",), kap["effect"], "1", f"relative T shift at kappa {KAPPA:g}", True)
    ds = raw.assign(data)
    at = raw.attrs
    sph = "spheroid" in shapes
    L = [f"Equivalent aspect ratio of a flat-ended cylinder: cubic cell {cell:g} lengths, nphi {at['nphi']} "
         f"(quarter orbit), kappa {KAPPA:g}, tol {TOL:g}; gamma_dot = {SHEAR_RATE:g} 1/s. "
         f"CPU {float(at['cpu_time_total']):.0f} s.", "",
         "Per resolution: T [s] and beta_e of the cylinder; beta_e of the spheroid of the same beta (exact: beta);",
         "rms of the fit omega = -(gd/2)(a - lam cos 2 theta) over the cylinder's orbit, relative to gd/2.",
         "| beta | vpd | grid | T cylinder | beta_e cylinder | beta_e spheroid | fit rms |", "|---|---|---|---|---|---|---|"]
    for j, b in enumerate(betas):
        for k, v in enumerate(vpds):
            L.append(f"| {b:g} | {v} | {int(raw.grid.values[0, j, k])}^3 | {T[0, j, k]:.3f} | {be[0, j, k]:.3f} | "
                     + (f"{be[1, j, k]:.3f}" if sph else "-") + f" | {raw.bretherton_rms.values[0, j, k]:.1e} |")
    L += ["", "Extrapolated to h -> 0 (Richardson with the observed order p on the three finest grids; error = "
          "max(Richardson correction, finest difference) + quadrature bound) beside the published rules",
          "| beta | T_inf [s] | +- disc. | +- quad. | p | **beta_e cylinder** | spheroid (exact = beta) "
          "| Cox 1971 | Harris & Pittman 1975 | Zhang et al. 2011 |", "|---|---|---|---|---|---|---|---|---|---|"]
    for j, b in enumerate(betas):
        p = f"{order[0, j]:.2f}" if np.isfinite(order[0, j]) else "-"
        s = f"{be_inf[1, j]:.2f} +- {be_err[1, j]:.2f}" if sph else "-"
        L.append(f"| {b:g} | {T_inf[0, j]:.2f} | {T_err[0, j]:.2f} | {quad[0, j, -1]:.2f} | {p} | "
                 f"**{be_inf[0, j]:.2f} +- {be_err[0, j]:.2f}** | {s} | {float(cox(b)):.2f} | "
                 f"{float(harris_pittman(b)):.2f} | {float(zhang(b)):.2f} |")
    if img:
        L += ["", f"Periodic images: beta {float(at['image_beta']):g}, vpd {int(at['image_vpd'])}; T_inf = c^-3 "
              "extrapolation through the two largest cells (c = cell / length)",
              "| shape | " + " | ".join(f"T(c={c:.3g})" for c in img["cells"]) + " | T_inf | "
              f"T(c={cell:g}) vs largest cell | vs T_inf |", "|---" * (len(img["cells"]) + 4) + "|"]
        for i, s in enumerate(shapes):
            L.append(f"| {s} | " + " | ".join(f"{t:.3f}" for t in img["T"][i]) + f" | {img['T_inf'][i]:.3f} | "
                     f"{100 * img['vs_largest'][i]:+.2f} % | {100 * img['effect'][i]:+.2f} % |")
    if kap:
        L += ["", f"Rigidity: beta {float(at['image_beta']):g}, vpd {int(at['image_vpd'])}, cell {cell:g}, "
              "T = T_inf + B / kappa through the two stiffest",
              "| shape | " + " | ".join(f"T(kappa={k:g})" for k in kap["kappas"]) + f" | T_inf | effect at "
              f"kappa={KAPPA:g} |", "|---" * (len(kap["kappas"]) + 3) + "|"]
        for i, s in enumerate(shapes):
            L.append(f"| {s} | " + " | ".join(f"{t:.3f}" for t in kap["T"][i]) + f" | {kap['T_inf'][i]:.3f} | "
                     f"{100 * kap['effect'][i]:+.2f} % |")
    return ds, "\n".join(L) + "\n"


def _figure(ds, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    betas, vpds = ds.beta.values, ds.vpd.values
    fig, ax = plt.subplots(figsize=(6, 4.5))
    bb = np.linspace(2.0, max(betas.max() * 1.1, 10), 200)
    names = {"cox": "Cox 1971", "harris_pittman": "Harris & Pittman 1975", "zhang": "Zhang et al. 2011"}
    for (k, f), ls in zip(RULES.items(), ["-", "--", ":"]):
        ax.plot(bb, f(bb) / bb, "k" + ls, lw=1, label=names[k])
    be = ds.beta_e.values
    for k, v in enumerate(vpds):
        ax.plot(betas, be[0, :, k] / betas, "o", ms=4, alpha=0.5, label=f"cylinder, {v} vox/d")
    ax.errorbar(betas, ds.beta_e_extrapolated.values[0] / betas, ds.beta_e_error.values[0] / betas, fmt="s",
                color="C3", capsize=3, label="cylinder, extrapolated")
    if "spheroid" in list(ds.shape.values):
        ax.errorbar(betas, ds.beta_e_extrapolated.values[1] / betas, ds.beta_e_error.values[1] / betas, fmt="x",
                    color="C7", capsize=3, label="spheroid control (exact: 1), extrapolated")
    ax.set_xlabel(r"aspect ratio $\beta = L/d$")
    ax.set_ylabel(r"$\beta_e / \beta$")
    ax.set_title(f"Finite cylinder in shear, cell {float(ds.attrs['cell_lengths']):g} lengths")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)


if __name__ == "__main__":
    sys.exit(main())
