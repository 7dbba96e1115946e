"""Consistency checks and normalisation: a parsed :class:`Scene` -> :class:`ResolvedScene`.

Everything Fortran needs is computed here once (counts from volume fractions,
Jeffery shape factors, step counts, ``auto`` choices with their reason), so the
run file's ``/setup/resolved`` group is a plain table of numbers with units.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pyfold.errors import InputError
from pyfold.files import regular_file
from pyfold.native import stokes as stokes_codes
from pyfold.scene import registry, shapes
from pyfold.scene._problems import Problems
from pyfold.scene.hydrodynamics_evidence import auto_evidence
from pyfold.scene.kappa_range import check_kappa
from pyfold.scene.vectors import unit_rows
from pyfold.scene.registry import EQUIVALENT_ASPECT_RATIO_DEFAULT, MAX_LENGTH_RATIO, MAX_PARTICLES_PER_FAMILY
from pyfold.scene.schema import Scene

__all__ = ["Family", "ResolvedScene", "normalise", "stokes_grid", "backend_mismatch", "HYDRODYNAMICS_CODES",
           "COLLISION_CODES", "SPHERE_INTERACTION_FRACTION"]

# code tables of /setup/resolved: views of the settings registry (pyfold/scene/registry.py)
HYDRODYNAMICS_CODES = registry.codes("model.hydrodynamics")
#: Spheres: hydrodynamic interactions "matter" for ``auto`` from this total volume
#: fraction on. Batchelor & Green (1972, J. Fluid Mech. 56:401):
#: eta/eta_f = 1 + 2.5 phi + 6.2 phi^2; the pair term is 2.48 phi of the single-particle
#: (Einstein) term, i.e. >= 12 % from phi = 0.05.
SPHERE_INTERACTION_FRACTION = 0.05
COLLISION_CODES = registry.codes("model.collisions")
ON_CAP_CODES = registry.codes("model.on_contact_cap")

#: Relative tolerance for "is a multiple of dt" (times given in decimal notation).
MULTIPLE_TOL = 1e-9
#: Default security zone as a fraction of the smallest particle radius (the registry's).
DEFAULT_ALPHA_OVER_RADIUS = registry.DEFAULT_ALPHA_OVER_RADIUS
#: Default number of statistics records and of snapshots over a run.
DEFAULT_RECORDS, DEFAULT_SNAPSHOTS = 100, 10
#: Restart checkpoints of a run by default: one every 1/20 of it, so a killed long run
#: loses at most 5 % of its steps (a checkpoint writes the particle state twice,
#: fold_output.f90: cheap next to the steps between two of them).
DEFAULT_CHECKPOINTS = 20
#: Largest number of time steps (fold_run counts steps in 32-bit integers).
MAX_STEPS = 2**31 - 1
#: Double precision round-off unit.
_EPS = float(np.finfo(np.float64).eps)
#: Smallest strain per step max|G_ij| dt: a step must move a particle at the far side
#: of the cell by at least a thousand round-off units of its position (below ~eps the
#: update x + G.x dt == x and nothing moves) [-].
MIN_STRAIN_PER_STEP = 1e3 * _EPS
#: Largest total strain max|G_ij| t_end: beyond 1/eps the Lees-Edwards offset (or the
#: deformed lattice) gamma L has lost every digit of a particle position [-].
MAX_STRAIN = 1.0 / _EPS
#: Stokes resolution below which `pyfold validate` and `pyfold run` warn: 4-8 voxels per
#: diameter for quantitative results (docs/physics.md#resolution; at 1-2 voxels per
#: diameter the effective viscosity is biased by 5-9 %).
STOKES_QUANTITATIVE_CELLS_PER_DIAMETER = 4
#: Lubrication threshold gap h_c in voxel widths: LUB_THRESHOLD_VOXELS of
#: fortran/contact/fold_lubrication.f90 (tests/micro/test_run_lubrication.py keeps the two equal)
LUBRICATION_THRESHOLD_VOXELS = 2.0
#: Most time steps the admissibility check of a deforming lattice visits one by one
#: (the native loop takes ~0.3 s per million); beyond, every k-th step with a margin.
LATTICE_CHECK_SAMPLES = 1_000_000


#: The numerics.stokes datasets of /setup/resolved, in the order they are written.
_STOKES_DATASETS = ("stokes_backend", "stokes_tolerance", "stokes_max_iterations", "stokes_kappa", "stokes_derivative",
                    "stokes_fft_plan", "stokes_mixing", "stokes_subsamples", "stokes_fibre_ends", "stokes_warm_start",
                    "stokes_initial_guess", "stokes_fft_precision", "stokes_rigidity", "stokes_solve_every",
                    "stokes_fibre_radius_scale", "stokes_reuse", "stokes_fibre_shells")


def _dataset(name: str, value) -> tuple[object, str, str]:
    """``(value, units, long_name)`` of the registered /setup/resolved dataset ``name``: a
    word as its code, an integer or bool as int32, a real as it is."""
    s = registry.resolved(name)
    if s.kind == "choice":
        return np.int32(s.codes[value]), s.units, s.legend
    if s.kind in ("integer", "bool"):
        return np.int32(value), s.units, s.legend
    return float(value), s.units, s.legend


@dataclass(frozen=True)
class Family:
    """One particle family after normalisation."""

    index: int
    name: str
    shape: str
    radius: float
    length: float  # cylinder length, spheroid major axis, 2R for spheres [m]
    aspect_ratio: float  # length / (2 radius) [-]
    equivalent_aspect_ratio: float  # beta_e of the Jeffery equation [-]
    xi: float  # Jeffery shape factor [-]
    count: int
    volume_fraction: float  # actual fraction of the cell the count fills [-]
    orientation: str
    axes: np.ndarray | None = None  # given or aligned axes, normalised; (count, dim) when positions are given
    positions: np.ndarray | None = None  # given centres (count, dim) [m]: no random placement

    @property
    def shape_code(self) -> int:
        return shapes.SHAPE_CODES[self.shape]


@dataclass(frozen=True)
class ResolvedScene:
    """A validated scene with every default filled in and every choice made."""

    scene: Scene  # the normalised scene (itself a valid scene)
    dim: int
    cell_lengths: np.ndarray  # (3,), Lz = 0 in 2-D [m]
    walls: bool
    wall_speed: float  # U: the walls at y = 0, Ly move at -U, +U [m/s]
    velocity_gradient: np.ndarray  # (3, 3) G_ij = du_i/dx_j [1/s]
    shear_rate: float  # sqrt(2 D:D) [1/s]
    viscosity: float
    dt: float
    t_end: float
    n_steps: int
    seed: int
    hydrodynamics: str
    collisions: str
    reason: str
    alpha: float
    contact_max_iter: int
    on_contact_cap: str
    lubrication: bool
    output_every: int
    snapshot_every: int
    checkpoint_every: int
    families: tuple[Family, ...]
    regime: str
    regime_measure: float  # n L^dim
    regime_threshold: float  # L/d of the longest family
    warnings: tuple[str, ...] = field(default=())
    stokes_grid: tuple[int, int, int] | None = None  # voxel counts (n3 = 1 in 2-D), stokes only
    toml: str = ""  # the scene file verbatim, when read from TOML
    preset_reason: str = ""  # numerics.preset = "study": what it chose, and the evidence

    @property
    def n_particles(self) -> int:
        return sum(f.count for f in self.families)

    def scene_json(self) -> str:
        """The normalised scene as JSON (what ``/setup/scene_json`` stores)."""
        return json.dumps(self.scene.model_dump(mode="json", exclude_none=True), indent=1)

    def resolved_datasets(self) -> dict[str, tuple[object, str, str]]:
        """``name -> (value, units, long_name)`` of the run file's ``/setup/resolved`` group."""
        fams = self.families
        return {
            "dim": _dataset("dim", self.dim),
            "cell_lengths": (self.cell_lengths, "m", "cell side lengths (Lx, Ly, Lz); Lz = 0 in 2-D"),
            "walls": (np.int32(self.walls), "1", "1: no-slip walls at y = 0 and y = Ly (Couette), 0: periodic"),
            "wall_speed": (self.wall_speed, "m/s", "walls at y = 0 and y = Ly move at -U and +U along x"),
            "velocity_gradient": (self.velocity_gradient, "1/s", "imposed velocity gradient G_ij = du_i/dx_j"),
            "shear_rate": (self.shear_rate, "1/s", "scalar deformation rate sqrt(2 D:D)"),
            "viscosity": _dataset("viscosity", self.viscosity),
            "dt": _dataset("dt", self.dt),
            "t_end": _dataset("t_end", self.t_end),
            "n_steps": (np.int32(self.n_steps), "1", "number of time steps, t_end / dt"),
            "seed": _dataset("seed", self.seed),
            "hydrodynamics": _dataset("hydrodynamics", self.hydrodynamics),
            "hydrodynamics_reason": (self.reason, "", "what was chosen for hydrodynamics and collisions, and why"),
            **({"numerics_preset_reason": (self.preset_reason, "", "numerics.preset: the numerical settings it "
                                           "chose, and the measured evidence")} if self.preset_reason else {}),
            "scene_warnings": ("\n".join(self.warnings), "", "what pyfold validate warned about (one per line)"),
            "collisions": _dataset("collisions", self.collisions),
            "alpha": _dataset("alpha", self.alpha),
            "contact_max_iter": _dataset("contact_max_iter", self.contact_max_iter),
            "on_contact_cap": _dataset("on_contact_cap", self.on_contact_cap),
            "lubrication": _dataset("lubrication", self.lubrication),
            "output_every": (np.int32(self.output_every), "1", "steps between statistics records"),
            "snapshot_every": (np.int32(self.snapshot_every), "1", "steps between snapshots, 0 = none"),
            "checkpoint_every": (np.int32(self.checkpoint_every), "1", "steps between checkpoints, 0 = none"),
            "family_names": ([f.name for f in fams], "", "particle family names, in family index order"),
            "family_shape": (np.array([f.shape_code for f in fams], np.int32), "1",
                             registry.resolved("family_shape").legend),
            "family_count": (np.array([f.count for f in fams], np.int32), "1", "particles per family"),
            "family_radius": (np.array([f.radius for f in fams]), "m", "radius per family"),
            "family_length": (np.array([f.length for f in fams]), "m", "length per family"),
            "family_volume_fraction": (np.array([f.volume_fraction for f in fams]), "1",
                                       "volume (2-D: area) fraction per family"),
            "family_aspect_ratio": (np.array([f.aspect_ratio for f in fams]), "1", "length / diameter"),
            "family_equivalent_aspect_ratio": (np.array([f.equivalent_aspect_ratio for f in fams]), "1",
                                               "equivalent spheroid aspect ratio of the Jeffery equation"),
            "family_xi": (np.array([f.xi for f in fams]), "1", "Jeffery shape factor"),
            "regime": (self.regime, "", "dilute, semi-dilute, concentrated (n L^dim against 1 and L/d) or spheres"),
            "regime_measure": (self.regime_measure, "1", "n L^dim: number density times longest length^dim"),
            **(self._stokes_datasets() if self.hydrodynamics == "stokes" else {}),
        }

    def _stokes_datasets(self) -> dict[str, tuple[object, str, str]]:
        st, num = self.scene.numerics.stokes, self.scene.numerics
        return {
            "stokes_grid": (np.array(self.stokes_grid, np.int32), "1",
                            "Stokes grid voxel counts along a1, a2, a3 (1 along a3 in 2-D)"),
            **{name: _dataset(name, getattr(st, registry.resolved(name).key)) for name in _STOKES_DATASETS},
            "time_scheme": _dataset("time_scheme", num.time_scheme),
        }

    def summary(self) -> str:
        """A few human-readable lines: regime, choices, particles, steps."""
        lines = [
            f"regime: {self.regime} (n L^{self.dim} = {self.regime_measure:.4g}; "
            f"semi-dilute from 1, concentrated from L/d = {self.regime_threshold:.4g})"
            if self.regime != "spheres" else
            f"regime: spheres, total volume fraction {sum(f.volume_fraction for f in self.families):.4g}",
            self.reason,
            *([self.preset_reason] if self.preset_reason else []),
            f"cell: {self.dim}-D {' x '.join(f'{v:g}' for v in self.cell_lengths[:self.dim])}, "
            f"{'Couette walls' if self.walls else 'periodic'}; {self.n_steps} steps of {self.dt:g} to t = {self.t_end:g}",
        ]
        for f in self.families:
            lines.append(
                f"  {f.name}: {f.count} {f.shape}{'s' if f.count > 1 else ''}, R = {f.radius:g}, L = {f.length:g}, "
                f"beta = {f.aspect_ratio:.4g}, beta_e = {f.equivalent_aspect_ratio:.4g}, xi = {f.xi:.6f}, "
                f"phi = {f.volume_fraction:.4g}, {f.orientation}")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _multiple_of(value: float, dt: float) -> int | None:
    k = round(value / dt)
    return k if abs(k * dt - value) <= MULTIPLE_TOL * max(value, dt) else None


def _is_simple_shear(G: np.ndarray) -> bool:
    mask = np.ones_like(G, dtype=bool)
    mask[0, 1] = False
    return bool(np.all(G[mask] == 0.0))


def _gradient(scene: Scene, problems: Problems) -> np.ndarray | None:
    """The (dim, dim) velocity gradient, from the kinematics module's constructors."""
    from pyfold import kinematics

    flow, dim = scene.flow, scene.cell.dim
    if flow.type == "general":
        if flow.rate is not None:
            problems.add("flow.rate", "not used with flow.type = 'general' (the gradient sets the rate); remove it")
        if flow.gradient is None:
            problems.add("flow.gradient", f"required with flow.type = 'general': a {dim} x {dim} traceless array")
            return None
        if all(v == 0.0 for row in flow.gradient for v in row):
            problems.add("flow.gradient", "must have a non-zero entry: a scene is a suspension under an imposed "
                         "flow (orbits, contacts, the effective viscosity sigma:E / (2 E:E) all need one); got all zeros")
            return None
        rows = flow.gradient
        if len(rows) != dim or any(len(r) != dim for r in rows):
            shape = f"{len(rows)} x {'/'.join(sorted({str(len(r)) for r in rows}))}"
            problems.add("flow.gradient", f"a {dim}-D cell (cell.dim = {dim}) needs a {dim} x {dim} gradient, got {shape}")
            return None
        try:
            return kinematics.traceless_gradient(rows, name="flow.gradient", dim=dim)
        except InputError as exc:
            problems.add("flow.gradient", str(exc).removeprefix("flow.gradient: "))
            return None
    if flow.gradient is not None:
        problems.add("flow.gradient", f"only with flow.type = 'general' (got flow.type = {flow.type!r}); remove it")
    if flow.rate is None:
        problems.add("flow.rate", f"required with flow.type = {flow.type!r}: the rate [1/s]")
        return None
    if flow.rate == 0.0:
        problems.add("flow.rate", f"must be non-zero (0 < |rate| <= 1e+30): flow.type = {flow.type!r} at rate 0 is no "
                     "flow at all, and the scene's meaning needs one (Jeffery orbits, contacts, the effective "
                     "viscosity sigma:E / (2 E:E) of a Stokes run); got 0")
        return None
    if flow.type == "simple_shear":
        return np.asarray(kinematics.simple_shear(flow.rate, dim=dim))
    if flow.type == "planar_elongation":
        return np.asarray(kinematics.planar_elongation(flow.rate, dim=dim))
    if dim == 2:
        problems.add("flow.type", "'uniaxial_elongation' needs a 3-D cell (cell.dim = 3); "
                     "allowed in 2-D: simple_shear, planar_elongation, general")
        return None
    return np.asarray(kinematics.uniaxial_elongation(flow.rate))


def _check_lattice_duration(scene: Scene, G: np.ndarray, lengths: np.ndarray, good: list, alpha: float, dt: float,
                            t_end: float, problems: Problems) -> None:
    """A lattice deformed by an elongational or general flow thins unless it can be
    remapped (Kraynik-Reinelt planar elongation in a cell with Lx = Ly): the run is
    admissible only while the reduced cell is thicker than twice the contact search
    range (fold_cell.cell_admissible_time, fold_contacts.contact_search_range)."""
    from pyfold.native import geometry as geo

    dim = scene.cell.dim
    rc = geo.contact_search_range([f.shape_code for f in good], [f.radius for f in good],
                                  [f.length for f in good], alpha=alpha)
    cell = geo.Cell(tuple(lengths[:dim]), velocity_gradient=G)
    n_steps = int(round(t_end / dt))
    n_check = n_steps
    if scene.flow.type == "planar_elongation" and lengths[0] == lengths[1]:
        # Kraynik-Reinelt: the lattice repeats with period ln((3 + sqrt 5)/2)/|rate|; one decides
        n_check = min(n_steps, int(np.log((3.0 + 5.0**0.5) / 2.0) / abs(float(G[0, 0])) / dt) + 2)
    if n_check <= LATTICE_CHECK_SAMPLES:
        t_ok = geo.admissible_t_end(cell, rc, dt, t_end)
    else:
        # More steps than the native check visits in about a second. Exactly over the
        # first LATTICE_CHECK_SAMPLES steps (an elongation thins the lattice early) ...
        horizon = LATTICE_CHECK_SAMPLES * dt
        t_ok = geo.admissible_t_end(cell, rc, dt, horizon)
        if t_ok >= horizon:
            # ... then every stride-th step, with the search range grown by exp(|G|_2 stride dt),
            # the most the thickness can change between two samples, so the answer stays on the
            # safe side (t_ok a multiple of stride dt).
            stride = -(-n_check // LATTICE_CHECK_SAMPLES)
            strain = float(np.linalg.norm(G, 2)) * stride * dt
            if strain > 0.05:
                largest = 0.05 * LATTICE_CHECK_SAMPLES / float(np.linalg.norm(G, 2))
                problems.add("numerics.t_end", f"flow.type = {scene.flow.type!r} deforms the periodic lattice, whose "
                             f"thickness must be checked over the whole run: the strain |G|_2 t_end = "
                             f"{float(np.linalg.norm(G, 2)) * t_end:.3g} over {n_steps} steps is too long to check; "
                             f"allowed: numerics.t_end <= {largest:.4g}, got {t_end:g}")
                return
            t_ok = geo.admissible_t_end(cell, rc * float(np.exp(strain)), stride * dt, t_end)
    if t_ok < 0:
        problems.add("cell.size", f"the cell must be thicker than twice the contact search range 2 x {rc:.4g} "
                     f"(particle extent, alpha and Verlet skin) along every lattice direction; got {cell.lattice().thickness.min():.4g}")
    elif t_ok < t_end and n_check < n_steps:
        # Kraynik-Reinelt: periodic in time, so no t_end helps; the cell must be larger.
        period = cell.lattice().period
        thinnest = min(float(cell.at_time(float(t)).lattice().thickness.min())
                       for t in np.linspace(0.0, period, 2001)) / float(lengths[0])
        problems.add("cell.size", f"the Kraynik-Reinelt lattice of flow.type = 'planar_elongation' (remapped, any "
                     f"strain) gets thinner than twice the contact search range 2 x {rc:.4g} at t = {t_ok:g}: over a "
                     f"period its reduced cell thins to {thinnest:.4f} of the side (sampled); allowed: cell.size "
                     f"x = y > about {2.0 * rc / thinnest:.4g}, got {lengths[0]:g}")
    elif t_ok < t_end:
        problems.add("numerics.t_end", f"flow.type = {scene.flow.type!r} deforms the periodic lattice without a "
                     f"reproducible remap (Kraynik-Reinelt needs planar elongation with cell.size x = y): the reduced "
                     f"cell gets thinner than twice the contact search range {rc:.4g} after t = {t_ok:g}; allowed: "
                     f"numerics.t_end <= {t_ok:g} (or enlarge cell.size), got {t_end:g}")


#: Times sampled for the imposed displacement per step on a deforming lattice (_check_affine_step).
AFFINE_CHECK_SAMPLES = 2000


def _check_affine_step(G: np.ndarray, lengths: np.ndarray, dim: int, shear_flow: bool, dt: float, t_end: float,
                       problems: Problems) -> None:
    """fold_run stops a step in which a particle moves more than half the smallest cell side
    (fold_driver: the minimum image would be meaningless), so validation refuses a time step
    in which the imposed flow alone does that. A particle at x moves with u = G (x - L/2)
    (fold_cell's frame); over the primary cell (the box [0, L) in shear, the reduced cell
    origin + A(t) [0, 1)^dim of a deforming lattice) |u| is largest at a corner. A deforming
    lattice is sampled over the run (over one period for Kraynik-Reinelt), each sample's
    bound grown by exp(|G|_2 spacing), the most it can grow between two samples."""
    from pyfold.native import geometry as geo

    half = 0.5 * float(np.min(lengths[:dim]))
    centre = 0.5 * lengths[:dim]
    corners = np.stack(np.meshgrid(*[[0.0, 1.0]] * dim, indexing="ij"), -1).reshape(-1, dim)
    g = np.asarray(G, dtype=np.float64)[:dim, :dim]

    def largest_speed(origin, vectors) -> float:
        points = origin + corners @ vectors
        return float(np.max(np.linalg.norm((points - centre) @ g.T, axis=1)))

    if shear_flow:
        speed, t_bad = largest_speed(np.zeros(dim), np.diag(lengths[:dim])), 0.0
        if speed * dt <= half:
            return
    else:
        cell = geo.Cell(tuple(lengths[:dim]), velocity_gradient=g)
        period = cell.lattice().period
        span = min(t_end, period) if period > 0 else t_end
        times = np.linspace(0.0, span, AFFINE_CHECK_SAMPLES + 1)
        grow = float(np.exp(float(np.linalg.norm(g, 2)) * (times[1] - times[0])))
        t_bad = None
        for t in times:
            lat = cell.at_time(float(t)).lattice()
            speed = largest_speed(lat.origin, lat.vectors) * (grow if t > 0 else 1.0)
            if speed * dt > half:
                t_bad = float(t)
                break
        if t_bad is None:
            return
    if t_bad <= dt or (not shear_flow and cell.lattice().period > 0):
        problems.add("numerics.dt", f"the imposed flow moves a particle at a corner of the cell by |G (x - L/2)| dt = "
                     f"{speed * dt:.4g} per step (t = {t_bad:.4g}), more than half the smallest cell side "
                     f"{half:.4g} (fold_run stops such a step as a blow-up); allowed: numerics.dt <= "
                     f"{half / speed:.4g}, got {dt:g}")
    else:
        t_ok = max(dt, (np.floor(t_bad / dt) - 1) * dt)
        problems.add("numerics.t_end", f"the lattice deformed by flow.type stretches the cell so that the imposed flow "
                     f"moves a particle at a corner by more than half the smallest cell side {half:.4g} per step "
                     f"from t = {t_bad:.4g} (fold_run stops such a step as a blow-up); allowed: numerics.t_end <= "
                     f"{t_ok:.6g} (or a smaller numerics.dt), got {t_end:g}")


#: Files accepted for positions / orientations (one row per particle).
GIVEN_POSITION_SUFFIXES = (".csv", ".npy")


def _table(value, path: str, dim: int, base_dir: Path, problems: Problems, unit: bool = False) -> np.ndarray | None:
    """An (n, dim) array of finite reals, inline (a TOML array of rows) or read from a .csv
    (comma-separated, an optional header line) or .npy file relative to ``base_dir``.
    ``unit``: rows are axes, must be non-zero and are normalised."""
    if isinstance(value, str):
        file = Path(value) if Path(value).is_absolute() else base_dir / value
        suffix = file.suffix.lower()
        if suffix not in GIVEN_POSITION_SUFFIXES:
            problems.add(path, f"a file must be .csv or .npy (one row per particle), got {value!r}")
            return None
        if file.exists() and not file.is_file():  # a folder, FIFO or device: never opened (a FIFO blocks)
            try:
                regular_file(file, path)
            except InputError as exc:
                problems.add(path, str(exc).removeprefix(f"{path}: "))
                return None
        try:
            if suffix == ".npy":
                arr = np.load(file, allow_pickle=False)
            else:
                lines = [ln for ln in file.read_text(encoding="utf-8").splitlines() if ln.strip()]
                try:  # a first line that is not numbers is a header
                    [float(v) for v in lines[0].split(",")] if lines else None
                    skip = 0
                except ValueError:
                    skip = 1
                rows = [[float(v) for v in ln.split(",")] for ln in lines[skip:]]
                if any(len(r) != len(rows[0]) for r in rows):
                    problems.add(path, f"{file}: rows of different lengths")
                    return None
                arr = np.asarray(rows, dtype=np.float64)
        except FileNotFoundError:
            problems.add(path, f"no such file: {file} (relative paths are taken from the scene file's folder)")
            return None
        except (OSError, ValueError, UnicodeDecodeError) as exc:
            problems.add(path, f"cannot read {file} as {suffix[1:]} numbers: {exc}")
            return None
        if arr.dtype.kind not in "fiu":
            problems.add(path, f"{file}: expected real numbers, got dtype {arr.dtype}")
            return None
        arr = np.asarray(arr, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] != dim:
            problems.add(path, f"{file}: expected one row of {dim} numbers (cell.dim = {dim}) per particle, at least "
                         f"one row; got shape {arr.shape}")
            return None
        if not np.all(np.isfinite(arr)):
            row = int(np.argmax(~np.all(np.isfinite(arr), axis=1)))
            problems.add(path, f"{file}: row {row} is not finite: {arr[row].tolist()}")
            return None
        where = f"{file}: "
    else:
        bad = [i for i, v in enumerate(value) if len(v) != dim]
        if bad:
            problems.add(path, f"each row must have {dim} components (cell.dim = {dim}); row {bad[0]} has "
                         f"{len(value[bad[0]])}")
            return None
        if not value:
            problems.add(path, "must have at least one row")
            return None
        arr = np.asarray(value, dtype=np.float64)
        where = ""
    if unit:
        arr, why = unit_rows(arr, "row")
        if why is not None:
            problems.add(path, f"{where}axes: {why}")
            return None
    return arr


def _outside_cell(positions: np.ndarray, cell) -> tuple[int, int, float, float] | None:
    """First ``(row, axis, value, side)`` with a coordinate outside ``[0, side)``."""
    sides = np.asarray(cell.size, dtype=np.float64)
    bad = (positions < 0.0) | (positions >= sides)
    if not bad.any():
        return None
    row = int(np.argmax(bad.any(axis=1)))
    axis = int(np.argmax(bad[row]))
    return row, axis, float(positions[row, axis]), float(sides[axis])


def _draw_axes(orientation: str, axes, count: int, dim: int, seed: int, index: int) -> np.ndarray:
    """Axes of a family with given positions but no given orientations, by its rule:
    aligned (the direction), isotropic (uniform on the sphere / circle), planar_random
    (uniform in the x-y plane); numpy PCG64 seeded by (numerics.seed, family index)."""
    if orientation == "aligned":
        return np.tile(np.asarray(axes, dtype=np.float64).reshape(-1, dim)[0], (count, 1))
    rng = np.random.default_rng([seed, index])
    if orientation == "planar_random" and dim == 3:
        phi = rng.uniform(0.0, 2.0 * np.pi, count)
        return np.stack([np.cos(phi), np.sin(phi), np.zeros(count)], axis=1)
    v = rng.standard_normal((count, dim))
    n = np.linalg.norm(v, axis=1)
    while np.any(n == 0.0):  # pragma: no cover - probability 0
        v[n == 0.0] = rng.standard_normal((int(np.sum(n == 0.0)), dim))
        n = np.linalg.norm(v, axis=1)
    return v / n[:, None]


def _family(scene: Scene, index: int, problems: Problems, cell_volume: float,
            base_dir: Path = Path(".")) -> Family | None:
    fam = scene.particles[index]
    dim = scene.cell.dim
    at = f"particles[{index}]"
    ok = True
    if fam.shape == "sphere":
        for key in ("length", "aspect_ratio"):
            if getattr(fam, key) is not None:
                problems.add(f"{at}.{key}", "a sphere has no length or aspect ratio (give its radius only)")
                ok = False
        length, beta = 2.0 * fam.radius, 1.0
    else:
        given = [k for k in ("length", "aspect_ratio") if getattr(fam, k) is not None]
        if len(given) != 1:
            problems.add(f"{at}.length", f"give exactly one of length, aspect_ratio for a {fam.shape} "
                         f"(got {', '.join(given) if given else 'neither'})")
            return None
        length = fam.length if fam.length is not None else 2.0 * fam.radius * fam.aspect_ratio
        beta = length / (2.0 * fam.radius)
        if not beta > 1.0:
            problems.add(f"{at}.{given[0]}", f"a {fam.shape} needs length > 2 radius (aspect ratio > 1), got "
                         f"aspect ratio {beta:.6g}; use shape = 'sphere' for round particles")
            return None
    if fam.equivalent_aspect_ratio is not None and fam.shape != "fibre":
        problems.add(f"{at}.equivalent_aspect_ratio", f"only for fibres (finite cylinders), not a {fam.shape}")
        ok = False
    rule = fam.equivalent_aspect_ratio or EQUIVALENT_ASPECT_RATIO_DEFAULT
    beta_e, xi = shapes.jeffery_xi(fam.shape, beta, rule)
    if fam.shape == "fibre" and not (1.0 < beta_e < beta):
        key = "length" if fam.length is not None else "aspect_ratio"
        others = [r for r in ("cox", "zhang", "harris_pittman") if r != rule]
        problems.add(f"{at}.{key}", f"the {rule!r} equivalent-aspect-ratio rule gives beta_e = {beta_e:.4g} for "
                     f"aspect ratio {beta:.4g}, outside its range of validity (a finite cylinder has "
                     f"1 < beta_e < beta); set {at}.equivalent_aspect_ratio to one of {others} or use longer fibres")
        ok = False

    vp = shapes.particle_volume(dim, fam.shape, fam.radius, length)
    positions = None
    if fam.positions is not None:
        positions = _table(fam.positions, f"{at}.positions", dim, base_dir, problems)
        if positions is None:
            return None
        count = len(positions)
        if fam.count is not None and fam.volume_fraction is not None:
            problems.add(f"{at}.count", "give at most one of count, volume_fraction (got both); with positions "
                         "neither is needed: the count is the number of rows")
            return None
        if fam.count is not None and fam.count != count:
            problems.add(f"{at}.count", f"must equal the number of rows of {at}.positions ({count}), got {fam.count}; "
                         "or leave it out")
            return None
        if fam.volume_fraction is not None:
            implied = int(round(fam.volume_fraction * cell_volume / vp))
            if implied != count:
                problems.add(f"{at}.volume_fraction", f"{fam.volume_fraction:g} of this cell is {implied} particles, "
                             f"but {at}.positions has {count} rows; allowed: the fraction of {count} particles, "
                             f"{count * vp / cell_volume:.6g} (or leave it out)")
                return None
        if count > MAX_PARTICLES_PER_FAMILY:
            problems.add(f"{at}.positions", f"{count} rows; allowed: at most {MAX_PARTICLES_PER_FAMILY} per family")
            return None
        bad = _outside_cell(positions, scene.cell)
        if bad is not None:
            row, axis, value, side = bad
            problems.add(f"{at}.positions", f"row {row}: {'xyz'[axis]} = {value:.17g} is outside the cell; allowed: "
                         f"0 <= {'xyz'[axis]} < {side:g} (cell.size; positions are not wrapped)")
            return None
    elif (fam.count is None) == (fam.volume_fraction is None):
        problems.add(f"{at}.count", "give exactly one of count, volume_fraction "
                     f"(got {'both' if fam.count is not None else 'neither'})")
        return None
    if positions is not None:
        pass  # count = the number of rows (checked above)
    elif fam.count is not None:
        count = fam.count
    else:
        exact = fam.volume_fraction * cell_volume / vp  # finite: lengths are bounded (schema, MAX_LENGTH_RATIO)
        if not exact < MAX_PARTICLES_PER_FAMILY + 0.5:
            problems.add(f"{at}.volume_fraction", f"{fam.volume_fraction:g} of this cell is {exact:.3g} particles; "
                         f"allowed: at most {MAX_PARTICLES_PER_FAMILY} per family (the cap of count), i.e. "
                         f"volume_fraction <= {MAX_PARTICLES_PER_FAMILY * vp / cell_volume:.3g}")
            return None
        count = int(round(exact))
        if count < 1:
            problems.add(f"{at}.volume_fraction", f"{fam.volume_fraction:g} of this cell holds no whole particle "
                         f"(one particle fills {vp / cell_volume:.3g}); allowed: >= {0.5 * vp / cell_volume:.3g}")
            return None
    axes = None
    orientation = fam.orientation
    if fam.orientations is not None and "orientation" not in fam.model_fields_set:
        orientation = "given"  # orientations given, orientation left out: they are the rule
    if orientation == "given":
        if fam.orientations is None:
            problems.add(f"{at}.orientations", "required with orientation = 'given': one axis per particle")
            ok = False
        elif fam.count is None and positions is None:
            problems.add(f"{at}.count", "orientation = 'given' needs count or positions (not volume_fraction)")
            ok = False
        else:
            rows = _table(fam.orientations, f"{at}.orientations", dim, base_dir, problems, unit=True)
            if rows is None:
                ok = False
            elif len(rows) != count:
                what = f"the {count} rows of {at}.positions" if positions is not None else f"count = {count}"
                problems.add(f"{at}.orientations", f"must hold one axis per particle ({what}), got {len(rows)}")
                ok = False
            else:
                axes = rows
    elif fam.orientations is not None:
        problems.add(f"{at}.orientations", "only with orientation = 'given' (or with orientation left out)")
        ok = False
    if fam.orientation == "aligned":
        direction = fam.direction if fam.direction is not None else [1.0] + [0.0] * (dim - 1)
        found = _axes([direction], f"{at}.direction", dim, problems)
        ok = ok and found is not None
        axes = found
    elif fam.direction is not None:
        problems.add(f"{at}.direction", "only with orientation = 'aligned'")
        ok = False
    if not ok:
        return None
    if positions is not None and orientation != "given":
        # the family's rule, drawn here (numpy PCG64 from numerics.seed and the family index),
        # so that validation checks the gaps of exactly the state fold_run starts from
        axes = _draw_axes(orientation, axes, count, dim, scene.numerics.seed, index)
    return Family(index=index, name=fam.name or f"family{index}", shape=fam.shape, radius=fam.radius,
                  length=length, aspect_ratio=beta, equivalent_aspect_ratio=beta_e, xi=xi, count=count,
                  volume_fraction=count * vp / cell_volume, orientation=orientation, axes=axes,
                  positions=positions)


#: Tolerance of the gap rule for given positions: every surface gap >= alpha - GAP_TOL_ULPS
#: eps max(L_i), the tolerance of the placement kernel's relaxation (fold_placement.f90).
GAP_TOL_ULPS = 64.0


def _voxel_span_violation(grid, lengths, dim: int, good, g_xy: float, t_end: float):
    """The Stokes voxeliser's rule (fortran/grid/fold_voxelise.f90): along every lattice
    direction d, twice the particle's span in voxels, n_d sum_j |A^-1_dj| e_j (e the
    half extent of its bounding box), must stay <= n_d - 2. Bounded over the run: e_j <= the
    largest half extent of any orientation (sphere R, fibre L/2 + R, spheroid L/2) and the
    Lees-Edwards offset |s| <= min(|G_xy| Ly t_end, Lx/2). Returns ``(axis, 2 span, n)`` of
    the first violated direction, or None."""
    e = max(f.radius if f.shape == "sphere" else 0.5 * f.length + (f.radius if f.shape == "fibre" else 0.0)
            for f in good)
    s_max = min(abs(g_xy) * float(lengths[1]) * t_end, 0.5 * float(lengths[0]))
    for ax in range(dim):
        n = int(grid[ax])
        inv_sum = 1.0 / float(lengths[ax])
        if ax == 0:
            inv_sum += s_max / (float(lengths[0]) * float(lengths[1]))
        span2 = 2.0 * n * inv_sum * e
        if span2 > n - 2.0:
            return ax, span2, n
    return None


def _check_given_gaps(good, lengths, dim: int, walls: bool, G, alpha: float, problems: Problems) -> None:
    """Every surface gap of a given configuration >= alpha (alpha/2 to Couette walls), with
    the placement kernel's pair search and capsule distance (native geometry binding)."""
    from pyfold.native import geometry as geo

    x = np.concatenate([f.positions for f in good])
    p = np.concatenate([np.broadcast_to(f.axes, (f.count, dim)) for f in good])
    fam = np.repeat([f.index for f in good], [f.count for f in good])
    row = np.concatenate([np.arange(f.count) for f in good])
    h = np.repeat([shapes.half_segment(f.shape, f.radius, f.length) for f in good], [f.count for f in good])
    rad = np.repeat([f.radius for f in good], [f.count for f in good])
    tol = GAP_TOL_ULPS * _EPS * float(np.max(lengths[:dim]))
    where = lambda k: f"particles[{fam[k]}].positions row {row[k]}"  # noqa: E731
    if walls:
        lo = x[:, 1] - h * np.abs(p[:, 1]) - rad
        hi = lengths[1] - (x[:, 1] + h * np.abs(p[:, 1])) - rad
        gap = np.minimum(lo, hi)
        bad = np.nonzero(gap < 0.5 * alpha - tol)[0]
        if bad.size:
            k = int(bad[0])
            problems.add(f"particles[{fam[k]}].positions", f"row {row[k]} is {gap[k]:.6g} from a wall; allowed: >= "
                         f"alpha/2 = {0.5 * alpha:.6g} (the placement's rule)")
            return
    if len(x) < 2:
        return
    cell = geo.Cell(tuple(lengths[:dim]), walls=walls, velocity_gradient=G)
    rc = (2.0 * float(np.max(h + rad)) + alpha) * (1.0 + 1e-9)  # fold_placement's search range
    pairs = geo.neighbour_pairs(x, cell, rc)
    if len(pairs) == 0:
        return
    i, j = pairs[:, 0], pairs[:, 1]
    r = geo.min_image(x[i] - x[j], cell)
    dist = geo.capsule_contact(r, p[i], h[i], rad[i], p[j], h[j], rad[j])["dist"]
    bad = np.nonzero(dist < alpha - tol)[0]
    if bad.size:
        k = int(bad[0])  # pairs are sorted: the first offending pair
        a, b = int(i[k]), int(j[k])
        other = f"row {row[b]}" if fam[a] == fam[b] else where(b)
        problems.add(f"particles[{fam[a]}].positions",
                     f"row {row[a]} and {other} are {dist[k]:.6g} apart (surface gap"
                     f"{', overlapping' if dist[k] < 0 else ''}); allowed: every gap >= alpha = {alpha:.6g} "
                     f"({bad.size} pair{'s' if bad.size > 1 else ''} closer)")


def _axes(vectors, path: str, dim: int, problems: Problems) -> np.ndarray | None:
    bad = [i for i, v in enumerate(vectors) if len(v) != dim]
    if bad:
        problems.add(path, f"each axis must have {dim} components (cell.dim = {dim}); "
                     f"entry {bad[0]} has {len(vectors[bad[0]])}")
        return None
    arr, why = unit_rows(vectors, "entry")
    if why is not None:
        problems.add(path, why if len(vectors) > 1 else why.replace("entry 0 ", "the vector ", 1))
    return arr


def normalise(scene: Scene, source: str = "scene", base_dir: str | Path | None = None) -> ResolvedScene:
    """Check every rule that ties keys together and resolve the scene.

    With ``numerics.preset = "study"`` the scene is resolved once to learn its regime,
    model, security zone and rates, the preset fills the numerical keys the scene leaves
    unset (pyfold/scene/study_preset.py), and the filled scene is resolved; its
    ``preset_reason`` says what was chosen and on what evidence.

    Parameters
    ----------
    scene : Scene
        A scene whose fields passed the schema (types, ranges, known keys).
    source : str
        Name used in the error message (the file name).
    base_dir : path, optional
        Folder of the files a scene names (``positions``, ``orientations``); default the
        folder of ``source`` when it is a file, else the working directory.

    Returns
    -------
    ResolvedScene

    Raises
    ------
    InputError
        Listing every problem found, each under its key path with the allowed range.
    """
    if scene.numerics.preset is None:
        return _normalise(scene, source, base_dir)
    from pyfold.scene import study_preset

    probe = _normalise(study_preset.probe_scene(scene), source, base_dir)
    filled, reason, warnings = study_preset.fill(scene, probe)
    resolved = _normalise(filled, source, base_dir)
    return dataclasses.replace(resolved, preset_reason=reason, warnings=resolved.warnings + warnings)


def _normalise(scene: Scene, source: str, base_dir: str | Path | None) -> ResolvedScene:
    """:func:`normalise` of a scene whose numerical keys are final."""
    problems = Problems()
    cell, dim = scene.cell, scene.cell.dim
    if len(cell.size) != dim:
        problems.add("cell.size", f"a {dim}-D cell (cell.dim = {dim}) needs {dim} side lengths, got {len(cell.size)}")
        problems.raise_if_any(source)
    lengths = np.zeros(3)
    lengths[:dim] = cell.size
    cell_volume = float(np.prod(cell.size))
    walls = cell.boundary == "couette"
    # Lengths are each within MAGNITUDE_LIMIT of 1 (schema); their ratios are bounded
    # here, so volumes, counts and grid sizes computed below stay finite.
    thinnest = min(range(len(scene.particles)), key=lambda i: scene.particles[i].radius)
    r_min, side = scene.particles[thinnest].radius, max(cell.size)
    if side > MAX_LENGTH_RATIO * r_min:
        problems.add("cell.size", f"the longest side {side:g} is {side / r_min:.3g} times the smallest particle radius "
                     f"particles[{thinnest}].radius = {r_min:g}; allowed: cell.size <= {MAX_LENGTH_RATIO:g} x "
                     f"the smallest radius = {MAX_LENGTH_RATIO * r_min:g} (or particles[{thinnest}].radius >= "
                     f"{side / MAX_LENGTH_RATIO:g})")

    G = _gradient(scene, problems)
    shear_flow = G is None or _is_simple_shear(G)
    if not shear_flow and walls:
        # Couette walls drive a simple shear; other flows use the periodic lattice
        # that deforms with the flow (fold_cell, fortran/geometry).
        key = "flow.gradient" if scene.flow.type == "general" else "flow.type"
        problems.add(key, "no-slip walls (cell.boundary = 'couette') drive a simple shear u = (rate y, 0, 0): "
                     f"G_xy must be the only non-zero entry; got flow.type = {scene.flow.type!r}"
                     f"{' with G = ' + str(G.tolist()) if scene.flow.type == 'general' else ''}; "
                     "use cell.boundary = 'periodic' for elongational flows")

    if base_dir is None:
        base_dir = Path(source).parent if Path(source).is_file() else Path(".")
    families = [_family(scene, i, problems, cell_volume, Path(base_dir)) for i in range(len(scene.particles))]
    names = [f.name for f in families if f is not None]
    for i, f in enumerate(families):
        if f is not None and names.count(f.name) > 1:
            problems.add(f"particles[{i}].name", f"family names must be unique, {f.name!r} is used twice")
    good = [f for f in families if f is not None]

    model = scene.model
    radii = [f.radius for f in good] or [min(p.radius for p in scene.particles)]
    alpha = model.alpha if model.alpha is not None else DEFAULT_ALPHA_OVER_RADIUS * min(radii)
    if alpha > min(radii):
        problems.add("model.alpha", f"must be between 0 and the smallest particle radius {min(radii):g} "
                     f"(a security zone of the order of a grid cell), got {alpha:g}")
    if model.hydrodynamics == "stokes" and not shear_flow and not any(
            b.deforming_lattice for b in registry.BACKENDS.values()):
        problems.add("model.hydrodynamics", "'stokes' is available for simple shear only: the FFT Stokes solver has "
                     f"no deforming (elongational) lattice yet (flow.type = {scene.flow.type!r}); use "
                     "hydrodynamics = 'jeffery'")
    st = scene.numerics.stokes
    # The backend: "auto" is the backend of the cell (pyfold.scene.registry.backend_for);
    # an explicit one must be that backend, since neither can do the other's cell.
    backend = registry.backend_for(walls)
    backend_text = backend_mismatch(st.backend, walls)
    if model.hydrodynamics == "stokes" and backend_text:
        problems.add("numerics.stokes.backend", backend_text)
    # The Stokes grid is computed only when hydrodynamics can be stokes (requested, or
    # auto in a simple shear with a backend for the cell); bounded by max_grid_points
    # before any rounding.
    stokes_possible = model.hydrodynamics == "stokes" or (model.hydrodynamics == "auto" and shear_flow
                                                          and not backend_text)
    grid = stokes_grid(lengths[:dim], 2.0 * min(radii), st.cells_per_diameter,
                       max_points=st.max_grid_points) if stokes_possible else None
    grid_points = int(np.prod(grid, dtype=object)) if grid is not None else 0
    if model.hydrodynamics == "stokes" and grid_points > st.max_grid_points:
        problems.add("numerics.stokes.max_grid_points",
                     f"the Stokes grid {' x '.join(map(str, grid))} = {grid_points} points (cells_per_diameter = "
                     f"{st.cells_per_diameter} across the thinnest diameter {2.0 * min(radii):g}) exceeds "
                     f"max_grid_points = {st.max_grid_points}; raise it (memory ~ {_grid_megabytes(grid, dim):.0f} MB), "
                     f"lower numerics.stokes.cells_per_diameter or the cell size")
    if grid is not None and st.fft_precision in registry.BACKENDS[backend].fft_precisions \
            and st.fft_precision == "single":
        tol_min = stokes_codes.single_tolerance_min(grid_points)
        if st.tolerance < tol_min:
            problems.add("numerics.stokes.tolerance",
                         f"with fft_precision = 'single' the CG residual cannot fall below the single-precision "
                         f"round-off of the transforms, (2 log2 N + 4) 2^-24 = {tol_min:.3g} on the "
                         f"{' x '.join(map(str, grid[:dim]))} grid; allowed: tolerance >= {tol_min:.3g} or "
                         f"fft_precision = 'double', got {st.tolerance:g}")
    if st.rigidity not in registry.BACKENDS[backend].rigidities:
        able = " or ".join(b.name for b in registry.BACKENDS.values() if st.rigidity in b.rigidities)
        allowed = " or ".join(f"rigidity = {r!r}" for r in registry.BACKENDS[backend].rigidities)
        problems.add("numerics.stokes.rigidity",
                     f"rigidity = {st.rigidity!r} needs the {able} backend (a periodic cell); the {backend} backend "
                     f"is penalised only; allowed: {allowed} with this cell, got {st.rigidity!r}")
    rigidity = registry.RIGIDITIES[st.rigidity]
    if st.fft_precision not in rigidity.fft_precisions:
        others = " or ".join(repr(r.name) for r in registry.RIGIDITIES.values() if st.fft_precision in r.fft_precisions)
        problems.add("numerics.stokes.fft_precision",
                     f"rigidity = {st.rigidity!r} transforms in {' or '.join(rigidity.fft_precisions)} precision only; "
                     f"allowed: fft_precision = {' or '.join(map(repr, rigidity.fft_precisions))} (or rigidity = "
                     f"{others}), got {st.fft_precision!r}")
    if grid is not None and grid_points <= st.max_grid_points and rigidity.uses_kappa:
        check_kappa(st, grid[:dim], grid_points, problems)
    voxel_text = ""
    if grid is not None and grid_points <= st.max_grid_points and good and G is not None and shear_flow:
        # walls: the lattice stays rectangular (no Lees-Edwards offset widens the span)
        g_xy = 0.0 if walls else float(G[0, 1])
        span = _voxel_span_violation(grid, lengths, dim, good, g_xy, scene.numerics.t_end)
        if span is not None:
            ax, voxels, n_ax = span
            better = next((c for c in range(st.cells_per_diameter + 1, 65)
                           if _voxel_span_violation(stokes_grid(lengths[:dim], 2.0 * min(radii), c), lengths, dim,
                                                    good, g_xy, scene.numerics.t_end) is None), None)
            voxel_text = (f"a particle spans up to {voxels:.3g} voxels along lattice direction {ax + 1} of the "
                          f"{' x '.join(map(str, grid[:dim]))} Stokes grid, more than {n_ax} - 2 (the voxeliser keeps "
                          "a particle two voxels clear of its own periodic image, fortran/grid/fold_voxelise.f90; "
                          "the sheared lattice widens the span by the Lees-Edwards offset)")
            hint = (f"allowed: cells_per_diameter >= {better}" if better is not None else
                    "no cells_per_diameter up to 64 suffices: use smaller particles or a larger cell")
            if model.hydrodynamics == "stokes":
                problems.add("numerics.stokes.cells_per_diameter", f"{voxel_text}; {hint}, got {st.cells_per_diameter}")
    # The lubrication rule (fortran/contact/fold_lubrication.f90): between spheres, in 3-D,
    # with the Stokes solver only (elsewhere it is a warning below).
    if model.lubrication and (dim != 3 or not any(f.shape == "sphere" for f in good)):
        problems.add("model.lubrication", "the lubrication correction (docs/physics.md#lubrication-between-spheres) is "
                     "defined between spheres in 3-D (a 2-D disk has no isolated Stokes mobility); this scene has "
                     + ("no sphere family" if not any(f.shape == "sphere" for f in good) else f"dim = {dim}"))

    # fold_run's rule (shapes.cell_range_violation, the one statement of it): with two or
    # more particles every periodic edge must exceed twice the contact search range, so the
    # minimum image of a pair is unique. A single particle has no pair: any size.
    n_total = sum(f.count for f in good)
    range_violation = shapes.cell_range_violation(lengths, dim, walls, [(f.shape, f.radius, f.length) for f in good], alpha,
                                        n_total)
    if range_violation is not None:
        ax, edge, rc = range_violation
        widest = max(good, key=lambda f: shapes.half_segment(f.shape, f.radius, f.length) + f.radius)
        key = f"particles[{widest.index}].{'radius' if widest.shape == 'sphere' else 'length'}"
        problems.add(key, f"the interaction range rc = {rc:.6g} of the contact search (largest particle extent "
                     f"{2.0 * (shapes.half_segment(widest.shape, widest.radius, widest.length) + widest.radius):g} "
                     f"+ 2 alpha + largest radius) must be below half the smallest periodic side ({'xyz'[ax]}: "
                     f"{edge:g} / 2 = {0.5 * edge:g}; fold_run needs every periodic edge > 2 rc when particles can "
                     f"pair, {n_total} particles here); enlarge cell.size or use smaller particles "
                     "(a single particle per cell may be as large as the cell allows)")
    for f in good:
        extent = f.length + (2.0 * f.radius if f.shape == "fibre" else 0.0)
        key = f"particles[{f.index}].{'radius' if f.shape == 'sphere' else 'length'}"
        if walls and extent + alpha >= lengths[1]:
            problems.add(key, f"particle extent {extent:g} + alpha {alpha:g} must be < the wall gap Ly = {lengths[1]:g}")

    given = [f for f in good if f.positions is not None]
    if given and len(given) != len(good):
        random_ = [f for f in good if f.positions is None]
        problems.add(f"particles[{random_[0].index}].positions", "families with given positions "
                     f"({', '.join(f'particles[{f.index}]' for f in given)}) cannot be mixed with randomly placed ones "
                     f"({', '.join(f'particles[{f.index}]' for f in random_)}): the placement kernel places every "
                     "particle of a scene at random; give positions for every family")
    elif given and range_violation is None and G is not None:
        _check_given_gaps(good, lengths, dim, walls, G, alpha, problems)

    # Random placement (honouring alpha) cannot exceed the random-packing limits.
    total_inflated, limits = 0.0, []
    for f in good:
        if f.positions is not None:
            continue  # given configurations (ordered arrays may be denser): their gaps are checked
        grown_length = f.length + alpha if f.shape != "sphere" else 2.0 * f.radius + alpha
        inflated = f.count * shapes.particle_volume(dim, f.shape, f.radius + 0.5 * alpha, grown_length) / cell_volume
        total_inflated += inflated
        found = shapes.random_packing_limit(f.shape, dim, f.aspect_ratio)
        if found is None:
            continue
        limit, why = found
        limits.append(limit)
        if inflated > limit:
            key = "count" if scene.particles[f.index].count is not None else "volume_fraction"
            problems.add(f"particles[{f.index}].{key}", f"volume fraction {f.volume_fraction:.4g} "
                         f"({inflated:.4g} with the security zone alpha) is beyond what random placement can reach: "
                         f"{why}; allowed: <= {limit * f.volume_fraction / inflated:.4g}")
    if len(good) > 1 and limits and total_inflated > max(limits):
        problems.add("particles", f"total volume fraction {sum(f.volume_fraction for f in good):.4g} "
                     f"({total_inflated:.4g} with alpha) exceeds the random-packing limit {max(limits):.4g} "
                     f"of the most packable family")

    num = scene.numerics
    if num.dt is None:
        problems.add("numerics.dt", 'required (a time step > 0), or numerics.preset = "study" to have it chosen '
                     "for the scene (pyfold/scene/study_preset.py)")
        problems.raise_if_any(source)
    n_steps = None
    scale = float(np.max(np.abs(G))) if G is not None else 0.0  # flow time scale 1/max|G_ij|
    dt_min = max(num.t_end / MAX_STEPS, MIN_STRAIN_PER_STEP / scale if scale > 0 else 0.0)
    if scale > 0 and scale * num.t_end > MAX_STRAIN:
        problems.add("numerics.t_end", f"the total strain max|G_ij| t_end = {scale * num.t_end:.3g} exceeds "
                     f"1/eps = {MAX_STRAIN:.3g} (positions would lose every digit); allowed: numerics.t_end <= "
                     f"{MAX_STRAIN / scale:.3g}, got {num.t_end:g}")
    elif num.dt > num.t_end:
        problems.add("numerics.dt", f"must be <= numerics.t_end = {num.t_end:g}, got {num.dt:g}")
    elif num.dt < dt_min:
        problems.add("numerics.dt", f"must be >= {dt_min:.3g}: at most t_end / dt = {MAX_STEPS} steps "
                     f"(numerics.t_end = {num.t_end:g}) and a strain max|G_ij| dt >= {MIN_STRAIN_PER_STEP:.2g} per "
                     f"step (flow time scale 1/max|G_ij| = {1.0 / scale if scale > 0 else float('inf'):.3g}); "
                     f"allowed: {dt_min:.3g} <= numerics.dt <= numerics.t_end = {num.t_end:g}, got {num.dt:g}")
    else:
        n_steps = _multiple_of(num.t_end, num.dt)
        if n_steps is None:
            problems.add("numerics.t_end", f"must be a multiple of numerics.dt = {num.dt:g}, got {num.t_end:g} "
                         f"(= {num.t_end / num.dt:.6g} dt)")
        elif n_steps > 2**31 - 1:
            problems.add("numerics.t_end", f"t_end / dt = {n_steps} steps, allowed <= {2**31 - 1}")
            n_steps = None

    out = scene.output
    every: dict[str, int] = {}
    if n_steps is not None:
        defaults = {"interval": max(1, n_steps // DEFAULT_RECORDS), "snapshot_interval": max(1, n_steps // DEFAULT_SNAPSHOTS),
                    "checkpoint_interval": max(1, n_steps // DEFAULT_CHECKPOINTS)}
        for key, default in defaults.items():
            value = getattr(out, key)
            if value is None:
                every[key] = default
                continue
            if value == 0.0 and key != "interval":
                every[key] = 0
                continue
            k = _multiple_of(value, num.dt)
            if k is None or k < 1:
                problems.add(f"output.{key}", f"must be a multiple of numerics.dt = {num.dt:g}"
                             f"{' or 0 (none)' if key != 'interval' else ''}, got {value:g}")
            elif k > n_steps:
                problems.add(f"output.{key}", f"must be <= numerics.t_end = {num.t_end:g}, got {value:g}")
            else:
                every[key] = k

    if not shear_flow and not walls and n_steps is not None and good and shapes.range_rule_applies(n_total):
        _check_lattice_duration(scene, G, lengths, good, alpha, num.dt, num.t_end, problems)
    if G is not None and n_steps is not None and not problems:
        _check_affine_step(G, lengths, dim, shear_flow, num.dt, num.t_end, problems)

    problems.raise_if_any(source)
    assert G is not None and n_steps is not None

    # Regime from the longest family (docs/physics.md#suspension-regimes).
    longest = max(good, key=lambda f: f.length)
    n_density = sum(f.count for f in good) / cell_volume
    regime, measure = shapes.regime(n_density, longest.length, 2.0 * longest.radius, dim)
    regime_text = f"{regime} (n L^{dim} = {measure:.3g}, L/d = {longest.aspect_ratio:.3g})"
    has_spheres = any(f.shape == "sphere" for f in good)
    if longest.shape == "sphere":
        # The n L^d rule classifies rods; for spheres it would call a 50 % packing dilute.
        regime = "spheres"
        regime_text = (f"spheres (volume fraction {sum(f.volume_fraction for f in good):.3g}; "
                       f"the n L^{dim} regimes are defined for elongated particles)")

    reasons = []
    collisions = model.collisions
    if collisions == "auto":
        if regime == "dilute" and not has_spheres:
            collisions = "none"
            reasons.append(f"collisions = none (auto): {regime_text}, particles rarely meet: no contact pass")
        else:
            collisions = "strategy"
            why = (f"{regime_text}; spheres present, whose collisions the n L^{dim} rule does not bound: contacts kept"
                   if regime == "dilute" else regime_text)
            reasons.append(f"collisions = strategy (auto): {why}")
    else:
        reasons.append(f"collisions = {collisions} (requested)")
    hydrodynamics = model.hydrodynamics
    grid_text = f"Stokes grid {' x '.join(map(str, grid))} = {grid_points} points" if grid is not None else ""
    if hydrodynamics == "auto":
        hydrodynamics = "jeffery"
        phi = sum(f.volume_fraction for f in good)
        interacting = (phi >= SPHERE_INTERACTION_FRACTION) if regime == "spheres" else regime != "dilute"
        if not interacting:
            why = (f"{regime_text}: below phi = {SPHERE_INTERACTION_FRACTION:g} the pair term of the suspension "
                   "viscosity is under 12 % of Einstein's (Batchelor & Green 1972)" if regime == "spheres" else
                   f"{regime_text}: hydrodynamic interactions between particles are negligible")
            reasons.insert(0, f"hydrodynamics = jeffery (auto): {why}")
        elif not shear_flow:
            reasons.insert(0, f"hydrodynamics = jeffery (auto): {regime_text}, interactions matter, but the FFT "
                           "Stokes solver has no deforming (elongational) lattice; hydrodynamic interactions are "
                           "neglected, an approximation in this regime")
        elif backend_text:
            reasons.insert(0, f"hydrodynamics = jeffery (auto): {regime_text}, interactions matter, but "
                           f"numerics.stokes.backend = {st.backend!r} cannot solve this cell ({backend_text}); "
                           "hydrodynamic interactions are neglected, an approximation in this regime")
        elif voxel_text:
            reasons.insert(0, f"hydrodynamics = jeffery (auto): {regime_text}, interactions matter, but {voxel_text}; "
                           "hydrodynamic interactions are neglected, an approximation in this regime")
        elif grid_points > st.max_grid_points:
            reasons.insert(0, f"hydrodynamics = jeffery (auto): {regime_text}, interactions matter, but the "
                           f"{grid_text} exceeds numerics.stokes.max_grid_points = {st.max_grid_points}; "
                           "hydrodynamic interactions are neglected, an approximation in this regime")
        else:
            hydrodynamics = "stokes"
            reasons.insert(0, f"hydrodynamics = stokes (auto): {regime_text}, hydrodynamic interactions matter and "
                           f"the {grid_text} is within numerics.stokes.max_grid_points = {st.max_grid_points}")
        # The measured effect of neglecting hydrodynamics on C_I in this regime (fibres), and
        # what the chosen model costs in C_I accuracy (pyfold/scene/hydrodynamics_evidence.py).
        # The measured rows are periodic Lees-Edwards cells: none for a cell with walls.
        if regime != "spheres" and not has_spheres and dim == 3:
            reasons[0] += (auto_evidence(regime, hydrodynamics) if not walls else
                           "; no measured C_I evidence for cells with walls (the rows of "
                           "pyfold/scene/hydrodynamics_evidence.py are periodic cells): this choice rests on the "
                           "regime alone")
    else:
        extra = f" ({grid_text})" if hydrodynamics == "stokes" else ""
        reasons.insert(0, f"hydrodynamics = {hydrodynamics} (requested){extra}")
    if hydrodynamics == "stokes":
        how = "auto: " if st.backend == registry.AUTO_BACKEND else "requested; "
        reasons.insert(1, f"Stokes backend = {backend} ({how}" + (
            "the cell has no-slip walls at y = 0 and y = Ly, which the staggered-grid hypre solver imposes)"
            if walls else "the cell is periodic, the FFT solver follows its Lees-Edwards lattice)"))
    G3 = np.zeros((3, 3))
    G3[:dim, :dim] = G
    from pyfold.kinematics import shear_rate

    rate = float(shear_rate(G3))
    warnings = []
    if model.lubrication and hydrodynamics != "stokes":
        warnings.append("model.lubrication: has no effect with hydrodynamics = jeffery: the correction adds what the "
                        "Stokes grid cannot resolve to the flow's sphere velocities "
                        "(docs/physics.md#lubrication-between-spheres)")
    if model.lubrication and hydrodynamics == "stokes":
        warnings.append("model.lubrication: qualitative only: with the isolated-sphere mobility the correction "
                        "slows the approach of near pairs 2-8 times below the grid-converged rate "
                        "(docs/physics.md#lubrication-between-spheres, studies/lubrication/pair_approach.py)")
    if model.lubrication and hydrodynamics == "stokes" and dim == 3:
        # fold_lubrication finds its pairs with the cell lists within 2 R_max + h_c,
        # h_c = 2 voxel widths (voxel = (cell volume / grid points)^(1/3), fold_grid's h)
        voxel = (float(np.prod(lengths[:dim])) / grid_points) ** (1.0 / dim)
        r_lub = 2.0 * max(f.radius for f in good if f.shape == "sphere") + LUBRICATION_THRESHOLD_VOXELS * voxel
        if n_total > 1 and min(lengths[:dim]) <= 2.0 * r_lub:
            problems.add("model.lubrication", f"the lubrication pair search range 2 R + h_c = {r_lub:.6g} "
                         f"(h_c = {LUBRICATION_THRESHOLD_VOXELS:g} voxels of {voxel:.4g}) must be below half the "
                         f"smallest periodic side {min(lengths[:dim]):g}; enlarge cell.size, raise "
                         "numerics.stokes.cells_per_diameter or use smaller spheres")
            problems.raise_if_any(source)
    for f in good:
        step = rate * 0.5 * f.length * num.dt  # tip displacement relative to the centre per step
        if collisions != "none" and step > 0.5 * alpha:
            warnings.append(f"{f.name}: a tip moves up to {step:.3g} per step, more than alpha/2 = {0.5 * alpha:.3g} "
                            "(docs/physics.md#time-step); contacts may need many iterations, consider a smaller dt")
        if step > f.radius:
            warnings.append(f"{f.name}: a tip moves up to {step:.3g} per step, more than a radius {f.radius:.3g} "
                            "(a fraction of a diameter per step, docs/physics.md#time-step)")

    if hydrodynamics == "stokes":
        thinnest_d = 2.0 * min(f.radius for f in good)
        per_diameter = min(n * thinnest_d / L for n, L in zip(grid[:dim], lengths[:dim]))
        scale = scene.numerics.stokes.fibre_radius_scale
        if per_diameter < STOKES_QUANTITATIVE_CELLS_PER_DIAMETER:
            # a radius scaled to the grid sets the fibres' rotation (its calibration measures it); the
            # effective viscosity keeps the coarse grid's bias
            biased = ("the effective viscosity is biased (5-9 % at 1-2 voxels per diameter); the fibres turn as the "
                      f"voxelised radius (fibre_radius_scale = {scale:g}) makes them, which a calibration to this grid "
                      "chooses (docs/fluid_coupled_ci.md#a-hydrodynamic-radius-calibrated-to-the-grid); use "
                      "cells_per_diameter = 4-8 for a quantitative viscosity" if scale != 1.0 else
                      "the effective viscosity and rotation rates are biased (5-9 % at 1-2 voxels per diameter); use "
                      "cells_per_diameter = 4-8 for quantitative results")
            warnings.append(
                f"numerics.stokes.cells_per_diameter: the Stokes grid {' x '.join(map(str, grid[:dim]))} resolves the "
                f"thinnest diameter {thinnest_d:g} by {per_diameter:.3g} voxels, below "
                f"{STOKES_QUANTITATIVE_CELLS_PER_DIAMETER}: {biased} (docs/physics.md#resolution)")
        if scene.numerics.stokes.fibre_shells != registry.default("numerics.stokes.fibre_shells") and scale <= 1.0:
            warnings.append(
                f"numerics.stokes.fibre_shells = {scene.numerics.stokes.fibre_shells!r} has no effect: the fibres get "
                f"no added shell at fibre_radius_scale = {scale:g} (it acts for a scale above 1)")
        uncalibrated = [f.name for f in good
                        if f.shape == "fibre" and scene.particles[f.index].equivalent_aspect_ratio is None]
        if scale != 1.0 and uncalibrated:
            warnings.append(
                f"numerics.stokes.fibre_radius_scale = {scale:g}: the Stokes solve turns the fibres like fibres of "
                f"another beta_e than their geometric shape's, but the beta_e the run records for "
                f"{', '.join(uncalibrated)} (Folgar-Tucker fits, contacts-only twins) is the default rule's "
                f"({EQUIVALENT_ASPECT_RATIO_DEFAULT!r}); set particles.equivalent_aspect_ratio to the rule the scale "
                f"was calibrated to (docs/fluid_coupled_ci.md#a-hydrodynamic-radius-calibrated-to-the-grid)")

    fam_tables = []
    for f in good:
        raw = scene.particles[f.index]
        update: dict[str, object] = {"name": f.name}
        if raw.shape == "fibre":
            update["equivalent_aspect_ratio"] = raw.equivalent_aspect_ratio or EQUIVALENT_ASPECT_RATIO_DEFAULT
        if raw.orientation == "aligned":
            update["direction"] = [float(v) for v in f.axes[0]]
        elif f.orientation == "given" and not isinstance(raw.orientations, str):
            update["orientations"] = f.axes.tolist()  # inline axes, normalised like direction
        if f.orientation != raw.orientation:
            update["orientation"] = f.orientation
        fam_tables.append(raw.model_copy(update=update))
    normalised = scene.model_copy(update={
        "particles": fam_tables,
        "model": model.model_copy(update={"hydrodynamics": hydrodynamics, "collisions": collisions, "alpha": alpha}),
        **({"numerics": num.model_copy(update={"stokes": st.model_copy(update={"backend": backend})})}
           if hydrodynamics == "stokes" else {}),
        "output": out.model_copy(update={
            "interval": every["interval"] * num.dt,
            "snapshot_interval": every["snapshot_interval"] * num.dt,
            "checkpoint_interval": every["checkpoint_interval"] * num.dt,
        }),
    })
    return ResolvedScene(
        scene=normalised, dim=dim, cell_lengths=lengths, walls=walls,
        wall_speed=float(G[0, 1]) * 0.5 * lengths[1] if walls else 0.0,
        velocity_gradient=G3, shear_rate=rate, viscosity=scene.fluid.viscosity, dt=num.dt, t_end=num.t_end,
        n_steps=n_steps, seed=num.seed, hydrodynamics=hydrodynamics, collisions=collisions,
        reason="; ".join(reasons), alpha=alpha, contact_max_iter=model.contact_max_iter,
        on_contact_cap=model.on_contact_cap, lubrication=model.lubrication,
        output_every=every["interval"], snapshot_every=every["snapshot_interval"],
        checkpoint_every=every["checkpoint_interval"], families=tuple(good), regime=regime,
        regime_measure=measure, regime_threshold=longest.aspect_ratio, warnings=tuple(warnings),
        stokes_grid=grid if hydrodynamics == "stokes" else None,
    )


def backend_mismatch(choice: str, walls: bool) -> str:
    """Why ``numerics.stokes.backend = choice`` cannot solve a cell with (``walls``) or
    without no-slip walls, with the allowed choices; empty when it can (``"auto"``
    always can: pyfold.scene.registry.backend_for)."""
    fits = registry.backend_for(walls)
    if choice == registry.AUTO_BACKEND or registry.backend_capable(choice, walls):
        return ""
    allowed = f"allowed: {fits!r} or {registry.AUTO_BACKEND!r}, got {choice!r}"
    if walls:
        return (f"'{choice}' solves fully periodic cells only: its Fourier basis cannot impose the no-slip walls of "
                f"cell.boundary = 'couette'; {allowed}")
    return (f"'{choice}' is for cells with walls (cell.boundary = 'couette'): its staggered grid is rectangular and "
            f"cannot follow the Lees-Edwards lattice of a periodic cell in shear; {allowed}")


#: FFT sizes FFTW handles with its fastest codelets: 2^a 3^b 5^c 7^d.
def _fft_size(n: int) -> int:
    """The smallest ``2^a 3^b 5^c 7^d >= max(2, n)``: a bounded search over the
    exponents (O(log^3 n) products; a power of two below ``2n`` always qualifies)."""
    n = max(2, int(n))
    best = 1 << (n - 1).bit_length()
    p3 = 1
    while p3 < best:
        p5 = p3
        while p5 < best:
            p7 = p5
            while p7 < best:
                m = p7
                while m < n:
                    m *= 2
                best = min(best, m)
                p7 *= 7
            p5 *= 5
        p3 *= 3
    return best


def stokes_grid(lengths, diameter: float, cells_per_diameter: int,
                max_points: int | None = None) -> tuple[int, int, int]:
    """Voxel counts of the Stokes grid: at least ``cells_per_diameter`` voxels across
    ``diameter`` along every axis, each count rounded up to an FFT-friendly size
    (``2^a 3^b 5^c 7^d``); ``(nx, ny, 1)`` in 2-D. When the unrounded grid already has
    more than ``max_points`` points (the budget, ``numerics.stokes.max_grid_points``)
    the unrounded counts are returned: such a grid is refused anyway.

    Parameters
    ----------
    lengths : sequence of float
        Cell side lengths, one per dimension [m].
    diameter : float
        Thinnest particle diameter 2R [m].
    cells_per_diameter : int
        Target resolution (4-8 for quantitative results, docs/physics.md#resolution).
    """
    h = diameter / cells_per_diameter
    raw = [max(1, int(np.ceil(float(L) / h * (1.0 - 1e-12)))) for L in lengths]
    total = 1
    for n in raw:
        total *= n
    if max_points is not None and total > max_points:
        counts = raw
    else:
        counts = [_fft_size(n) for n in raw]
    return tuple(counts + [1] * (3 - len(counts)))


def _grid_megabytes(grid, dim: int) -> float:
    """Memory of the Stokes solver: about 34 doubles per voxel in 3-D (6 strain fields,
    viscosity, 4 CG vectors of 3 complex half-spectrum components, tables), 20 in 2-D."""
    per = 34 if dim == 3 else 20
    return float(np.prod(grid)) * per * 8 / 1e6
