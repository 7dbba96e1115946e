"""Fictitious-domain Stokes solver of the Fortran core (``fortran/stokes``), serial FFTW.

The periodic cell (lattice basis ``A``, columns a1, a2, a3; Lees–Edwards shear:
``a2 = (s, Ly, 0)``) carries the flow ``u = G·x + ũ`` with ``ũ`` periodic. The
particles are a region of viscosity ``κ η_f``; with ``κ → ∞`` they move rigidly
(Glowinski & Joseph penalisation, docs/physics.md#fictitious-domain-penalisation). The
solver is a preconditioned conjugate-gradient method whose preconditioner is the constant-viscosity Stokes
Green operator in Fourier space (Moulinec & Suquet 1998, *Comput. Methods Appl.
Mech. Eng.* 157:69; CG variant: Zeman et al. 2010, *J. Comput. Phys.* 229:8065).

Array conventions (in memory; not the run-file convention): a field on an
``nx × ny [× nz]`` grid is indexed ``[i, j, k]`` with ``i`` along a1; 2-D fields
have shape ``(nx, ny, 1)``. Voxel ``m`` has its centre at ``A·(m + 1/2)/n``.
Velocities ``u`` have shape ``(nx, ny, nz, dim)`` (``ũ`` at voxel centres).
Particle vectors are ``(N, dim)`` as everywhere in pyfold.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pyfold.errors import InputError, checked
from pyfold.native import load
from pyfold.scene import registry as _registry

# Code tables of the Stokes settings: views of the settings registry
# (pyfold/scene/registry.py), which also generates the Fortran constants
# (fortran/core/fold_settings.f90); tests/micro/test_stokes_code_tables.py checks the
# constants of the Fortran modules that are not generated (fold_time_scheme, fold_fft_transport).
BACKENDS = _registry.codes("numerics.stokes.backend")
DERIVATIVES = _registry.codes("numerics.stokes.derivative")
MIXINGS = _registry.codes("numerics.stokes.mixing")
FIBRE_ENDS = _registry.codes("numerics.stokes.fibre_ends")
FIBRE_SHELLS = _registry.codes("numerics.stokes.fibre_shells")
GUESSES = _registry.codes("numerics.stokes.initial_guess")
REUSES = _registry.codes("numerics.stokes.reuse")
SCHEMES = _registry.codes("numerics.time_scheme")
FFT_PLANS = _registry.codes("numerics.stokes.fft_plan")
#: transforms of the CG operator (fold_settings FOLD_FFT_DOUBLE / FOLD_FFT_SINGLE); fold_run only
FFT_PRECISIONS = _registry.codes("numerics.stokes.fft_precision")
#: rigidity of the particles (fold_settings FOLD_RIGIDITY_*): the seed's penalty kappa, or the
#: constraint eps(u) = 0 on the voxels covered at least half, by a multiplier (fold_stokes_rigid; fft)
RIGIDITIES = _registry.codes("numerics.stokes.rigidity")
SHAPES = _registry.codes("particles.shape")

#: Unit round-off of single precision (fold_stokes_fft FOLD_SINGLE_ROUNDOFF).
SINGLE_ROUNDOFF = 0.5 * float(np.finfo(np.float32).eps)


def single_tolerance_min(voxels: int) -> float:
    """Smallest CG tolerance accepted with ``fft_precision = "single"`` on a grid of
    ``voxels`` points: ``(2 log2 N + 4) u_s``, the residual attainable when the operator's
    transforms round to single precision (derivation: the header of
    fortran/stokes/fold_stokes_fft.f90; its ``single_tol_min`` is the Fortran copy, and
    tests/micro/test_stokes_code_tables.py checks that fold_run refuses exactly below it).
    """
    return SINGLE_ROUNDOFF * (2.0 * math.log2(max(int(voxels), 2)) + 4.0)


#: The backend choice that has no code: :func:`backend_for` resolves it from the cell
#: (the normaliser writes the resolved code to /setup/resolved/stokes_backend).
AUTO_BACKEND = _registry.AUTO_BACKEND
#: Every word numerics.stokes.backend accepts: the coded backends and "auto".
BACKEND_CHOICES = _registry.setting("numerics.stokes.backend").choices
#: The backend "auto" stands for in a cell with or without walls (the capability table
#: of the registry decides: pyfold.scene.registry.BACKENDS).
backend_for = _registry.backend_for

#: Bounds of the viscosity contrast kappa (the registry's; fold_settings FOLD_KAPPA_MIN,
#: FOLD_KAPPA_MAX, which fold_run_file refuses outside).
KAPPA_MIN, KAPPA_MAX = _registry.KAPPA_MIN, _registry.KAPPA_MAX


@dataclass(frozen=True)
class KappaRange:
    """What a grid, tolerance and precision allow (:func:`kappa_range`)."""

    #: largest kappa accepted at the tolerance
    kappa_max: float
    #: largest tolerance at which the kappa asked about is accepted
    tolerance_max: float
    #: relative round-off of the CG operator, (2 log2 N + 4) u of its transforms
    eps_op: float


def kappa_range(voxels: int, tol: float, kappa: float = 1.0, fft_precision: str = "double") -> KappaRange:
    """The largest kappa a run accepts on a grid of ``voxels`` points at CG tolerance
    ``tol`` with transforms of ``fft_precision`` (a key of :data:`FFT_PRECISIONS`), the
    largest tolerance that accepts ``kappa``, and the operator's round-off ``eps_op``.

    ``kappa_max = (1 + tol + eps_op) / (tol + eps_op + eps_d)`` (at most :data:`KAPPA_MAX`;
    ``eps_d`` the double-precision round-off): beyond it the bound on the solver's error
    of the particles' stress contribution, ``(kappa - 1)(tol + eps_op) + kappa eps_d`` of
    it, exceeds the contribution itself
    (docs/physics.md#how-large-a-penalty-the-solver-can-carry). Computed by the Fortran
    of fortran/stokes/fold_stokes_trust.f90, which fold_run applies too.
    """
    kmax, tmax, eps_op = load("_fold_stokes").fold_stokes_kappa_max(int(voxels), float(tol), float(kappa),
                                                                    FFT_PRECISIONS[fft_precision])
    return KappaRange(float(kmax), float(tmax), float(eps_op))


def stress_check(eta_eff: float, eta_f: float, voxels: int, kappa: float, tol: float) -> None:
    """fold_run's run-time check of a solve: raise :class:`~pyfold.errors.PyfoldError`
    with fold_run's cause when ``eta_eff`` is below ``eta_f`` (less the round-off of the
    sums over ``voxels``), impossible for particles at least as viscous as the fluid."""
    stat, msg = load("_fold_stokes").fold_stokes_stress_check(float(eta_eff), float(eta_f), int(voxels),
                                                              float(kappa), float(tol))
    checked(stat, msg)

#: The defaults of every solver setting that changes results, named as in the scene file
#: (a view of the settings registry, which the scene schema reads too).
DEFAULTS = {key: _registry.default(f"numerics.stokes.{key}")
            for key in ("backend", "tolerance", "max_iterations", "kappa", "derivative", "mixing", "subsamples",
                        "fibre_ends", "fibre_radius_scale", "fibre_shells", "warm_start", "initial_guess", "fft_plan", "fft_precision",
                        "rigidity")}


@dataclass(frozen=True)
class StokesSettings:
    """Settings of the fictitious-domain solve (checked on construction).

    Attributes
    ----------
    eta_f : fluid viscosity [Pa s], > 0.
    kappa : viscosity contrast η_solid/η_f, in [KAPPA_MIN, KAPPA_MAX]; rigidity error ~ 1/κ,
        CG iterations ~ √κ. These bindings take any such κ (tests explore the solver beyond
        what a run accepts); a run accepts at most the ``kappa_max`` of :func:`kappa_range`.
    tol : relative preconditioned residual at which CG stops, in (0, 1).
    max_iter : CG iteration cap, >= 1.
    derivative : ``"fd"`` (rotated finite differences, Willot 2015, *C. R. Mécanique*
        343:232; default) or ``"spectral"`` (``i k``, Nyquist modes removed).
    mixing : viscosity of partially covered voxels: ``"harmonic"`` (default),
        ``"arithmetic"`` (η_f(1 + (κ−1)χ), docs/physics.md#viscosity-of-partially-covered-voxels;
        inflates particles by ~h/2),
        ``"geometric"``.
    subsamples : sub-samples per voxel edge for the partial-volume χ, 1..8.
    fibre_ends : ``"flat"`` cylinder (default) or ``"capped"`` (the contact capsule).
    fibre_radius_scale : radius of the voxelised fibres over their geometric radius (a
        hydrodynamic radius calibrated to the grid); spheres and spheroids keep theirs.
    fibre_shells : with ``fibre_radius_scale`` > 1, the added shells of near fibres:
        ``"overlap"`` (their coverages add up) or ``"apart"`` (each ends the security zone
        short of the other particle's geometric surface; ``solve_particles``' ``alpha``).
    warm_start : start CG from the previous step's solution (time marching only).
    guess : initial guess of a warm start: ``"previous"`` (the last solution) or
        ``"extrapolate"`` (2 x_n − x_(n−1) of the last two).
    measure_plans : FFTW_MEASURE plans (seconds to make, faster transforms; repeated
        runs agree to the solver tolerance) or FFTW_ESTIMATE (bitwise reproducible).
    rigidity : ``"penalty"`` (default; kappa in the solid) or ``"exact"`` (eps(u) = 0 on the
        voxels covered at least half, by a multiplier; kappa unused; fold_stokes_rigid).
    backend : the Stokes backend, a word of :data:`BACKEND_CHOICES` (the bindings below
        solve periodic cells, for which ``"auto"`` is ``"fft"``: :func:`backend_for`).

    Defaults: :data:`DEFAULTS` (shared with the scene file).
    """

    eta_f: float = 1.0
    kappa: float = DEFAULTS["kappa"]
    tol: float = DEFAULTS["tolerance"]
    max_iter: int = DEFAULTS["max_iterations"]
    derivative: str = DEFAULTS["derivative"]
    mixing: str = DEFAULTS["mixing"]
    subsamples: int = DEFAULTS["subsamples"]
    fibre_ends: str = DEFAULTS["fibre_ends"]
    fibre_radius_scale: float = DEFAULTS["fibre_radius_scale"]
    fibre_shells: str = DEFAULTS["fibre_shells"]
    warm_start: bool = DEFAULTS["warm_start"]
    guess: str = DEFAULTS["initial_guess"]
    measure_plans: bool = DEFAULTS["fft_plan"] == "measure"
    backend: str = DEFAULTS["backend"]
    rigidity: str = DEFAULTS["rigidity"]

    def __post_init__(self) -> None:
        if not self.eta_f > 0:
            raise InputError(f"eta_f: must be > 0, got {self.eta_f}")
        # the ranges of the scene's numerics.stokes keys (the registry's), under the bindings' names
        for key, path in (("kappa", "kappa"), ("tol", "tolerance"), ("max_iter", "max_iterations"),
                          ("subsamples", "subsamples"), ("fibre_radius_scale", "fibre_radius_scale")):
            if not _registry.in_range(f"numerics.stokes.{path}", getattr(self, key)):
                raise InputError(f"{key}: must be in {_registry.range_text(f'numerics.stokes.{path}')}, "
                                 f"got {getattr(self, key)}")
        for key, table in (("derivative", DERIVATIVES), ("mixing", MIXINGS), ("fibre_ends", FIBRE_ENDS),
                           ("fibre_shells", FIBRE_SHELLS),
                           ("guess", GUESSES), ("backend", BACKEND_CHOICES), ("rigidity", RIGIDITIES)):
            if getattr(self, key) not in table:
                raise InputError(f"{key}: must be one of {sorted(table)}, got {getattr(self, key)!r}")
        if self.backend not in (AUTO_BACKEND, backend_for(walls=False)):
            raise InputError(f"backend: these bindings solve fully periodic cells with the FFT solver; "
                             f"allowed: 'fft' or 'auto', got {self.backend!r} (walled cells run through "
                             f"fold_run, numerics.stokes.backend)")

    def codes(self) -> dict:
        return dict(eta_f=float(self.eta_f), kappa=float(self.kappa), tol=float(self.tol),
                    max_iter=int(self.max_iter), derivative=DERIVATIVES[self.derivative],
                    mixing=MIXINGS[self.mixing], plan_effort=int(self.measure_plans),
                    rigidity=RIGIDITIES[self.rigidity])


@dataclass
class Particles:
    """A particle set in the pyfold convention: ``x``, ``p`` of shape (N, dim).

    ``shape`` holds names (``"fibre"``, ``"sphere"``, ``"spheroid"``) or the codes
    1, 2, 3; ``length`` is the fibre length / spheroid major axis / 2R for spheres.
    """

    x: np.ndarray
    p: np.ndarray
    radius: np.ndarray
    length: np.ndarray
    shape: np.ndarray
    xi: np.ndarray = field(default=None)

    def __post_init__(self) -> None:
        self.x = np.atleast_2d(np.asarray(self.x, dtype=np.float64))
        n, dim = self.x.shape
        if dim not in (2, 3):
            raise InputError(f"x: expected shape (N, 2 or 3), got {self.x.shape}")
        self.p = np.atleast_2d(np.asarray(self.p, dtype=np.float64))
        if self.p.shape != (n, dim):
            raise InputError(f"p: expected shape {(n, dim)}, got {self.p.shape}")
        shp = np.atleast_1d(np.asarray(self.shape))
        if shp.dtype.kind in "US":
            unknown = set(shp.tolist()) - set(SHAPES)
            if unknown:
                raise InputError(f"shape: allowed {sorted(SHAPES)}, got {sorted(unknown)}")
            shp = np.array([SHAPES[s] for s in shp.tolist()])
        self.shape = np.broadcast_to(shp.astype(np.int32), (n,)).copy()
        self.radius = np.broadcast_to(np.asarray(self.radius, dtype=np.float64), (n,)).copy()
        self.length = np.broadcast_to(np.asarray(self.length, dtype=np.float64), (n,)).copy()
        self.xi = np.zeros(n) if self.xi is None else np.broadcast_to(np.asarray(self.xi, float), (n,)).copy()

    @property
    def dim(self) -> int:
        return self.x.shape[1]


@dataclass
class FlowSolution:
    """Result of one solve. ``stress`` is the deviatoric bulk stress ⟨2ηε(u)⟩ (3×3)."""

    u: np.ndarray
    stress: np.ndarray
    eta_eff: float
    eta_dissipation: float
    iterations: int
    residual: float
    history: np.ndarray
    chi: np.ndarray | None = None
    v: np.ndarray | None = None
    omega: np.ndarray | None = None
    rigidity: np.ndarray | None = None
    stress_particles: np.ndarray | None = None
    solid_strain: float | None = None
    solid_fraction: float | None = None


@dataclass
class MarchResult:
    """Histories of a time integration: ``x``, ``p`` of shape (nsteps + 1, N, dim);
    per-step ``iterations``, ``residual``, ``rigidity_max``, ``eta_eff``,
    ``solid_strain``, ``solid_fraction``, ``initial_residual`` (relative residual of
    the solve's initial guess) of shape (nsteps,)."""

    t: np.ndarray
    x: np.ndarray
    p: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    rigidity_max: np.ndarray
    eta_eff: np.ndarray
    solid_strain: np.ndarray
    solid_fraction: np.ndarray
    initial_residual: np.ndarray


def _grid(grid, dim: int) -> tuple[int, int, int]:
    g = tuple(int(v) for v in np.atleast_1d(grid))
    if len(g) != dim or any(v < 2 for v in g):
        raise InputError(f"grid: expected {dim} voxel counts >= 2, got {grid}")
    return g + (1,) * (3 - dim)


def _matrix(a, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.shape in ((2, 2), (3, 3)):
        out = np.eye(3) if name == "lattice" else np.zeros((3, 3))
        out[: a.shape[0], : a.shape[1]] = a
        return np.asfortranarray(out)
    raise InputError(f"{name}: expected shape (2, 2) or (3, 3), got {a.shape}")


def _lengths(lengths, dim: int) -> np.ndarray:
    L = np.asarray(lengths, dtype=np.float64)
    if L.shape != (dim,) or not np.all(L > 0):
        raise InputError(f"cell_lengths: expected {dim} positive lengths, got {lengths}")
    return np.concatenate([L, np.ones(3 - dim)])


def _simple_shear_cell(dim: int, cell_lengths, grid, shear_rate: float) -> tuple[tuple[int, ...], np.ndarray, np.ndarray]:
    """Voxel counts and cell lengths padded to 3-D, and the gradient ``G`` (3, 3) of
    simple shear ``u = shear_rate y e_x``."""
    n = _grid(grid, dim)
    L = _lengths(cell_lengths, dim)
    G = np.zeros((3, 3), order="F")
    G[0, 1] = float(shear_rate)
    return n, L, G


def solve_chi(chi, lattice, G, settings: StokesSettings | None = None) -> FlowSolution:
    """Solve the flow for a given characteristic function ``chi`` (no particles).

    Parameters
    ----------
    chi : (nx, ny) or (nx, ny, nz) solid fraction per voxel, in [0, 1].
    lattice : (d, d) lattice basis, columns a1..ad [m].
    G : (d, d) mean velocity gradient G_ij = ∂u_i/∂x_j [1/s].
    settings : StokesSettings.

    Raises
    ------
    InputError, ConvergenceError (with the residual reached).
    """
    s = settings or StokesSettings()
    chi = np.asarray(chi, dtype=np.float64)
    dim = chi.ndim
    if dim not in (2, 3) or min(chi.shape) < 2:
        raise InputError(f"chi: expected a 2-D or 3-D array with every size >= 2, got shape {chi.shape}")
    if np.any(chi < 0) or np.any(chi > 1):
        raise InputError("chi: values must lie in [0, 1]")
    A = _matrix(lattice, "lattice")
    if np.asarray(lattice).shape[0] != dim or np.asarray(G).shape[0] != dim:
        raise InputError(f"lattice, G: expected shape ({dim}, {dim}) for a {dim}-D chi")
    chi3 = np.asfortranarray(chi.reshape(chi.shape + (1,) * (3 - dim)))
    c = s.codes()
    ext = load("_fold_stokes")
    u, stress, eta_eff, eta_diss, it, res, hist, stat, msg = ext.fold_stokes_solve_chi(
        dim, A, _matrix(G, "G"), chi3, c["eta_f"], c["kappa"], c["tol"], c["max_iter"], c["derivative"],
        c["mixing"], c["plan_effort"], c["rigidity"])
    checked(stat, msg)
    return FlowSolution(u=u, stress=stress, eta_eff=float(eta_eff), eta_dissipation=float(eta_diss),
                        iterations=int(it), residual=float(res), history=hist[: int(it) + 1].copy())


def solve_particles(particles: Particles, cell_lengths, grid, shear_rate: float = 1.0, shear_offset: float = 0.0,
                    settings: StokesSettings | None = None, alpha: float = 0.0) -> FlowSolution:
    """Rigid velocities of particles in simple shear ``u = γ̇ (y − Ly/2) e_x`` (frame rule
    of ``fold_cell``) on the Lees–Edwards lattice with offset ``shear_offset``.
    ``alpha``: the contacts' security zone [m], the gap the added fibre shells keep with
    ``settings.fibre_shells = "apart"`` (as fold_run takes it from model.alpha).

    Returns the flow, χ, the rigid velocities ``v`` (N, dim) and ``omega`` (N, 3),
    the rigidity residual per particle and the bulk stress.
    """
    s = settings or StokesSettings()
    n, L, G = _simple_shear_cell(particles.dim, cell_lengths, grid, shear_rate)
    c = s.codes()
    ext = load("_fold_stokes")
    (chi, u, v, omega, rig, stress, sig_p, scal, it, hist, stat, msg) = ext.fold_stokes_solve_particles(
        n[0], n[1], n[2], L, float(shear_offset), G, particles.shape, particles.radius, particles.length,
        particles.xi, np.asfortranarray(particles.x.T), np.asfortranarray(particles.p.T), c["eta_f"], c["kappa"],
        c["tol"], c["max_iter"], c["derivative"], c["mixing"], int(s.subsamples), FIBRE_ENDS[s.fibre_ends],
        float(s.fibre_radius_scale), FIBRE_SHELLS[s.fibre_shells], float(alpha), c["plan_effort"], c["rigidity"])
    checked(stat, msg)
    return FlowSolution(u=u, stress=stress, eta_eff=float(scal[1]), eta_dissipation=float(scal[2]),
                        iterations=int(it), residual=float(scal[0]), history=hist[: int(it) + 1].copy(), chi=chi,
                        v=v.T.copy(), omega=omega.T.copy(), rigidity=rig, stress_particles=sig_p,
                        solid_strain=float(scal[3]), solid_fraction=float(scal[4]))


def march(particles: Particles, cell_lengths, grid, dt: float, nsteps: int, shear_rate: float = 1.0,
          t0: float = 0.0, scheme: str = "ab2", settings: StokesSettings | None = None) -> MarchResult:
    """Integrate particles in simple shear with the Stokes rigid velocities.

    ``scheme``: ``"euler"`` (first order) or ``"ab2"`` (Adams–Bashforth 2, first step
    Euler; second order). Rotations are exact (Rodrigues); positions are wrapped
    into the Lees–Edwards cell.
    """
    s = settings or StokesSettings()
    if scheme not in SCHEMES:
        raise InputError(f"scheme: must be one of {sorted(SCHEMES)}, got {scheme!r}")
    if not dt > 0 or int(nsteps) < 1:
        raise InputError(f"dt, nsteps: need dt > 0 and nsteps >= 1, got {dt}, {nsteps}")
    n, L, G = _simple_shear_cell(particles.dim, cell_lengths, grid, shear_rate)
    c = s.codes()
    ext = load("_fold_stokes")
    xh, ph, rec, stat, msg = ext.fold_stokes_march(
        n[0], n[1], n[2], int(nsteps), L, G, float(t0), float(dt), SCHEMES[scheme], particles.shape,
        particles.radius, particles.length, particles.xi, np.asfortranarray(particles.x.T),
        np.asfortranarray(particles.p.T), c["eta_f"], c["kappa"], c["tol"], c["max_iter"], c["derivative"],
        c["mixing"], int(s.subsamples), FIBRE_ENDS[s.fibre_ends], float(s.fibre_radius_scale),
        GUESSES[s.guess] if s.warm_start else 0,
        c["plan_effort"], c["rigidity"])
    checked(stat, msg)
    return MarchResult(t=t0 + dt * np.arange(nsteps + 1), x=np.transpose(xh, (2, 1, 0)),
                       p=np.transpose(ph, (2, 1, 0)), iterations=rec[0].astype(int), residual=rec[1],
                       rigidity_max=rec[2], eta_eff=rec[3], solid_strain=rec[4], solid_fraction=rec[5],
                       initial_residual=rec[6])
