"""The scene settings and the Stokes backends, each declared once, as data.

Every key of a scene file (each field of the schema that is not a table) is a
:class:`Setting`: its TOML path, type, range or enumeration (words and their integer
codes), default, units, the physics that uses it, a help text, and the
``/setup/resolved`` dataset and legend it is written as when ``fold_run`` reads it.
Every Stokes backend is a :class:`Backend` with the capabilities the normaliser, the
bindings and ``fold_run`` ask about instead of testing names.

Views of these tables (generated or computed, never copied by hand):

* the scene schema's fields (``pyfold/scene/schema.py``: :func:`pyfold.scene.schema_fields.field`),
* the code tables of the normaliser and the bindings (``pyfold/scene/normalise.py``,
  ``pyfold/native/stokes.py``: :func:`codes`) and the legends of ``/setup/resolved``,
* ``fortran/core/fold_settings.f90``: codes, ranges, defaults and capabilities that
  ``fortran/io/fold_run_file.f90`` and ``fortran/stokes/fold_stokes_solver.f90`` use,
  written by ``scripts/generate_settings``,
* the tables of ``docs/scenes.md`` between ``<!-- settings:... -->`` markers, same script,
* ``fortran/stokes/solver_modules.txt``: the module, constructor and code constant of each
  rigidity formulation and of each backend not on an FFT transport, same script; from it
  ``fortran/stokes/meson.build`` compiles the modules and writes the construction calls into
  ``fold_stokes_build.f90.in`` and ``fold_stokes_factory.f90.in``.

``tests/micro/test_settings_registry.py`` fails when a generated copy is stale.
This module uses the standard library only, so the generator runs without the
package's dependencies.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import ClassVar, Mapping

__all__ = ["Setting", "Backend", "Rigidity", "SETTINGS", "BACKENDS", "RIGIDITIES", "AUTO_BACKEND", "setting", "codes", "resolved",
           "in_range", "range_text",
           "backend_for", "backend_capable", "DEFAULT_ALPHA_OVER_RADIUS", "KAPPA_MIN", "KAPPA_MAX",
           "MAGNITUDE_LIMIT", "SMALLEST", "MAX_LENGTH_RATIO", "MAX_PARTICLES_PER_FAMILY",
           "EQUIVALENT_ASPECT_RATIO_DEFAULT", "FILE_PATH_MAX"]

#: Largest value of a 32-bit signed integer (counts and seeds fold_run holds in default integers).
INT32_MAX = 2**31 - 1

#: Bounds of the viscosity contrast kappa = eta_solid / eta_f. kappa = 1 is a particle-free
#: fluid, a test of the solver; the rigidity error falls like 1/kappa
#: (docs/physics.md#fictitious-domain-penalisation) and 1e12 keeps kappa eta_f and the CG
#: residuals within double precision. A run allows at most the kappa_max of
#: pyfold.native.stokes.kappa_range at its grid, tolerance and precision, usually far less.
KAPPA_MIN, KAPPA_MAX = 1.0, 1.0e12

#: Default security zone as a fraction of the smallest particle radius (the seed's
#: Couette scene uses alpha = R / 15; a tenth keeps alpha below a grid cell at the
#: default 4 cells per diameter). pyfold.scene.sheared_fibres takes its default from it.
DEFAULT_ALPHA_OVER_RADIUS = 0.1

#: Every dimensional value (lengths [m], rates [1/s], viscosity [Pa s]) must lie within
#: 30 decades of 1: any consistent unit system works (SI fibres are ~1e-5 m, lengths in
#: fibre lengths are ~1), and then a volume (L^3, <= 1e90) or a product of a few such
#: values stays finite and normal in double precision (limits 1e+-308).
MAGNITUDE_LIMIT = 1e30
#: its reciprocal, the smallest length or viscosity
SMALLEST = 1e-30

#: Largest ratio of the longest cell side to the smallest particle radius (and so of any
#: two lengths of a scene: every particle must fit in half the cell). 1e6 radii per side
#: is far beyond any simulation (the Stokes grid, the cell lists, the particle count all
#: scale with it); it keeps cell / particle volume ratios <= 1e18 and grid sizes finite.
MAX_LENGTH_RATIO = 1e6

#: Largest number of particles of one family: ``count``, or the count a
#: ``volume_fraction`` gives (one cap, applied to both).
MAX_PARTICLES_PER_FAMILY = 10_000_000

#: Default rule for the equivalent aspect ratio of a finite cylinder: Cox (1971,
#: J. Fluid Mech. 45:625) slender-body result ``beta_e = 1.24 beta / sqrt(ln beta)``,
#: the classic choice for long fibres (docs/physics.md#equivalent-aspect-ratio-of-a-finite-cylinder).
EQUIVALENT_ASPECT_RATIO_DEFAULT = "cox"

#: Longest name of a data file in a scene (``.csv`` or ``.npy``, relative to the scene file)
FILE_PATH_MAX = 4096


@dataclass(frozen=True)
class Setting:
    """One scene setting.

    ``kind`` is ``"choice"`` (a word of ``choices``), ``"integer"``, ``"real"``,
    ``"bool"``, ``"vector"`` (``size`` reals), ``"matrix"`` (``rows`` vectors of ``size``
    reals; with ``file`` also the name of a data file holding them) or ``"text"`` (``size``
    characters matching ``pattern``). A numeric range, of a number or of each entry of a
    vector or matrix, is ``[lo, hi]``, a bound excluded when ``lo_open`` / ``hi_open``;
    ``None`` is unbounded; ``values``, when given, are the only integers allowed (``lo``
    and ``hi`` their extremes). A bound is written as the pydantic message should name it
    (``0``, not ``0.0``: "greater than 0"). ``codes`` maps a word to the integer written to
    ``/setup/resolved`` (a word without a code, like the backend's ``"auto"``, is
    resolved by the normaliser first). ``default`` ``None``: computed by the normaliser
    (``default_text`` says how) or required.
    """

    path: str
    kind: str
    default: object = None
    choices: tuple[str, ...] = ()
    codes: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    lo: float | int | None = None
    hi: float | int | None = None
    lo_open: bool = False
    hi_open: bool = False
    units: str = "1"
    physics: str = "all"
    help: str = ""
    #: name of the /setup/resolved dataset, and its legend (long_name)
    resolved: str | None = None
    legend: str = ""
    #: fold_run reads the dataset only when present (older run files): the default stands in
    optional: bool = False
    #: stem of the generated Fortran constants (FOLD_LO_<stem>, FOLD_HI_<stem>, FOLD_DEF_<stem>)
    fortran: str | None = None
    #: prefix of the named Fortran code constants, and the constant per word when not <prefix><WORD>
    fortran_codes: str | None = None
    default_text: str = ""
    #: the only integers allowed (kind "integer"), lo and hi their extremes
    values: tuple[int, ...] = ()
    #: (fewest, most) entries of a vector or of each row of a matrix, characters of a text;
    #: None: no bound on that side
    size: tuple[int | None, int | None] | None = None
    #: (fewest, most) rows of a matrix
    rows: tuple[int | None, int | None] | None = None
    #: a matrix may instead be given as the name of a .csv / .npy file (relative to the scene file)
    file: bool = False
    #: regular expression a text matches
    pattern: str | None = None
    #: a setting added after sweeps had named their runs: at its default it is left out of a run's
    #: identity (pyfold.sweep.plan.run_id), so the runs named before it existed keep their names
    #: (its default reproduces what those runs simulated)
    identity_at_default: bool = True

    @property
    def key(self) -> str:
        """The last component of the TOML path (the pydantic field name)."""
        return self.path.rsplit(".", 1)[-1]

    def code_names(self) -> dict[str, int]:
        """Fortran constant name -> code of each coded word."""
        return {f"{self.fortran_codes}{word.upper()}": code for word, code in self.codes.items()}

    def code_range(self) -> tuple[int, int]:
        """Smallest and largest code (the range fold_run accepts)."""
        return min(self.codes.values()), max(self.codes.values())

    def legend_of_codes(self) -> str:
        """``"0 stop, 1 continue"``: the codes in increasing order."""
        return ", ".join(f"{c} {w}" for w, c in sorted(self.codes.items(), key=lambda wc: wc[1]))


def _codes(**table: int) -> Mapping[str, int]:
    return MappingProxyType(dict(table))


_STOKES = "stokes"
_CONTACTS = "contacts"

#: The backend choice that has no code: :func:`backend_for` resolves it from the cell.
AUTO_BACKEND = "auto"


class _Coded:
    """A registry entry named by a word of an enumerated setting (``SETTING``). The
    setting's words, codes, legend and help are made from its entries (:func:`_words`,
    :func:`_legend`, :func:`_help`), so an entry is the only place that names it."""

    #: TOML path of the setting whose words name the entries
    SETTING: ClassVar[str] = ""

    @property
    def fortran_code(self) -> str:
        """Name of its generated Fortran code constant (``FOLD_STOKES_HYPRE``, ``FOLD_RIGIDITY_EXACT``)."""
        return f"{setting(self.SETTING).fortran_codes}{self.name.upper()}"  # type: ignore[attr-defined]


@dataclass(frozen=True)
class Rigidity(_Coded):
    """A rigidity formulation of the Stokes solve (a ``numerics.stokes.rigidity`` word):
    what the rest of the code asks of it instead of testing its name."""

    SETTING: ClassVar[str] = "numerics.stokes.rigidity"
    name: str
    #: its /setup/resolved/stokes_rigidity code
    code: int
    #: the solid is a viscosity kappa eta_f (numerics.stokes.kappa applies, and its
    #: grid-dependent bound, pyfold/scene/kappa_range.py and fold_stokes_trust)
    uses_kappa: bool
    #: FFT precisions it can run with
    fft_precisions: tuple[str, ...]
    #: what it is, for messages
    summary: str
    #: what it is in the setting's /setup/resolved legend and in its help text
    legend: str
    help: str
    #: its module (fortran/stokes/<module>.f90) and constructor on an FFT transport,
    #: ``constructor(fft, set, solver, stat, errmsg)``, which fold_stokes_build calls for
    #: its code (generated from fortran/stokes/solver_modules.txt)
    fortran_module: str
    constructor: str


#: Rigidity formulations of the FFT-transport backends. A new one is an entry here and
#: its module in fortran/stokes: the numerics.stokes.rigidity setting takes its word, code,
#: legend and help from the entries, every FFT-transport backend offers it, and
#: scripts/generate_settings lists its module and constructor in
#: fortran/stokes/solver_modules.txt, from which meson compiles the module and writes its
#: construction call into fold_stokes_build. Nothing else names it
#: (tests/micro/test_solver_seam.py); docs/architecture.md, "A Stokes solver".
RIGIDITIES: Mapping[str, Rigidity] = MappingProxyType({
    "penalty": Rigidity("penalty", code=0, uses_kappa=True, fft_precisions=("double", "single"),
                        summary="the seed's penalty: viscosity kappa eta_f in the solid",
                        legend="kappa", help="viscosity kappa eta_f in the solid",
                        fortran_module="fold_stokes_fft", constructor="stokes_fft_new"),
    "exact": Rigidity("exact", code=1, uses_kappa=False, fft_precisions=("double",),
                      summary="eps(u) = 0 on the solid voxels by a multiplier",
                      legend="multiplier on the solid voxels", help="eps(u) = 0 by a multiplier",
                      fortran_module="fold_stokes_rigid", constructor="stokes_rigid_new"),
})


@dataclass(frozen=True)
class Backend(_Coded):
    """A Stokes backend of fortran/stokes and its capabilities."""

    SETTING: ClassVar[str] = "numerics.stokes.backend"
    name: str
    #: its /setup/resolved/stokes_backend code
    code: int
    #: solves a cell with no-slip walls at y = 0, Ly
    walls: bool
    #: follows the sheared (Lees-Edwards) lattice of a periodic cell in shear
    lees_edwards: bool
    #: follows a deforming (elongational) lattice
    deforming_lattice: bool
    #: precisions of its FFTs (empty: it has none, numerics.stokes.fft_precision does not apply)
    fft_precisions: tuple[str, ...]
    #: runs on several MPI ranks
    mpi: bool
    #: rigidity formulations (numerics.stokes.rigidity words): every one of RIGIDITIES on
    #: an FFT transport, which the formulations construct
    rigidities: tuple[str, ...]
    #: built on an FFT transport (fortran/stokes/fold_fft_transport.f90: serial FFTW or FFTW-MPI slabs)
    fft_transport: bool
    #: runs in one process without MPI (the Python extensions, pyfold.native.stokes)
    serial: bool
    #: what it is, for messages
    summary: str
    #: what it is in the setting's /setup/resolved legend and in its help text
    legend: str
    help: str
    #: a backend not on an FFT transport: its module (fortran/stokes/<module>.f90) and
    #: constructor, ``constructor(set, dim, n, comm, solver, stat, errmsg)``, which
    #: fold_stokes_factory calls for its code (generated from solver_modules.txt). None for
    #: an FFT-transport backend: the rigidity formulation (:class:`Rigidity`) makes it.
    fortran_module: str | None = None
    constructor: str | None = None


#: Stokes backends. A new one is an entry here and its module in fortran/stokes (the
#: numerics.stokes.backend setting takes its word, code, legend and help from the
#: entries): a backend on an FFT transport is made by the rigidity formulations
#: (RIGIDITIES); any other names its fortran_module and constructor, which
#: scripts/generate_settings lists in fortran/stokes/solver_modules.txt: meson compiles the
#: module and writes its construction call into fold_stokes_factory. Nothing else names it
#: (tests/micro/test_solver_seam.py); docs/architecture.md, "A Stokes solver".
BACKENDS: Mapping[str, Backend] = MappingProxyType({
    "fft": Backend("fft", code=1, walls=False, lees_edwards=True, deforming_lattice=False,
                   fft_precisions=("double", "single"), mpi=True, rigidities=tuple(RIGIDITIES), fft_transport=True,
                   serial=True, summary="FFT-preconditioned CG on the periodic, Lees-Edwards cell",
                   legend="periodic cell", help="periodic, Lees-Edwards cell"),
    "hypre": Backend("hypre", code=2, walls=True, lees_edwards=False, deforming_lattice=False, fft_precisions=(),
                     mpi=True, rigidities=("penalty",), fft_transport=False, serial=False,
                     summary="staggered grid with no-slip walls", legend="cell with walls", help="cell with walls",
                     fortran_module="fold_stokes_hypre", constructor="stokes_hypre_new"),
})


def _words(entries: Mapping[str, _Coded], *first: str) -> tuple[tuple[str, ...], Mapping[str, int]]:
    """The words (``first``, which have no code, then the entries') and codes of the
    setting whose words name ``entries``."""
    return (*first, *entries), _codes(**{name: e.code for name, e in entries.items()})  # type: ignore[attr-defined]


def _legend(head: str, entries: Mapping[str, _Coded]) -> str:
    """``"head: 0 word (legend), 1 word (legend)"``, the /setup/resolved legend."""
    return f"{head}: " + ", ".join(f"{e.code} {name} ({e.legend})" for name, e in entries.items())  # type: ignore[attr-defined]


def _help(entries: Mapping[str, _Coded], *more: tuple[str, str]) -> str:
    """``'"word" (help), ... or "word" (help)'`` over the entries and ``more`` (word, help)."""
    items = [f'"{name}" ({e.help})' for name, e in entries.items()] + [f'"{w}" ({h})' for w, h in more]  # type: ignore[attr-defined]
    return ", ".join(items[:-1]) + " or " + items[-1] if len(items) > 1 else items[0]


SETTINGS: tuple[Setting, ...] = (
    # ---- top level
    Setting("title", "text", "", size=(None, 200), help="short title of the scene"),
    Setting("description", "text", "", size=(None, 4000), help="free description of the scene"),
    # ---- [cell]
    Setting("cell.dim", "integer", 3, lo=2, hi=3, values=(2, 3), resolved="dim", legend="spatial dimension",
            fortran="DIM", help="spatial dimension, 2 or 3"),
    Setting("cell.size", "vector", None, lo=SMALLEST, hi=MAGNITUDE_LIMIT, size=(2, 3), units="m",
            help="side lengths (Lx, Ly[, Lz]), one per dimension"),
    Setting("cell.boundary", "choice", "periodic", ("periodic", "couette"),
            help='"periodic" on every side, or "couette": no-slip walls at y = 0 and y = Ly moving at -U and +U '
                 '(U = rate Ly / 2), periodic in x (and z)'),
    # ---- [flow]
    Setting("flow.type", "choice", "simple_shear", ("simple_shear", "planar_elongation", "uniaxial_elongation", "general"),
            help="the imposed mean flow u = G . x"),
    Setting("flow.rate", "real", None, lo=-MAGNITUDE_LIMIT, hi=MAGNITUDE_LIMIT, units="1/s",
            default_text='required unless type = "general"',
            help="simple shear: G_xy = rate; planar elongation: G = diag(rate, -rate[, 0]); "
                 "uniaxial elongation: G = diag(rate, -rate/2, -rate/2)"),
    Setting("flow.gradient", "matrix", None, lo=-MAGNITUDE_LIMIT, hi=MAGNITUDE_LIMIT, size=(2, 3), rows=(2, 3),
            units="1/s", default_text='required with type = "general"',
            help='the full velocity gradient G_ij = du_i/dx_j (dim x dim, traceless), type = "general" only'),
    # ---- [fluid]
    Setting("fluid.viscosity", "real", 1.0, lo=SMALLEST, hi=MAGNITUDE_LIMIT, units="Pa s", resolved="viscosity",
            legend="fluid viscosity", fortran="VISCOSITY", help="dynamic viscosity of the suspending Newtonian fluid"),
    # ---- [[particles]]
    Setting("particles.name", "text", None, size=(1, 64), pattern=r"^[A-Za-z0-9_.+-]+$",
            default_text='`"family<index>"`', help="label used in outputs"),
    Setting("particles.shape", "choice", None, ("fibre", "sphere", "spheroid"),
            _codes(fibre=1, sphere=2, spheroid=3), resolved="family_shape", legend="1 fibre, 2 sphere, 3 spheroid",
            fortran="SHAPE",
            help="cylinder (R, L); sphere (2-D disk); prolate spheroid, semi-axes L/2 and R (2-D ellipse)"),
    Setting("particles.radius", "real", None, lo=SMALLEST, hi=MAGNITUDE_LIMIT, units="m",
            help="fibre cross-section radius, sphere radius, spheroid minor semi-axis"),
    Setting("particles.length", "real", None, lo=SMALLEST, hi=MAGNITUDE_LIMIT, units="m",
            default_text="from aspect_ratio", help="fibre (cylinder) length or spheroid major axis; not for spheres"),
    Setting("particles.aspect_ratio", "real", None, lo=0, hi=MAX_LENGTH_RATIO, lo_open=True,
            default_text="from length", help="length / (2 radius), an alternative to length; not for spheres"),
    Setting("particles.count", "integer", None, lo=1, hi=MAX_PARTICLES_PER_FAMILY,
            default_text="from volume_fraction", help="number of particles (give exactly one of count, volume_fraction)"),
    Setting("particles.volume_fraction", "real", None, lo=0, hi=1, lo_open=True, hi_open=True,
            default_text="from count", help="fraction of the cell volume (area in 2-D) the family fills"),
    Setting("particles.orientation", "choice", "isotropic", ("isotropic", "aligned", "planar_random", "given"),
            help="initial orientations of the family"),
    Setting("particles.direction", "vector", None, size=(2, 3), default_text="x, the flow direction",
            help='axis of every particle for orientation = "aligned" (normalised)'),
    Setting("particles.orientations", "matrix", None, size=(2, 3), file=True,
            default_text='required with orientation = "given"',
            help='one axis per particle (count x dim) for orientation = "given" (each normalised), inline or a '
                 ".csv / .npy file (one row per particle)"),
    Setting("particles.positions", "matrix", None, size=(2, 3), file=True, units="m", default_text="random placement",
            help="given centres, one per particle (n x dim), inline or a .csv / .npy file (one row per particle; "
                 "a CSV may start with a header line): the count is the number of rows"),
    Setting("particles.equivalent_aspect_ratio", "choice", None, ("cox", "zhang", "harris_pittman"),
            default_text=f'`"{EQUIVALENT_ASPECT_RATIO_DEFAULT}"` (finite cylinders)',
            help="finite cylinders only: rule giving the equivalent spheroid aspect ratio "
                 "(Cox 1971, Zhang et al. 2011, Harris & Pittman 1975)"),
    # ---- [model]
    Setting("model.hydrodynamics", "choice", "auto", ("auto", "jeffery", "stokes"), _codes(jeffery=0, stokes=1),
            resolved="hydrodynamics", legend="0 jeffery, 1 stokes", fortran="HYDRODYNAMICS",
            fortran_codes="FOLD_HYDRO_",
            help='"auto" (chosen from the regime), "jeffery" (imposed-flow kinematics) or "stokes"'),
    Setting("model.collisions", "choice", "auto", ("auto", "strategy", "naive", "none"),
            _codes(none=0, naive=1, strategy=2), physics=_CONTACTS, resolved="collisions",
            legend="0 none, 1 naive, 2 strategy", fortran="COLLISIONS",
            help='"auto" (chosen from the regime), "strategy" (seed loop with cell lists), '
                 '"naive" (same rule, O(N^2) reference) or "none"'),
    Setting("model.alpha", "real", None, lo=0.0, units="m", physics=_CONTACTS, resolved="alpha",
            legend="security zone alpha", fortran="ALPHA",
            default_text=f"{DEFAULT_ALPHA_OVER_RADIUS:g} × smallest radius",
            help="security zone alpha, at most the smallest particle radius"),
    Setting("model.contact_max_iter", "integer", 100, lo=1, hi=100_000, physics=_CONTACTS,
            resolved="contact_max_iter", legend="cap on contact iterations per step", fortran="CONTACT_MAX_ITER",
            help="cap on contact-correction iterations per step"),
    Setting("model.on_contact_cap", "choice", "stop", ("stop", "continue"),
            MappingProxyType({"stop": 0, "continue": 1}), physics=_CONTACTS,
            resolved="on_contact_cap", legend="0 stop, 1 continue", fortran="ON_CONTACT_CAP",
            help='what to do when the cap is hit: "stop" the run (status failed) or "continue" and count it'),
    Setting("model.lubrication", "bool", False, physics=_STOKES, resolved="lubrication",
            legend="sphere-sphere lubrication on (1) or off (0)", fortran="LUBRICATION",
            help="sphere-sphere lubrication force; spheres only"),
    # ---- [numerics]
    Setting("numerics.dt", "real", None, lo=0, lo_open=True, units="s", resolved="dt", legend="time step",
            fortran="DT", default_text='required, unless numerics.preset = "study" chooses it',
            help="time step"),
    Setting("numerics.t_end", "real", None, lo=0, lo_open=True, units="s", resolved="t_end", legend="end time",
            fortran="T_END", help="end time; a multiple of dt"),
    Setting("numerics.seed", "integer", 0, lo=0, hi=INT32_MAX, resolved="seed", legend="random seed",
            help="seed of every random draw (placement, orientations)"),
    Setting("numerics.preset", "choice", None, ("study",),
            default_text="none: each key keeps its own default",
            help='"study": every numerical setting the scene leaves '
                 'unset (dt and the Stokes kappa, tolerance, precision, solve reuse and resolution, with the '
                 'fibre radius calibrated to the grid, and its shell rule, where that was measured) chosen, for the scene\'s regime '
                 'and aspect ratio, as the cheapest measured to move C_I by less than half its statistical '
                 'error over 4 seeds; a stated grid known to be too coarse is kept with a warning '
                 '(pyfold/scene/study_preset.py, docs/speed_accuracy.md)'),
    Setting("numerics.time_scheme", "choice", "ab2", ("ab2", "euler"), _codes(euler=1, ab2=2), physics=_STOKES,
            resolved="time_scheme",
            legend="time scheme of the Stokes velocities: 1 explicit Euler, 2 Adams-Bashforth 2",
            fortran="TIME_SCHEME", help='"ab2" (Adams-Bashforth 2, first step Euler) or "euler" (explicit Euler)'),
    # ---- [numerics.stokes]
    Setting("numerics.stokes.backend", "choice", "auto", *_words(BACKENDS, AUTO_BACKEND),
            physics=_STOKES, resolved="stokes_backend", legend=_legend("Stokes backend", BACKENDS),
            fortran="STOKES_BACKEND", fortran_codes="FOLD_STOKES_",
            help=_help(BACKENDS, (AUTO_BACKEND, "the backend of the cell"))),
    Setting("numerics.stokes.tolerance", "real", 1.0e-6, lo=0.0, hi=1.0, lo_open=True, hi_open=True,
            physics=_STOKES, resolved="stokes_tolerance",
            legend="relative preconditioned CG residual of a Stokes solve", fortran="STOKES_TOLERANCE",
            help="relative (preconditioned) residual at which the conjugate-gradient solve stops"),
    Setting("numerics.stokes.max_iterations", "integer", 1000, lo=1, hi=1_000_000, physics=_STOKES,
            resolved="stokes_max_iterations", legend="CG iteration cap of a Stokes solve",
            fortran="STOKES_MAX_ITERATIONS", help="CG iteration cap per solve; reaching it stops the run"),
    Setting("numerics.stokes.kappa", "real", 1.0e3, lo=KAPPA_MIN, hi=KAPPA_MAX, physics=_STOKES,
            resolved="stokes_kappa", legend="viscosity contrast kappa = eta_solid / eta_fluid",
            fortran="STOKES_KAPPA", help="viscosity contrast of the penalisation eta_solid / eta_fluid"),
    Setting("numerics.stokes.cells_per_diameter", "integer", 4, lo=1, hi=64, physics=_STOKES,
            help="grid cells per diameter of the thinnest particle"),
    Setting("numerics.stokes.max_grid_points", "integer", 64**3, lo=8, hi=INT32_MAX, physics=_STOKES,
            help="largest Stokes grid (voxel count) allowed"),
    Setting("numerics.stokes.derivative", "choice", "fd", ("fd", "spectral"), _codes(spectral=0, fd=1),
            physics=_STOKES, resolved="stokes_derivative",
            legend="0 spectral, 1 rotated finite differences (Willot 2015)", fortran="STOKES_DERIVATIVE",
            fortran_codes="FOLD_DERIV_", help='"fd" (rotated finite differences) or "spectral" (i k)'),
    Setting("numerics.stokes.mixing", "choice", "harmonic", ("harmonic", "arithmetic", "geometric"),
            _codes(arithmetic=0, harmonic=1, geometric=2), physics=_STOKES, resolved="stokes_mixing",
            legend="viscosity of partially covered voxels: 0 arithmetic, 1 harmonic, 2 geometric",
            fortran="STOKES_MIXING", fortran_codes="FOLD_MIX_",
            help="viscosity of a partially covered voxel"),
    Setting("numerics.stokes.subsamples", "integer", 3, lo=1, hi=8, physics=_STOKES, resolved="stokes_subsamples",
            legend="sub-samples per voxel edge of the partial-volume chi", fortran="STOKES_SUBSAMPLES",
            help="sub-samples per voxel edge of the partial-volume chi"),
    Setting("numerics.stokes.fibre_ends", "choice", "flat", ("flat", "capped"), _codes(flat=0, capped=1),
            physics=_STOKES, resolved="stokes_fibre_ends", legend="fibre ends of the voxelisation: 0 flat, 1 capped",
            fortran="STOKES_FIBRE_ENDS", fortran_codes="FOLD_ENDS_",
            help='fibre ends of the voxelised particle: "flat" cylinder or "capped" (the contact capsule)'),
    Setting("numerics.stokes.fibre_radius_scale", "real", 1.0, lo=0.5, hi=2.0, physics=_STOKES,
            resolved="stokes_fibre_radius_scale", optional=True, identity_at_default=False,
            legend="radius of the voxelised fibre over its geometric radius", fortran="STOKES_FIBRE_RADIUS_SCALE",
            help="radius of the voxelised fibre (its hydrodynamic radius on the grid) over its geometric radius; "
                 "contacts, volume fraction and the Jeffery shape factor keep the geometric one "
                 "(docs/fluid_coupled_ci.md#a-hydrodynamic-radius-calibrated-to-the-grid)"),
    Setting("numerics.stokes.fibre_shells", "choice", "overlap", ("overlap", "apart"), _codes(overlap=0, apart=1),
            physics=_STOKES, resolved="stokes_fibre_shells", optional=True, identity_at_default=False,
            legend="with fibre_radius_scale > 1, the shells added to near fibres: 0 overlap (coverages add up), "
                   "1 kept apart by the security zone alpha",
            fortran="STOKES_FIBRE_SHELLS", fortran_codes="FOLD_SHELLS_",
            help='with fibre_radius_scale > 1, the shell of radius (s - 1) R added to each fibre near another '
                 'particle: "overlap", the shells of near fibres overlap and their coverages add up (clipped at '
                 '1), so fibres closer than 2 (s - 1) R share rigid voxels; "apart", a shell ends where it would '
                 'come closer than the security zone alpha to another particle\'s geometric surface (the shells '
                 'of two fibres share the gap between them), so the voxelised bodies stay at least alpha apart, '
                 'as the contacts keep the geometric ones (docs/fluid_coupled_ci.md#fibre-shells-kept-apart)'),
    Setting("numerics.stokes.warm_start", "bool", True, physics=_STOKES, resolved="stokes_warm_start",
            legend="1: each CG solve starts from the previous solution, 0: from zero", fortran="STOKES_WARM_START",
            help="start each CG solve from the previous solution (see initial_guess) or from zero"),
    Setting("numerics.stokes.fft_plan", "choice", "measure", ("measure", "estimate"), _codes(estimate=0, measure=1),
            physics=_STOKES, resolved="stokes_fft_plan", legend="FFTW planning: 0 estimate, 1 measure",
            fortran="STOKES_FFT_PLAN",
            help='FFTW planning: "measure" (faster transforms) or "estimate" (bitwise reproducible)'),
    Setting("numerics.stokes.fft_precision", "choice", "double", ("double", "single"), _codes(double=0, single=1),
            physics=_STOKES, resolved="stokes_fft_precision", optional=True,
            legend="precision of the CG operator's FFTs: 0 double, 1 single", fortran="STOKES_FFT_PRECISION",
            fortran_codes="FOLD_FFT_", help="precision of the FFTs of the CG operator"),
    Setting("numerics.stokes.rigidity", "choice", "penalty", *_words(RIGIDITIES),
            physics=_STOKES, resolved="stokes_rigidity", optional=True,
            legend=_legend("rigidity of the particles", RIGIDITIES), fortran="STOKES_RIGIDITY",
            fortran_codes="FOLD_RIGIDITY_", help=_help(RIGIDITIES)),
    Setting("numerics.stokes.initial_guess", "choice", "previous", ("previous", "extrapolate"),
            _codes(previous=1, extrapolate=2), physics=_STOKES, resolved="stokes_initial_guess", optional=True,
            legend="CG initial guess: 1 previous solution, 2 extrapolated from the last two",
            fortran="STOKES_INITIAL_GUESS", fortran_codes="FOLD_GUESS_",
            help='initial guess of each CG solve: "previous" or "extrapolate" (2 u_n - u_(n-1))'),
    Setting("numerics.stokes.solve_every", "integer", 1, lo=1, hi=1000, physics=_STOKES,
            resolved="stokes_solve_every", optional=True,
            legend="a Stokes solve every k-th step, velocities extrapolated linearly in between",
            fortran="STOKES_SOLVE_EVERY", help="a Stokes solve every k-th step only"),
    Setting("numerics.stokes.reuse", "choice", "linear", ("linear", "jeffery"), _codes(linear=1, jeffery=2),
            physics=_STOKES, resolved="stokes_reuse", optional=True, identity_at_default=False,
            legend="velocities between solves: 1 linear extrapolation of the last two solves, 2 each particle's "
                   "Jeffery velocity at its current state plus that extrapolation of its departure from it",
            fortran="STOKES_REUSE", fortran_codes="FOLD_REUSE_",
            help='with solve_every > 1, the velocities of the steps between solves: "linear", the linear '
                 'extrapolation of the last two solves; "jeffery", each particle\'s dilute Jeffery velocity '
                 'at its current position and axis plus the linear extrapolation of the solves\' departure '
                 'from it, so that the rotation in the mean flow is followed every step and only the '
                 'interactions are extrapolated (docs/physics.md#solve-re-use)'),
    # ---- [output]
    Setting("output.interval", "real", None, lo=0, lo_open=True, units="s",
            default_text="t_end / 100, rounded down to a multiple of dt",
            help="interval between records of the statistics (a2, a4, contact and drift counters)"),
    Setting("output.snapshot_interval", "real", None, lo=0, units="s",
            default_text="t_end / 10, rounded down to a multiple of dt",
            help="interval between particle snapshots (positions, axes); 0 = none"),
    Setting("output.checkpoint_interval", "real", None, lo=0, units="s",
            default_text="t_end / 20, rounded down to a multiple of dt",
            help="interval between restart checkpoints; 0 = none"),
)

_BY_PATH = {s.path: s for s in SETTINGS}
_BY_RESOLVED = {s.resolved: s for s in SETTINGS if s.resolved}


def setting(path: str) -> Setting:
    """The setting at TOML ``path`` (``"numerics.stokes.kappa"``)."""
    return _BY_PATH[path]


def resolved(name: str) -> Setting:
    """The setting written as ``/setup/resolved/<name>``."""
    return _BY_RESOLVED[name]


def codes(path: str) -> Mapping[str, int]:
    """Word -> integer code of an enumerated setting (read-only)."""
    return setting(path).codes


def default(path: str) -> object:
    """The default of the setting at ``path``."""
    return setting(path).default


def range_text(path: str) -> str:
    """The range of a numeric setting as text: ``[1, 1e+12]``, ``(0, 1)``, ``>= 1``."""
    s = setting(path)
    if s.lo is not None and s.hi is not None:
        return f"{'(' if s.lo_open else '['}{s.lo:g}, {s.hi:g}{')' if s.hi_open else ']'}"
    if s.lo is not None:
        return f"{'>' if s.lo_open else '>='} {s.lo:g}"
    return f"{'<' if s.hi_open else '<='} {s.hi:g}"


def in_range(path: str, value: float) -> bool:
    """Whether ``value`` lies in the range of the numeric setting at ``path`` (NaN never does)."""
    s = setting(path)
    if s.lo is not None and not (value > s.lo if s.lo_open else value >= s.lo):
        return False
    if s.hi is not None and not (value < s.hi if s.hi_open else value <= s.hi):
        return False
    return value == value


# ---------------------------------------------------------------------------------------
# Stokes backends and what each can do

def backend_for(walls: bool) -> str:
    """The backend ``"auto"`` stands for: the one that imposes walls in a cell with walls,
    the one that follows the Lees-Edwards lattice in a periodic cell.

    The backends are not interchangeable: the FFT solver's Fourier basis is periodic, so
    it cannot impose walls; hypre's staggered grid is rectangular, so it cannot follow the
    sheared lattice of a periodic cell in shear.
    """
    return next(b.name for b in BACKENDS.values() if (b.walls if walls else b.lees_edwards))


def backend_capable(name: str, walls: bool) -> bool:
    """Whether backend ``name`` solves a cell with (``walls``) or without no-slip walls."""
    b = BACKENDS[name]
    return b.walls if walls else b.lees_edwards
