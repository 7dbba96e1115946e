"""The initial particle state of a resolved scene, from the Fortran placement kernel.

``fold_placement`` (``fortran/particles/fold_placement.f90``) draws the
axes (given, isotropic, or uniform in a plane) and places the centres by random
sequential addition, then, for dense targets, relaxation sweeps that push
overlapping pairs apart, so every surface gap is >= alpha (alpha/2 to walls). It
is seeded: the same scene gives the same initial state, so the run file holds
the full initial state and a run is reproducible from the scene's seed.
"""
from __future__ import annotations

import numpy as np

from pyfold.native.geometry import ORIENT_GIVEN, ORIENT_ISOTROPIC, ORIENT_PLANAR
from pyfold.run_file import InitialState
from pyfold.scene.normalise import ResolvedScene

#: Random positions tried per particle before it is left to the relaxation sweeps.
MAX_ATTEMPTS = 2000
#: Relaxation sweeps allowed to remove the overlaps RSA could not avoid.
RELAX_SWEEPS = 5000


def particle_arrays(resolved: ResolvedScene) -> dict[str, np.ndarray]:
    """Per-particle ``shape``, ``family``, ``radius``, ``length``, ``xi`` (in family order),
    and the placement kernel's ``orient_mode`` and ``axis`` ``(n, dim)``."""
    fams, dim = resolved.families, resolved.dim
    counts = [f.count for f in fams]
    modes, axes = [], []
    for f in fams:
        if f.orientation == "isotropic" or (f.orientation == "planar_random" and dim == 2):
            modes.append(np.full(f.count, ORIENT_ISOTROPIC))
            axes.append(np.zeros((f.count, dim)))
        elif f.orientation == "planar_random":  # uniform in the x-y plane: the plane normal to z
            modes.append(np.full(f.count, ORIENT_PLANAR))
            axes.append(np.tile([0.0, 0.0, 1.0], (f.count, 1)))
        else:  # aligned (one axis for all) or given (one each), already normalised
            modes.append(np.full(f.count, ORIENT_GIVEN))
            axes.append(np.broadcast_to(f.axes, (f.count, dim)))
    return {
        "shape": np.repeat([f.shape_code for f in fams], counts).astype(np.int32),
        "family": np.repeat([f.index for f in fams], counts).astype(np.int32),
        "radius": np.repeat([f.radius for f in fams], counts).astype(np.float64),
        "length": np.repeat([f.length for f in fams], counts).astype(np.float64),
        "xi": np.repeat([f.xi for f in fams], counts).astype(np.float64),
        "orient_mode": np.concatenate(modes).astype(np.int32),
        "axis": np.concatenate(axes).astype(np.float64),
    }


def initial_state(resolved: ResolvedScene) -> InitialState:
    """Draw the axes and place the centres without overlap (gaps >= alpha).

    Raises
    ------
    InputError
        The kernel could not reach the scene's volume fraction (its message gives
        the fraction random sequential addition reached).
    PyfoldError
        The native extension is not built.
    """
    from pyfold.native.geometry import Cell, place_particles

    a = particle_arrays(resolved)
    # the full gradient: a non-shear flow places in its deforming lattice at t = 0
    cell = Cell(tuple(resolved.cell_lengths[: resolved.dim]), walls=resolved.walls,
                velocity_gradient=resolved.velocity_gradient)
    placed = place_particles(cell, a["shape"], a["radius"], a["length"], alpha=resolved.alpha, seed=resolved.seed,
                             orientation=a["orient_mode"], axis=a["axis"], max_attempts=MAX_ATTEMPTS,
                             relax_sweeps=RELAX_SWEEPS)
    return InitialState(x=placed.x, p=placed.p, shape=a["shape"], family=a["family"], radius=a["radius"],
                        length=a["length"], xi=a["xi"])
