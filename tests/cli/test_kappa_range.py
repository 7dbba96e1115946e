"""The penalty kappa a Stokes run accepts is bounded by what the solver resolves at its
grid, tolerance and precision (docs/physics.md, "How large a penalty the solver can
carry"): beyond kappa_max the bound on the solver's error of the particles' stress
exceeds that contribution. `pyfold validate` and `pyfold run` refuse such a kappa with
exit 2 naming numerics.stokes.kappa and the range; a kappa at the edge runs and gives
the effective viscosity of the kappa -> infinity trend within the derived bound.

The scene: two spheres (R = 1/8, 4 voxels per diameter: a 16^3 grid) in a unit cell
under simple shear, Stokes, 5 steps of 0.01.
"""
from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import write_scene
from pyfold.cli import main
from pyfold.native.stokes import kappa_range

RADIUS = 0.125
GRID_POINTS = 16**3  # cells_per_diameter 4 across 2 R = 1/4 of the unit cell
TOL = 1e-6  # the default CG tolerance
#: solid volume fraction of the two spheres
PHI = 2 * 4.0 / 3.0 * math.pi * RADIUS**3


def two_spheres(**stokes) -> dict:
    return {
        "title": "two spheres, Stokes, 5 steps",
        "cell": {"dim": 3, "size": [1.0, 1.0, 1.0]},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [{"name": "spheres", "shape": "sphere", "radius": RADIUS, "count": 2}],
        "model": {"hydrodynamics": "stokes", "collisions": "strategy", "alpha": 0.0125},
        "numerics": {"dt": 0.01, "t_end": 0.05, "seed": 3, "stokes": {"tolerance": TOL, **stokes}},
        "output": {"interval": 0.01, "snapshot_interval": 0.05},
    }


def _eps(precision: str) -> float:
    """(2 log2 N + 4) u for the 16^3 grid."""
    return (2 * math.log2(GRID_POINTS) + 4) * (2.0**-24 if precision == "single" else 2.0**-53)


def test_kappa_max_is_the_edge_of_the_derived_bound_and_falls_with_the_tolerance():
    """(kappa - 1)(tol + eps_op) + kappa eps_d = 1 at kappa_max, and at tolerance_max for
    a given kappa; eps_op = (2 log2 N + 4) u of the transforms, eps_d that of double."""
    for precision, tol in (("double", 1e-6), ("double", 1e-3), ("single", 1e-4)):
        r = kappa_range(GRID_POINTS, tol, 1e5, precision)
        eps_op, eps_d = _eps(precision), _eps("double")
        assert r.eps_op == pytest.approx(eps_op, rel=1e-14)
        assert (r.kappa_max - 1) * (tol + eps_op) + r.kappa_max * eps_d == pytest.approx(1.0, rel=1e-12)
        assert (1e5 - 1) * (r.tolerance_max + eps_op) + 1e5 * eps_d == pytest.approx(1.0, rel=1e-12)
    assert kappa_range(GRID_POINTS, 1e-4).kappa_max < kappa_range(GRID_POINTS, 1e-6).kappa_max
    # the default kappa = 1e3 stays allowed at the loosest double tolerance the docs measure
    assert kappa_range(72**3, 1e-3).kappa_max >= 1e3
    # no tolerance lifts kappa beyond the absolute cap
    assert kappa_range(GRID_POINTS, 1e-15).kappa_max == 1e12


@pytest.mark.parametrize("kappa", [1e12, 1e8])
def test_kappa_beyond_the_bound_is_refused_by_validate_and_run_naming_key_and_range(kappa, tmp_path, capsys):
    """The reviewer's kappa = 1e12 (effective viscosity of either sign, status ok) and 1e8
    (a larger rigidity error than 1e3) are beyond kappa_max = 1e6 at 16^3, tol 1e-6."""
    scene = write_scene(tmp_path / "two_spheres.toml", two_spheres(kappa=kappa))
    kmax = kappa_range(GRID_POINTS, TOL).kappa_max
    for command in (["validate", str(scene)], ["run", str(scene), "-o", str(tmp_path / "out.h5")]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "numerics.stokes.kappa" in err and f"allowed: kappa in [1, {kmax:.4g}]" in err, err
        assert "16 x 16 x 16 grid" in err and "tolerance <= " in err and "Traceback" not in err
    assert not (tmp_path / "out.h5").exists() and not (tmp_path / "out.h5.partial").exists()


def _eta_eff(path: Path) -> tuple[str, np.ndarray]:
    with h5py.File(path) as f:
        status = f.attrs["status"]
        return (status.decode() if isinstance(status, bytes) else str(status)), f["effective_viscosity"][()]


def _solver_error_bound(kappa: float, delta: float) -> float:
    """|error of eta_eff| <= eta_f ((kappa - 1)(tol + eps_op) sqrt(phi Delta) + kappa eps_d phi)
    (fortran/stokes/fold_stokes_trust.f90), eta_f = 1, double transforms: eps_op = eps_d."""
    eps = _eps("double")
    return (kappa - 1) * (TOL + eps) * math.sqrt(PHI * delta) + kappa * eps * PHI


def test_kappa_at_the_edge_runs_and_stays_on_the_large_kappa_trend(tmp_path, capsys):
    """At kappa_max the run is ok and its eta_eff differs from kappa = 1e3's by at most the
    two solver error bounds plus the penalty difference of a sphere between kappa = 1e3 and
    infinity, 3 phi / (2 (kappa + 1)) (Taylor 1932: intrinsic viscosity (5 kappa + 2) /
    (2 kappa + 2)); the exact eta_eff grows with kappa (minimum dissipation), so the
    difference is bounded on both sides. At kappa = 1e12 the same difference was 15-1500."""
    kmax = kappa_range(GRID_POINTS, TOL).kappa_max
    etas = {}
    for kappa in (1e3, kmax):
        scene = write_scene(tmp_path / f"k{kappa:.0e}.toml", two_spheres(kappa=kappa))
        out = tmp_path / f"k{kappa:.0e}.h5"
        assert main(["run", str(scene), "-o", str(out)]) == 0, capsys.readouterr().err
        status, etas[kappa] = _eta_eff(out)
        assert status == "ok"
        assert np.all(etas[kappa] >= 1.0)  # minimum dissipation: eta_eff >= eta_f
    delta = etas[1e3] - 1.0
    assert np.all(delta > 0)
    bound = (np.array([_solver_error_bound(kmax, d) + _solver_error_bound(1e3, d) for d in delta])
             + 3 * PHI / (2 * (1e3 + 1)))
    diff = etas[kmax] - etas[1e3]
    assert np.all(np.abs(diff) <= bound), (diff, bound)
