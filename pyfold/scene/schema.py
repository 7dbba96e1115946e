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

Every field that is not a table is a setting of the registry
(:mod:`pyfold.scene.registry`): its type, range, words and default are built from
there by :func:`_registered` and :func:`_default`.
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

#: Bounds shared with pyfold.scene.normalise; declared with the settings (pyfold/scene/registry.py).
EQUIVALENT_ASPECT_RATIO_DEFAULT = registry.EQUIVALENT_ASPECT_RATIO_DEFAULT
MAGNITUDE_LIMIT = registry.MAGNITUDE_LIMIT
MAX_LENGTH_RATIO = registry.MAX_LENGTH_RATIO
MAX_PARTICLES_PER_FAMILY = registry.MAX_PARTICLES_PER_FAMILY


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


def _bounded(s: registry.Setting, kind: str):
    """A number within the setting's range (strict; a real finite)."""
    bounds = {}
    if s.lo is not None:
        bounds["gt" if s.lo_open else "ge"] = s.lo
    if s.hi is not None:
        bounds["lt" if s.hi_open else "le"] = s.hi
    if kind == "integer":
        return Annotated[int, Field(**bounds)]
    if bounds:
        return Annotated[float, Field(**bounds), AfterValidator(_finite)]
    return Annotated[float, AfterValidator(_finite)]


def _sized(size: tuple[int | None, int | None] | None, **extra) -> dict:
    """Field arguments of a length bound (fewest, most) and any others."""
    lo, hi = size or (None, None)
    return {**({} if lo is None else {"min_length": lo}), **({} if hi is None else {"max_length": hi}), **extra}


#: a data file named in a scene (``.csv`` or ``.npy``), relative to the scene file
FilePath = Annotated[str, Field(min_length=1, max_length=registry.FILE_PATH_MAX)]


def _registered(path: str):
    """The field type of the registered setting at TOML ``path`` (pyfold/scene/registry.py):
    its words, its allowed integers, its type within its range (strict, finite), its
    vector or matrix of such reals (or the data file holding it), or its text."""
    s = registry.setting(path)
    if s.kind == "choice":
        return Literal[s.choices]
    if s.kind == "bool":
        return bool
    if s.kind == "integer" and s.values:
        return Annotated[int, AfterValidator(_one_of(*s.values))]
    if s.kind in ("integer", "real"):
        return _bounded(s, s.kind)
    if s.kind == "text":
        return Annotated[str, Field(**_sized(s.size, **({"pattern": s.pattern} if s.pattern else {})))]
    vector = Annotated[list[_bounded(s, "real")], Field(**_sized(s.size))]
    if s.kind == "vector":
        return vector
    matrix = Annotated[list[vector], Field(**_sized(s.rows))] if s.rows else list[vector]
    return matrix | FilePath if s.file else matrix


def _default(path: str):
    """The registered default of the setting at ``path``."""
    return registry.default(path)


class _Table(BaseModel):
    """A TOML table: strict types, unknown keys rejected, values frozen once read."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


class Cell(_Table):
    """The computational cell."""

    #: 2 or 3 (a strict integer: 3.0 is rejected like every non-integer for an integer key)
    dim: _registered("cell.dim") = _default("cell.dim")
    #: Side lengths (Lx, Ly[, Lz]), one per dimension [m]
    size: _registered("cell.size")
    #: "periodic" on every side, or "couette": no-slip walls at y = 0 and y = Ly
    #: moving at -U and +U (U = rate * Ly / 2), periodic in x (and z)
    boundary: _registered("cell.boundary") = _default("cell.boundary")


class Flow(_Table):
    """The imposed mean flow ``u = G . x``."""

    type: _registered("flow.type") = _default("flow.type")
    #: simple shear: G_xy = rate; planar elongation: G = diag(rate, -rate[, 0]);
    #: uniaxial elongation: G = diag(rate, -rate/2, -rate/2) [1/s]
    rate: _registered("flow.rate") | None = None
    #: the full velocity gradient G_ij = du_i/dx_j (dim x dim, traceless), type = "general" only [1/s]
    gradient: _registered("flow.gradient") | None = None


class Fluid(_Table):
    """The suspending Newtonian fluid."""

    #: dynamic viscosity [Pa s]
    viscosity: _registered("fluid.viscosity") = _default("fluid.viscosity")


class ParticleFamily(_Table):
    """One family of identical particles."""

    #: label used in outputs (default "family<index>")
    name: _registered("particles.name") | None = None
    shape: _registered("particles.shape")
    #: fibre cross-section radius, sphere radius, spheroid minor semi-axis [m]
    radius: _registered("particles.radius")
    #: fibre (cylinder) length or spheroid major axis; not for spheres [m]
    length: _registered("particles.length") | None = None
    #: length / (2 radius), an alternative to `length`; not for spheres [-]
    aspect_ratio: _registered("particles.aspect_ratio") | None = None
    #: number of particles (give exactly one of count, volume_fraction)
    count: _registered("particles.count") | None = None
    #: fraction of the cell volume (area in 2-D) the family fills [-]
    volume_fraction: _registered("particles.volume_fraction") | None = None
    orientation: _registered("particles.orientation") = _default("particles.orientation")
    #: axis of every particle for orientation = "aligned" (normalised; default the flow direction x)
    direction: _registered("particles.direction") | None = None
    #: one axis per particle (count x dim) for orientation = "given" (each normalised), inline
    #: or a .csv / .npy file (path relative to the scene file, one row per particle)
    orientations: _registered("particles.orientations") | None = None
    #: given centres, one per particle (n x dim) [m], inline or a .csv / .npy file (path
    #: relative to the scene file, one row per particle; a CSV may start with a header line):
    #: no random placement, the count is the number of rows
    positions: _registered("particles.positions") | None = None
    #: finite cylinders only: rule giving the equivalent spheroid aspect ratio
    #: (Cox 1971, Zhang et al. 2011, Harris & Pittman 1975)
    equivalent_aspect_ratio: _registered("particles.equivalent_aspect_ratio") | None = None


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
    #: radius of the voxelised fibre over its geometric radius (a hydrodynamic radius calibrated
    #: to the grid, studies/interaction_coefficient/grid_fibre_shape.py); contacts, volume
    #: fraction and the Jeffery shape factor keep the geometric radius [-]
    fibre_radius_scale: _registered("numerics.stokes.fibre_radius_scale") = _default("numerics.stokes.fibre_radius_scale")
    #: with fibre_radius_scale > 1, the added shells of near fibres: "overlap" (coverages add up) or
    #: "apart" (each shell ends the security zone alpha short of the other particle's geometric surface)
    fibre_shells: _registered("numerics.stokes.fibre_shells") = _default("numerics.stokes.fibre_shells")
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
    #: velocities between solves: extrapolated solves, or Jeffery plus extrapolated departures
    reuse: _registered("numerics.stokes.reuse") = _default("numerics.stokes.reuse")


class Numerics(_Table):
    """Time stepping and solver settings."""

    #: time step [s]; required unless preset = "study" chooses it
    dt: _registered("numerics.dt") | None = None
    #: end time; a multiple of dt [s]
    t_end: _registered("numerics.t_end")
    #: seed of every random draw (placement, orientations)
    seed: _registered("numerics.seed") = _default("numerics.seed")
    #: time scheme of the Stokes rigid velocities: "ab2" (Adams-Bashforth 2, first step
    #: Euler; second order) or "euler" (explicit Euler, the seed's). Rotations are exact
    #: either way. Jeffery hydrodynamics ignores it (exact propagator for constant G).
    time_scheme: _registered("numerics.time_scheme") = _default("numerics.time_scheme")
    #: "study": the numerical settings the scene leaves unset (dt, and for a Stokes-coupled
    #: run the solver's kappa, tolerance, precision, solve reuse and resolution) chosen by their
    #: measured effect on C_I (pyfold/scene/study_preset.py); absent: each key's own default
    #: (absent rather than a word, so the normalised scene, and a sweep run's identity, of a
    #: scene without a preset are what they were before the key existed)
    preset: _registered("numerics.preset") | None = None
    stokes: StokesSettings = StokesSettings()


class Output(_Table):
    """What the run file records and how often (times are multiples of numerics.dt)."""

    #: interval between records of the statistics (a2, a4, contact and drift counters) [s]
    #: (default: t_end / 100 rounded down to a multiple of dt)
    interval: _registered("output.interval") | None = None
    #: interval between particle snapshots (positions, axes); 0 = none
    #: (default: t_end / 10 rounded down to a multiple of dt) [s]
    snapshot_interval: _registered("output.snapshot_interval") | None = None
    #: interval between restart checkpoints; 0 = none
    #: (default: t_end / 20 rounded down to a multiple of dt) [s]
    checkpoint_interval: _registered("output.checkpoint_interval") | None = None


class Scene(_Table):
    """A complete scene: what ``pyfold run`` simulates."""

    title: _registered("title") = _default("title")
    description: _registered("description") = _default("description")
    cell: Cell
    flow: Flow
    fluid: Fluid = Fluid()
    particles: Annotated[list[ParticleFamily], Field(min_length=1, max_length=64)]
    model: Model = Model()
    numerics: Numerics
    output: Output = Output()
