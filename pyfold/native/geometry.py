"""Geometry, particle and contact kernels of the direct simulation (``pyfold._fold_geometry``).

Thin, shape-checking wrappers over the Fortran modules ``fold_cell`` (periodic
Lees–Edwards or Couette cell), ``fold_segment`` (segment–segment closest points,
capsule gaps), ``fold_cell_list`` (O(N) neighbour search under sheared images),
``fold_placement`` (seeded random non-overlapping placement), ``fold_kinematics``
(Jeffery 1922 kinematics, exact rigid rotation) and ``fold_contacts`` (the seed's
collision strategy, Laure, Megally & Coupez). Arrays are ``(N, dim)`` here and
``(dim, N)`` in Fortran; indices returned to Python are 0-based.

Frame rule (``fold_cell``): the imposed mean velocity is ``u = G·(x − L/2)`` (cell
centre at rest, walls at ∓U). Simple shear ``G[0, 1] = γ̇`` uses the Lees–Edwards
cell with primary cell ``[0, L)``; any other traceless ``G`` (planar or uniaxial
elongation, a general gradient) a lattice carried by the flow, ``A(t) = exp(G t) A0``,
reduced at every time (Minkowski-type reduction), with Kraynik–Reinelt remapping for
planar elongation in a cell with ``Lx = Ly`` (its lattice is then the square rotated
by the magic angle) and a limited admissible duration otherwise
(:func:`admissible_t_end`). Walls host simple shear only. Every particle is treated, for overlap and contact, as a
capsule (points within ``radius`` of an axis segment): exact for spheres, containing
the cylinder for fibres, and a *bounding* capsule (half-segment ``L/2 − R``) for
spheroids.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pyfold.errors import InputError, checked
from pyfold.native import load

FIBRE, SPHERE, SPHEROID = 1, 2, 3
"""Shape codes (``fold_particles``)."""
ORIENT_GIVEN, ORIENT_ISOTROPIC, ORIENT_PLANAR = 0, 1, 2
"""Orientation modes of :func:`place_particles` (``fold_placement``)."""
CONTACT_MODES = {"none": 0, "naive": 1, "strategy": 2}
ON_CAP = {"stop": 0, "continue": 1}


@dataclass(frozen=True)
class Cell:
    """Simulation cell.

    Parameters
    ----------
    lengths
        Edge lengths ``(Lx, Ly)`` in 2-D or ``(Lx, Ly, Lz)`` in 3-D [m]; sets ``dim``.
    walls
        No-slip walls at ``y = 0`` (moving at −U) and ``y = Ly`` (+U), periodic elsewhere.
    shear_rate
        γ̇ = G[0, 1] = du_x/dy [1/s].
    shear_offset
        Lees–Edwards offset ``s`` of the lattice vector ``a2 = (s, Ly, 0)`` [m]
        (``s = γ̇ t Ly`` wrapped to ``[−Lx/2, Lx/2)``; ignored with walls).
    velocity_gradient
        Full velocity gradient G[i, j] = du_i/dx_j, (dim, dim) or (3, 3) [1/s]; when
        given it replaces ``shear_rate``. A non-shear gradient makes the lattice deform
        with the flow (``fold_cell``).
    time
        Time of a deforming lattice (``A(t) = exp(G t) A0``, reduced) [s]; ignored in
        simple shear, whose state is ``shear_offset``.
    """

    lengths: tuple[float, ...]
    walls: bool = False
    shear_rate: float = 0.0
    shear_offset: float = 0.0
    velocity_gradient: tuple | None = None
    time: float = 0.0

    def __post_init__(self) -> None:
        lengths = tuple(float(v) for v in self.lengths)
        if len(lengths) not in (2, 3) or not all(np.isfinite(lengths)) or min(lengths) <= 0:
            raise InputError(f"cell lengths: expected 2 or 3 finite values > 0, got {self.lengths}")
        object.__setattr__(self, "lengths", lengths)
        if self.velocity_gradient is not None:
            g = np.asarray(self.velocity_gradient, dtype=np.float64)
            if g.shape not in ((len(lengths),) * 2, (3, 3)) or not np.all(np.isfinite(g)):
                raise InputError(f"velocity_gradient: expected a finite ({len(lengths)}, {len(lengths)}) or (3, 3) "
                                 f"array, got shape {g.shape}")
            g3 = np.zeros((3, 3))
            g3[: g.shape[0], : g.shape[1]] = g
            object.__setattr__(self, "velocity_gradient", tuple(map(tuple, g3.tolist())))
            object.__setattr__(self, "shear_rate", float(g3[0, 1]))

    @property
    def dim(self) -> int:
        return len(self.lengths)

    def lengths3(self) -> np.ndarray:
        out = np.ones(3)
        out[: self.dim] = self.lengths
        return out

    def gradient(self) -> np.ndarray:
        """Velocity gradient G (3, 3), G[i, j] = du_i/dx_j."""
        if self.velocity_gradient is not None:
            return np.array(self.velocity_gradient, dtype=np.float64)
        g = np.zeros((3, 3))
        g[0, 1] = self.shear_rate
        return g

    @property
    def is_shear(self) -> bool:
        """Simple shear (or no flow): the Lees–Edwards cell of ``shear_offset``."""
        g = self.gradient()
        g[0, 1] = 0.0
        return not np.any(g)

    def at_time(self, t: float) -> "Cell":
        """The same cell at time ``t``: the Lees–Edwards offset s = γ̇ t Ly (wrapped) in
        simple shear, the deformed lattice of time ``t`` otherwise."""
        if not self.is_shear:
            return Cell(self.lengths, self.walls, self.shear_rate, 0.0, self.velocity_gradient, float(t))
        if self.walls:
            return self
        lx, ly = self.lengths[0], self.lengths[1]
        s = (self.shear_rate * t * ly + 0.5 * lx) % lx - 0.5 * lx
        return Cell(self.lengths, self.walls, self.shear_rate, s, self.velocity_gradient, float(t))

    def lattice(self) -> "Lattice":
        """The current periodic lattice (``fold_cell``), see :class:`Lattice`."""
        basis, thick, origin, flow, period, stat, msg = _ext().fold_geo_cell_info(
            self.dim, self.lengths3(), int(self.walls), self.gradient(), float(self.time))
        checked(stat, msg)
        d = self.dim
        if self.is_shear:
            basis = basis.copy()
            basis[0, 1] = self.shear_offset  # the offset as given (at_time or explicit)
        return Lattice(np.ascontiguousarray(basis[:d, :d].T), thick[:d].copy(), origin[:d].copy(),
                       FLOWS[int(flow)], float(period))


FLOWS = {0: "shear", 1: "planar_kraynik_reinelt", 2: "general"}
"""Lattice kinds of ``fold_cell`` (``FOLD_FLOW_*``)."""


@dataclass(frozen=True)
class Lattice:
    """Periodic lattice of a :class:`Cell` at its time."""

    vectors: np.ndarray
    """(dim, dim): row k is lattice vector k (the reduced basis of a deforming cell) [m]."""
    thickness: np.ndarray
    """(dim,): distance between the primary cell's faces along each vector's dual; a
    range r has a unique periodic image within r while ``2 r < thickness.min()`` [m]."""
    origin: np.ndarray
    """(dim,): corner of the primary cell ``origin + vectors.T @ [0, 1)^dim``
    (deforming cells; 0 for the shear box ``[0, L)``) [m]."""
    flow: str
    """``"shear"``, ``"planar_kraynik_reinelt"`` or ``"general"``."""
    period: float
    """Kraynik–Reinelt time period ln((3 + √5)/2)/|ε| (0 otherwise) [s]."""


@dataclass(frozen=True)
class ContactStats:
    """What one collision pass did (``contact_stats_t``)."""

    n_corrections: int
    iterations: int
    min_gap: float
    min_gap_over_alpha: float
    pairs_left: int
    worst_gap: float
    capped: bool
    push: float
    """Margin beyond ``alpha`` each correction aims at, ``max(1e-3 alpha, 16 tol_gap)`` [m]."""
    list_builds: int
    """Candidate-pair (Verlet) lists built in the pass (1 unless corrections moved a
    particle by more than half the skin)."""
    list_pairs: int
    """Pairs in the last candidate list."""


def _vectors(name: str, a, dim: int | None = None, n: int | None = None) -> np.ndarray:
    """(N, dim) float array → Fortran-ordered (dim, N), with a named shape error."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or (dim is not None and arr.shape[1] != dim) \
            or (n is not None and arr.shape[0] != n):
        want = f"({n if n is not None else 'N'}, {dim if dim is not None else '2 or 3'})"
        raise InputError(f"{name}: expected shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: values must be finite")
    return np.asfortranarray(arr.T)


def _per_particle(name: str, a, n: int, dtype=np.float64) -> np.ndarray:
    arr = np.asarray(a, dtype=dtype)
    if arr.ndim == 0:
        arr = np.full(n, arr, dtype=dtype)
    if arr.shape != (n,):
        raise InputError(f"{name}: expected a scalar or shape ({n},), got {arr.shape}")
    return np.ascontiguousarray(arr)


def _omega(name: str, a, n: int) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.shape != (n, 3):
        raise InputError(f"{name}: expected shape ({n}, 3) (2-D: only the last column is used), got {arr.shape}")
    return np.asfortranarray(arr.T)


def _ext():
    return load("_fold_geometry")


def _cell_args(cell: Cell) -> tuple:
    return cell.lengths3(), int(cell.walls), float(cell.shear_offset), cell.gradient(), float(cell.time)


def min_image(dx, cell: Cell) -> np.ndarray:
    """Shortest image (N, dim) of displacements ``dx`` under the periodic (sheared or
    deformed) lattice."""
    d = _vectors("dx", dx, cell.dim)
    out, stat, msg = _ext().fold_geo_min_image(*_cell_args(cell), d)
    checked(stat, msg)
    return np.ascontiguousarray(out.T)


def wrap(x, v, cell: Cell) -> tuple[np.ndarray, np.ndarray]:
    """Positions wrapped into the primary cell (``[0, L)`` in shear) and velocities with
    the jump ``−G·(lattice shift)`` (Lees–Edwards: ∓γ̇Ly)."""
    xf = _vectors("x", x, cell.dim)
    vf = _vectors("v", v, cell.dim, xf.shape[1])
    xo, vo, stat, msg = _ext().fold_geo_wrap(*_cell_args(cell), xf, vf)
    checked(stat, msg)
    return np.ascontiguousarray(xo.T), np.ascontiguousarray(vo.T)


def capsule_contact(r, p1, h1, rad1, p2, h2, rad2) -> dict[str, np.ndarray]:
    """Closest points of capsule pairs (batched over N).

    Capsule k is the set of points within ``rad_k`` of the segment ``c_k + s p_k``,
    ``|s| ≤ h_k``; ``r = c1 − c2`` (already a minimum image). Returns ``dist`` (surface
    distance, negative on overlap; with zero radii the segment–segment distance),
    ``normal`` (N, dim) unit vector from 2 to 1, and the arms ``s``, ``t`` of the
    closest axis points (Ericson 2005, *Real-Time Collision Detection*, §5.1.9).
    """
    rf = _vectors("r", r)
    dim, n = rf.shape
    p1f = _vectors("p1", p1, dim, n)
    p2f = _vectors("p2", p2, dim, n)
    s, t, dist, normal = _ext().fold_geo_capsule_contact(
        rf, p1f, _per_particle("h1", h1, n), _per_particle("rad1", rad1, n), p2f,
        _per_particle("h2", h2, n), _per_particle("rad2", rad2, n))
    return {"dist": dist, "normal": np.ascontiguousarray(normal.T), "s": s, "t": t}


def neighbour_pairs(x, cell: Cell, rc: float, method: str = "cells") -> np.ndarray:
    """All pairs (M, 2), 0-based, ``i < j``, sorted, whose minimum-image centre distance is < ``rc``.

    ``method="cells"`` uses the O(N) cell list, ``"naive"`` the O(N²) double loop.
    Every periodic edge must exceed ``2 rc`` (else :class:`InputError`).
    """
    if method not in ("cells", "naive"):
        raise InputError(f"method: expected 'cells' or 'naive', got {method!r}")
    xf = _vectors("x", x, cell.dim)
    n = xf.shape[1]
    room = max(16, 8 * n)
    for _ in range(2):
        pairs, npairs, stat, msg = _ext().fold_geo_pairs(room, *_cell_args(cell), xf, float(rc),
                                                         int(method == "cells"))
        if npairs <= room:
            break
        room = npairs
    checked(stat, msg)
    return np.ascontiguousarray(pairs[:, :npairs].T) - 1


@dataclass(frozen=True)
class Placement:
    """Result of :func:`place_particles`."""

    x: np.ndarray
    p: np.ndarray
    n_rsa: int
    relax_sweeps: int


def place_particles(cell: Cell, shape, radius, length, *, alpha: float, seed: int,
                    orientation="isotropic", axis=None, max_attempts: int = 1000,
                    relax_sweeps: int = 5000) -> Placement:
    """Seeded random non-overlapping placement (``fold_placement``).

    Random sequential addition (largest particles first, gap ≥ ``alpha`` between
    particles and ≥ ``alpha/2`` to walls, ``max_attempts`` tries each); what RSA cannot
    place is then pushed apart by translation-only relaxation sweeps (at most
    ``relax_sweeps``; 0 = pure RSA), which keeps the drawn orientations exactly.

    Parameters
    ----------
    shape, radius, length
        Per particle (N,): shape code (:data:`FIBRE`, :data:`SPHERE`, :data:`SPHEROID`),
        radius [m], length [m] (fibre length, spheroid major axis, 2R for spheres).
    orientation
        ``"isotropic"``, ``"planar"`` (uniform in the plane normal to ``axis``; 2-D:
        isotropic), ``"aligned"`` / ``"given"`` (along ``axis``), or an (N,) array of
        :data:`ORIENT_GIVEN` / :data:`ORIENT_ISOTROPIC` / :data:`ORIENT_PLANAR` codes.
    axis
        (dim,) or (N, dim): the axis (aligned/given) or plane normal (planar).

    Raises
    ------
    InputError
        Invalid arguments, or the target volume fraction was not reached (the
        message gives the fraction random sequential addition reached).
    """
    dim = cell.dim
    shape_a = np.asarray(shape)
    if shape_a.ndim != 1:
        raise InputError(f"shape: expected shape (N,), got {shape_a.shape}")
    n = shape_a.shape[0]
    shape_a = _per_particle("shape", shape_a, n, np.int32)
    if np.any((shape_a < FIBRE) | (shape_a > SPHEROID)):
        raise InputError("shape: codes must be 1 (fibre), 2 (sphere) or 3 (spheroid)")
    codes = {"given": ORIENT_GIVEN, "aligned": ORIENT_GIVEN, "isotropic": ORIENT_ISOTROPIC,
             "planar": ORIENT_PLANAR}
    if isinstance(orientation, str):
        if orientation not in codes:
            raise InputError(f"orientation: expected one of {sorted(codes)}, got {orientation!r}")
        modes = np.full(n, codes[orientation], dtype=np.int32)
    else:
        modes = _per_particle("orientation", orientation, n, np.int32)
    if axis is None:
        if np.any(modes != ORIENT_ISOTROPIC):
            if dim == 3 and np.all(modes != ORIENT_GIVEN):
                axis = np.array([0.0, 0.0, 1.0])  # planar: the flow-gradient plane x-y
            else:
                raise InputError("axis: required for 'aligned'/'given' orientations")
        else:
            axis = np.eye(dim)[0]
    axis_a = np.asarray(axis, dtype=np.float64)
    if axis_a.shape == (dim,):
        axis_a = np.tile(axis_a, (n, 1))
    if max_attempts < 1 or relax_sweeps < 0:
        raise InputError("max_attempts must be >= 1 and relax_sweeps >= 0")
    x, p, n_rsa, sweeps, stat, msg = _ext().fold_geo_place(
        *_cell_args(cell), shape_a,
        _per_particle("radius", radius, n), _per_particle("length", length, n), modes,
        _vectors("axis", axis_a, dim, n), float(alpha), int(seed), int(max_attempts), int(relax_sweeps))
    checked(stat, msg)
    return Placement(np.ascontiguousarray(x.T), np.ascontiguousarray(p.T), int(n_rsa), int(sweeps))


def jeffery_velocities(cell: Cell, x, p, xi) -> tuple[np.ndarray, np.ndarray]:
    """Dilute rigid velocities: ``v = G·(x − L/2)`` (N, dim) and the Jeffery angular
    velocity ``ω`` (N, 3) whose rotation gives ``dp/dt = W·p + ξ(D·p − (p·D·p)p)``
    (Jeffery 1922, Proc. R. Soc. A 102:161), plus the axial spin ω_f·p (3-D)."""
    xf = _vectors("x", x, cell.dim)
    n = xf.shape[1]
    pf = _vectors("p", p, cell.dim, n)
    v, omega, stat, msg = _ext().fold_geo_jeffery(cell.lengths3(), int(cell.walls), cell.gradient(), xf, pf,
                                                  _per_particle("xi", xi, n))
    checked(stat, msg)
    return np.ascontiguousarray(v.T), np.ascontiguousarray(omega.T)


def rigid_update(x, p, v, omega, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``x + v dt`` and ``p`` turned exactly by ``ω dt`` (Rodrigues; an angle in 2-D)."""
    xf = _vectors("x", x)
    dim, n = xf.shape
    xo, po = _ext().fold_geo_rigid_update(xf, _vectors("p", p, dim, n), _vectors("v", v, dim, n),
                                          _omega("omega", omega, n), float(dt))
    return np.ascontiguousarray(xo.T), np.ascontiguousarray(po.T)


def jeffery_advance(cell: Cell, x, p, xi, dt: float, nsteps: int, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Integrate dilute Jeffery kinematics (velocities frozen over each step, exact rotation,
    Lees–Edwards wrapping). Returns ``x`` and ``p`` histories of shape
    ``(nsteps // every + 1, N, dim)``, every ``every`` steps from the initial state."""
    if nsteps < 0 or every < 1 or not dt > 0:
        raise InputError(f"need nsteps >= 0, every >= 1 and dt > 0, got {nsteps}, {every}, {dt}")
    xf = _vectors("x", x, cell.dim)
    n = xf.shape[1]
    nout = nsteps // every + 1
    xh, ph, stat, msg = _ext().fold_geo_jeffery_advance(nout, cell.lengths3(), int(cell.walls), cell.gradient(),
                                                        xf, _vectors("p", p, cell.dim, n),
                                                        _per_particle("xi", xi, n), float(dt), int(every))
    checked(stat, msg)
    return np.transpose(xh, (2, 1, 0)).copy(), np.transpose(ph, (2, 1, 0)).copy()


def resolve_contacts(cell: Cell, shape, radius, length, x, p, v, omega, dt: float, *, alpha: float,
                     mode: str = "strategy", max_iter: int = 100, on_cap: str = "stop",
                     owned: Sequence[int] | None = None, skin: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, ContactStats]:
    """The seed's collision strategy on rigid velocities (``fold_contacts.resolve_contacts``).

    Gaps are taken at the predicted positions at ``t + dt`` (cell offset advanced by
    ``dt``); while a particle's worst gap is below ``alpha``, equal and opposite
    impulses at the contact point aim, to first order, at the gap ``alpha + push``
    (two spheres: ``δ = (|D| + push)/(2Δt)``, the seed's ``|D|/(2Δt)`` plus the small
    documented push ``max(1e-3 alpha, 16 tol_gap)`` that makes the loop terminate).
    ``mode`` is ``"none"`` (statistics only), ``"naive"`` (O(N²) candidate search) or
    ``"strategy"`` (cell lists); both sweep one Verlet list of candidate pairs per step.
    ``owned = (first, last)`` (0-based, inclusive) restricts the particles whose
    corrections are computed (MPI split); by default all. ``skin`` is the Verlet skin
    [m] (default ``alpha + max(radius)``; any value gives the same corrections).
    Returns the corrected ``v`` (N, dim), ``omega`` (N, 3) and :class:`ContactStats`.

    Raises
    ------
    OverlapError
        The iteration cap was reached and ``on_cap="stop"``.
    """
    if mode not in CONTACT_MODES:
        raise InputError(f"mode: expected one of {sorted(CONTACT_MODES)}, got {mode!r}")
    if on_cap not in ON_CAP:
        raise InputError(f"on_cap: expected one of {sorted(ON_CAP)}, got {on_cap!r}")
    xf = _vectors("x", x, cell.dim)
    n = xf.shape[1]
    first, last = (0, n - 1) if owned is None else (int(owned[0]), int(owned[1]))
    out = _ext().fold_geo_resolve_contacts(
        *_cell_args(cell),
        _per_particle("shape", shape, n, np.int32), _per_particle("radius", radius, n),
        _per_particle("length", length, n), xf, _vectors("p", p, cell.dim, n), _vectors("v", v, cell.dim, n),
        _omega("omega", omega, n), float(dt), CONTACT_MODES[mode], float(alpha), int(max_iter), ON_CAP[on_cap],
        -1.0 if skin is None else float(skin), first + 1, last + 1)
    vo, oo, ncorr, iters, min_gap, mgoa, left, worst, capped, push, builds, npairs, stat, msg = out
    checked(stat, msg)
    stats = ContactStats(int(ncorr), int(iters), float(min_gap), float(mgoa), int(left), float(worst), bool(capped),
                         float(push), int(builds), int(npairs))
    return np.ascontiguousarray(vo.T), np.ascontiguousarray(oo.T), stats


def contact_search_range(shape, radius, length, *, alpha: float, skin: float | None = None) -> float:
    """Centre-distance range of the contact search (``fold_contacts.contact_search_range``):
    ``2 max(h + R) + alpha + skin`` (h the half segment, default skin ``alpha + max R``).
    The periodic cell must stay thicker than twice this [m]."""
    shape_a = np.asarray(shape, dtype=np.int32)
    n = shape_a.shape[0]
    return float(_ext().fold_geo_contact_range(shape_a, _per_particle("radius", radius, n),
                                               _per_particle("length", length, n), float(alpha),
                                               -1.0 if skin is None else float(skin)))


def admissible_t_end(cell: Cell, rc: float, dt: float, t_end: float) -> float:
    """Largest multiple of ``dt`` up to ``t_end`` for which the lattice of ``cell``
    (taken at t = 0) stays thicker than ``2 rc`` at every step, so a search of range
    ``rc`` has a unique minimum image (``fold_cell.cell_admissible_time``). Returns
    ``t_end`` for simple shear and Kraynik–Reinelt planar elongation (when the cell is
    thick enough at t = 0), ``-1`` when even t = 0 fails."""
    if not (dt > 0 and t_end >= 0 and rc > 0):
        raise InputError(f"need dt > 0, t_end >= 0 and rc > 0, got {dt}, {t_end}, {rc}")
    t_ok, stat, msg = _ext().fold_geo_admissible_time(cell.dim, cell.lengths3(), int(cell.walls), cell.gradient(),
                                                      float(rc), float(dt), float(t_end))
    checked(stat, msg)
    return float(t_ok)
