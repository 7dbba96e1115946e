"""The viscosity contrast a Stokes run can carry at its grid, tolerance and precision.

The bound itself is computed in one place, fortran/stokes/fold_stokes_trust.f90 (through
:func:`pyfold.native.stokes.kappa_range`), which fold_run applies to /setup/resolved as well;
its derivation: docs/physics.md#how-large-a-penalty-the-solver-can-carry.
"""
from __future__ import annotations

from collections.abc import Sequence

from pyfold.native import stokes as stokes_codes
from pyfold.scene._problems import Problems


def check_kappa(st, grid: Sequence[int], grid_points: int, problems: Problems) -> None:
    """Add a problem at ``numerics.stokes.kappa`` when ``st.kappa`` (``st``: the scene's
    ``numerics.stokes``) exceeds what the solver resolves on ``grid`` (``grid_points``
    voxels) at ``st.tolerance`` and ``st.fft_precision``: the message gives the allowed
    range there and the tolerance that would carry this kappa."""
    allowed = stokes_codes.kappa_range(grid_points, st.tolerance, st.kappa, st.fft_precision)
    if st.kappa <= allowed.kappa_max:
        return
    unit = "2^-24" if st.fft_precision == "single" else "2^-53"
    problems.add("numerics.stokes.kappa",
                 f"the solver cannot carry this penalty on the {' x '.join(map(str, grid))} grid at tolerance "
                 f"{st.tolerance:g} with fft_precision = {st.fft_precision!r}: the bound on its error of the "
                 f"particles' stress, (kappa - 1) (tolerance + eps_op) + kappa eps_d with eps_op = (2 log2 N + 4) "
                 f"{unit} = {allowed.eps_op:.3g}, exceeds the particles' contribution itself (docs/physics.md, \"How large "
                 f"a penalty the solver can carry\"); allowed: kappa in [{stokes_codes.KAPPA_MIN:g}, "
                 f"{allowed.kappa_max:.4g}] here, or tolerance <= {allowed.tolerance_max:.3g} for this kappa, got {st.kappa:g}")
