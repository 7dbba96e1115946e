"""The scene file's schema: one pydantic model per TOML table.

Field-level rules (types, ranges, allowed words, unknown keys) live here; rules
that tie several keys together (a 2-D cell with a 3-D gradient, walls with an
elongational flow, a volume fraction beyond random packing, ...) live in
:mod:`pyfold.scene.checks`, so that every error can name its own key path.

Types are strict: ``"1.0"`` is not a number and ``1.5`` or ``3.0`` is not an
integer (every integer key, ``cell.dim`` included); an integer is accepted where a
real is expected. Units: SI or any consistent set (Stokes flow is linear), see
``docs/scenes.md``; every dimensional value stays within :data:`MAGNITUDE_LIMIT`
of 1 so that the arithmetic on it stays finite.
"""
from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from pyfold.scene import registry

__all__ = [
    "Cell",
    "Flow",
    "Fluid",
    "ParticleFamily",
    "Model",
    "StokesSettings",
    "Numerics",
    "Output",
    "Scene",
    "EQUIVALENT_ASPECT_RATIO_DEFAULT",
    "MAGNITUDE_LIMIT",
    "MAX_LENGTH_RATIO",
    "MAX_PARTICLES_PER_FAMILY",
]

#: Default rule for the equivalent aspect ratio of a finite cylinder: Cox (1971,
#: J. Fluid Mech. 45:625) slender-body result ``beta_e = 1.24 beta / sqrt(ln beta)``,
#: the classic choice for long fibres (docs/physics.md#equivalent-aspect-ratio-of-a-finite-cylinder).
EQUIVALENT_ASPECT_RATIO_DEFAULT = "cox"


#: Every dimensional value (lengths [m], rates [1/s], viscosity [Pa s]) must lie within
#: 30 decades of 1: any consistent unit system works (SI fibres are ~1e-5 m, lengths in
#: fibre lengths are ~1), and then a volume (L^3, <= 1e90) or a product of a few such
#: values stays finite and normal in double precision (limits 1e+-308).
MAGNITUDE_LIMIT = 1e30
#: its reciprocal, the smallest length or viscosity
_SMALLEST = 1e-30

#: Largest ratio of the longest cell side to the smallest particle radius (and so of any
#: two lengths of a scene: every particle must fit in half the cell). 1e6 radii per side
#: is far beyond any simulation (the Stokes grid, the cell lists, the particle count all
#: scale with it); it keeps cell / particle volume ratios <= 1e18 and grid sizes finite.
MAX_LENGTH_RATIO = 1e6

#: Largest number of particles of one family: ``count``, or the count a
#: ``volume_fraction`` gives (one cap, applied to both).
MAX_PARTICLES_PER_FAMILY = 10_000_000


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError("must be a finite number (not nan or inf)")
    return value


def _one_of(*allowed: int):
    def check(value: int) -> int:
        if value not in allowed:
            raise ValueError(f"must be {' or '.join(map(str, allowed))}")
        return value
    return check


def _registered(path: str):
    """The field type of the registered setting at TOML ``path`` (pyfold/scene/registry.py):
    its words, or its type within its range (strict, finite)."""
    s = registry.setting(path)
    if s.kind == "choice":
        return Literal[s.choices]
    if s.kind == "bool":
        return bool
    bounds = {}
    if s.lo is not None:
        bounds["gt" if s.lo_open else "ge"] = s.lo
    if s.hi is not None:
        bounds["lt" if s.hi_open else "le"] = s.hi
    if s.kind == "integer":
        return Annotated[int, Field(**bounds)]
    return Annotated[float, Field(**bounds), AfterValidator(_finite)]


def _default(path: str):
    """The registered default of the setting at ``path``."""
    return registry.default(path)


Real = Annotated[float, AfterValidator(_finite)]
PositiveReal = Annotated[float, Field(gt=0), AfterValidator(_finite)]
NonNegativeReal = Annotated[float, Field(ge=0), AfterValidator(_finite)]
#: a length [m]: 1e-30 <= value <= MAGNITUDE_LIMIT
Length = Annotated[float, Field(ge=_SMALLEST, le=MAGNITUDE_LIMIT), AfterValidator(_finite)]
#: a rate or velocity gradient entry [1/s]: |value| <= MAGNITUDE_LIMIT
Rate = Annotated[float, Field(ge=-MAGNITUDE_LIMIT, le=MAGNITUDE_LIMIT), AfterValidator(_finite)]
Vector = Annotated[list[Real], Field(min_length=2, max_length=3)]
#: a data file named in a scene (``.csv`` or ``.npy``), relative to the scene file
FilePath = Annotated[str, Field(min_length=1, max_length=4096)]
RateVector = Annotated[list[Rate], Field(min_length=2, max_length=3)]


class _Table(BaseModel):
    """A TOML table: strict types, unknown keys rejected, values frozen once read."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


class Cell(_Table):
    """The computational cell."""

    #: 2 or 3 (a strict integer: 3.0 is rejected like every non-integer for an integer key)
    dim: Annotated[int, AfterValidator(_one_of(2, 3))] = 3
    #: Side lengths (Lx, Ly[, Lz]), one per dimension [m]
    size: Annotated[list[Length], Field(min_length=2, max_length=3)]
    #: "periodic" on every side, or "couette": no-slip walls at y = 0 and y = Ly
    #: moving at -U and +U (U = rate * Ly / 2), periodic in x (and z)
    boundary: Literal["periodic", "couette"] = "periodic"


class Flow(_Table):
    """The imposed mean flow ``u = G . x``."""

    type: Literal["simple_shear", "planar_elongation", "uniaxial_elongation", "general"] = "simple_shear"
    #: simple shear: G_xy = rate; planar elongation: G = diag(rate, -rate[, 0]);
    #: uniaxial elongation: G = diag(rate, -rate/2, -rate/2) [1/s]
    rate: Rate | None = None
    #: the full velocity gradient G_ij = du_i/dx_j (dim x dim, traceless), type = "general" only [1/s]
    gradient: Annotated[list[RateVector], Field(min_length=2, max_length=3)] | None = None


class Fluid(_Table):
    """The suspending Newtonian fluid."""

    #: dynamic viscosity [Pa s]
    viscosity: Annotated[float, Field(ge=_SMALLEST, le=MAGNITUDE_LIMIT), AfterValidator(_finite)] = 1.0


class ParticleFamily(_Table):
    """One family of identical particles."""

    #: label used in outputs (default "family<index>")
    name: Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.+-]+$")] | None = None
    shape: _registered("particles.shape")
    #: fibre cross-section radius, sphere radius, spheroid minor semi-axis [m]
    radius: Length
    #: fibre (cylinder) length or spheroid major axis; not for spheres [m]
    length: Length | None = None
    #: length / (2 radius), an alternative to `length`; not for spheres [-]
    aspect_ratio: Annotated[float, Field(gt=0, le=MAX_LENGTH_RATIO), AfterValidator(_finite)] | None = None
    #: number of particles (give exactly one of count, volume_fraction)
    count: Annotated[int, Field(ge=1, le=MAX_PARTICLES_PER_FAMILY)] | None = None
    #: fraction of the cell volume (area in 2-D) the family fills [-]
    volume_fraction: Annotated[float, Field(gt=0, lt=1), AfterValidator(_finite)] | None = None
    orientation: Literal["isotropic", "aligned", "planar_random", "given"] = "isotropic"
    #: axis of every particle for orientation = "aligned" (normalised; default the flow direction x)
    direction: Vector | None = None
    #: one axis per particle (count x dim) for orientation = "given" (each normalised), inline
    #: or a .csv / .npy file (path relative to the scene file, one row per particle)
    orientations: list[Vector] | FilePath | None = None
    #: given centres, one per particle (n x dim) [m], inline or a .csv / .npy file (path
    #: relative to the scene file, one row per particle; a CSV may start with a header line):
    #: no random placement, the count is the number of rows
    positions: list[Vector] | FilePath | None = None
    #: finite cylinders only: rule giving the equivalent spheroid aspect ratio
    #: (Cox 1971, Zhang et al. 2011, Harris & Pittman 1975)
    equivalent_aspect_ratio: Literal["cox", "zhang", "harris_pittman"] | None = None


class Model(_Table):
    """Physical model of the direct simulation."""

    #: "auto" (chosen from the regime), "jeffery" (imposed-flow kinematics) or "stokes"
    hydrodynamics: _registered("model.hydrodynamics") = _default("model.hydrodynamics")
    #: "auto" (chosen from the regime), "strategy" (seed loop with cell lists),
    #: "naive" (same rule, O(N^2) reference) or "none"
    collisions: _registered("model.collisions") = _default("model.collisions")
    #: security zone alpha [m] (default: a tenth of the smallest particle radius)
    alpha: _registered("model.alpha") | None = None
    #: cap on contact-correction iterations per step
    contact_max_iter: _registered("model.contact_max_iter") = _default("model.contact_max_iter")
    #: what to do when the cap is hit: "stop" the run (status failed) or "continue" and count it
    on_contact_cap: _registered("model.on_contact_cap") = _default("model.on_contact_cap")
    #: sphere-sphere lubrication force (docs/physics.md#lubrication-between-spheres); spheres only
    lubrication: _registered("model.lubrication") = _default("model.lubrication")


class StokesSettings(_Table):
    """Settings of the fictitious-domain Stokes solver (``fortran/stokes``).

    Types, ranges, words and defaults come from the settings registry
    (pyfold/scene/registry.py), the one place the bindings and fold_run take them from
    too; every field below that changes results is written to ``/setup/resolved`` and
    read from there by ``fold_run``.
    """

    #: Stokes backend: "fft" (FFT-preconditioned CG on the periodic, Lees-Edwards cell),
    #: "hypre" (staggered grid with no-slip walls: cell.boundary = "couette" only) or
    #: "auto" (hypre when the cell has walls, fft otherwise; pyfold.native.stokes.backend_for)
    backend: _registered("numerics.stokes.backend") = _default("numerics.stokes.backend")
    #: relative (preconditioned) residual at which the conjugate-gradient solve stops [-]
    tolerance: _registered("numerics.stokes.tolerance") = _default("numerics.stokes.tolerance")
    #: CG iteration cap per solve; reaching it stops the run (exit 1, residual reached)
    max_iterations: _registered("numerics.stokes.max_iterations") = _default("numerics.stokes.max_iterations")
    #: viscosity contrast of the penalisation eta_solid / eta_fluid (seed: 1e3); rigidity
    #: error ~ 1/kappa, CG iterations ~ sqrt(kappa) (docs/physics.md#fictitious-domain-penalisation,
    #: docs/physics.md#solver-vs-contrast); at most kappa_max ~ 1/tolerance of the grid and
    #: precision (pyfold/scene/kappa_range.py, docs/physics.md#how-large-a-penalty-the-solver-can-carry) [-]
    kappa: _registered("numerics.stokes.kappa") = _default("numerics.stokes.kappa")
    #: grid cells per diameter of the thinnest particle (4-8, docs/physics.md#resolution) [-]
    cells_per_diameter: _registered("numerics.stokes.cells_per_diameter") = _default("numerics.stokes.cells_per_diameter")
    #: largest Stokes grid (voxel count) allowed: "auto" falls back to jeffery above it,
    #: an explicit "stokes" is rejected (default 64^3; memory ~ 0.27 kB per point in 3-D)
    max_grid_points: _registered("numerics.stokes.max_grid_points") = _default("numerics.stokes.max_grid_points")
    #: derivative scheme: "fd" (rotated finite differences, Willot 2015; no Gibbs ringing)
    #: or "spectral" (i k, Nyquist modes removed)
    derivative: _registered("numerics.stokes.derivative") = _default("numerics.stokes.derivative")
    #: viscosity of a partially covered voxel: "harmonic" 1/eta = (1-chi)/eta_f + chi/(kappa eta_f),
    #: "arithmetic" eta_f (1 + (kappa-1) chi) (inflates particles by ~h/2) or "geometric"
    #: eta_f kappa^chi (docs/physics.md#viscosity-of-partially-covered-voxels)
    mixing: _registered("numerics.stokes.mixing") = _default("numerics.stokes.mixing")
    #: sub-samples per voxel edge of the partial-volume chi (1..8) [-]
    subsamples: _registered("numerics.stokes.subsamples") = _default("numerics.stokes.subsamples")
    #: fibre ends of the voxelised particle: "flat" cylinder or "capped" (the contact capsule)
    fibre_ends: _registered("numerics.stokes.fibre_ends") = _default("numerics.stokes.fibre_ends")
    #: start each CG solve from the previous solution (see initial_guess) or from zero
    warm_start: _registered("numerics.stokes.warm_start") = _default("numerics.stokes.warm_start")
    #: FFTW planning: "measure" (faster transforms, plans timed at start-up; repeated runs
    #: agree to the solver tolerance) or "estimate" (bitwise reproducible)
    fft_plan: _registered("numerics.stokes.fft_plan") = _default("numerics.stokes.fft_plan")
    #: precision of the FFTs of the CG operator: "double" or "single" (single-precision
    #: transforms inside the double-precision CG, 1.3-1.4x cheaper iterations; fold_run refuses
    #: a tolerance below (2 log2 N + 4) 2^-24 for N voxels, docs/physics.md)
    fft_precision: _registered("numerics.stokes.fft_precision") = _default("numerics.stokes.fft_precision")
    #: rigidity of the particles: "penalty" (the seed's viscosity kappa eta_f in the solid;
    #: rigidity error ~ 1/kappa, CG iterations ~ sqrt(kappa)) or "exact" (eps(u) = 0 on the
    #: voxels covered at least half, imposed by a multiplier, the others with the harmonic
    #: mixing's kappa -> infinity viscosity; no kappa; the CG tolerance is the rigidity
    #: error; fft backend, double precision; docs/physics.md#exact-rigidity)
    rigidity: _registered("numerics.stokes.rigidity") = _default("numerics.stokes.rigidity")
    #: initial guess of each CG solve: "previous" (the last step's solution) or
    #: "extrapolate" (2 u_n - u_(n-1) of the last two solutions); measured by
    #: benchmarks/bench_stokes_step.py (2 % fewer iterations on the dense-fibre scene)
    initial_guess: _registered("numerics.stokes.initial_guess") = _default("numerics.stokes.initial_guess")
    #: a Stokes solve every k-th step only; in between the rigid velocities are the linear
    #: extrapolation in time of the last two solves (contacts still every step). A
    #: speed-accuracy setting (benchmarks/bench_stokes_step.py); 1 = a solve every step
    solve_every: _registered("numerics.stokes.solve_every") = _default("numerics.stokes.solve_every")


class Numerics(_Table):
    """Time stepping and solver settings."""

    #: time step [s]
    dt: PositiveReal
    #: end time; a multiple of dt [s]
    t_end: PositiveReal
    #: seed of every random draw (placement, orientations)
    seed: _registered("numerics.seed") = _default("numerics.seed")
    #: time scheme of the Stokes rigid velocities: "ab2" (Adams-Bashforth 2, first step
    #: Euler; second order) or "euler" (explicit Euler, the seed's). Rotations are exact
    #: either way. Jeffery hydrodynamics ignores it (exact propagator for constant G).
    time_scheme: _registered("numerics.time_scheme") = _default("numerics.time_scheme")
    stokes: StokesSettings = StokesSettings()


class Output(_Table):
    """What the run file records and how often (times are multiples of numerics.dt)."""

    #: interval between records of the statistics (a2, a4, contact and drift counters) [s]
    #: (default: t_end / 100 rounded down to a multiple of dt)
    interval: PositiveReal | None = None
    #: interval between particle snapshots (positions, axes); 0 = none
    #: (default: t_end / 10 rounded down to a multiple of dt) [s]
    snapshot_interval: NonNegativeReal | None = None
    #: interval between restart checkpoints; 0 = none
    #: (default: t_end / 20 rounded down to a multiple of dt) [s]
    checkpoint_interval: NonNegativeReal | None = None


class Scene(_Table):
    """A complete scene: what ``pyfold run`` simulates."""

    title: Annotated[str, Field(max_length=200)] = ""
    description: Annotated[str, Field(max_length=4000)] = ""
    cell: Cell
    flow: Flow
    fluid: Fluid = Fluid()
    particles: Annotated[list[ParticleFamily], Field(min_length=1, max_length=64)]
    model: Model = Model()
    numerics: Numerics
    output: Output = Output()
