"""fold_run's trust in a Stokes solve (fortran/stokes/fold_stokes_trust.f90): the kappa
range it refuses beyond, and the run-time check that ends a run whose effective
viscosity falls below the fluid's, impossible for particles at least as viscous as the
fluid (minimum dissipation). The range and the check are the same Fortran that
`pyfold validate` calls (pyfold.native.stokes.kappa_range)."""
from __future__ import annotations

import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from pyfold.errors import NumericalError
from pyfold.native.stokes import kappa_range, stress_check
from test_run_common import run_fold, write_run_file

ROOT = Path(__file__).resolve().parents[2]
DOUBLE_ROUNDOFF = 2.0**-53


def test_stress_check_refuses_an_effective_viscosity_below_the_fluids():
    with pytest.raises(NumericalError, match=r"untrustworthy stress: effective viscosity -7\.6300E\+02.*kappa"):
        stress_check(-763.0, 1.0, 4096, 1e12, 1e-6)
    with pytest.raises(NumericalError, match="below the fluid's"):
        stress_check(float("nan"), 1.0, 4096, 1e3, 1e-6)
    # the round-off allowance is that of the N-term sums, N u: half of it passes, twice fails
    n = 4096
    stress_check(2.0 * (1.0 - 0.5 * n * DOUBLE_ROUNDOFF), 2.0, n, 1.0, 1e-6)
    with pytest.raises(NumericalError):
        stress_check(2.0 * (1.0 - 2.0 * n * DOUBLE_ROUNDOFF), 2.0, n, 1.0, 1e-6)
    stress_check(1.0357, 1.0, n, 1e3, 1e-6)


def _two_spheres(path, kappa: float, tol: float, t_end: float) -> np.ndarray:
    """Two spheres (R = 1/8) in a unit cell, 16^3 grid, a record, snapshot and checkpoint
    every step; returns the initial positions."""
    x = np.array([[0.3, 0.35, 0.4], [0.7, 0.6, 0.65]])
    write_run_file(path, x=x, p=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], radius=0.125, length=0.25, xi=0.0, shape=[2, 2],
                   dt=0.01, t_end=t_end, collisions=2, alpha=0.0125, snapshot_every=1, checkpoint_every=1,
                   stokes={"stokes_grid": (16, 16, 16), "stokes_kappa": kappa, "stokes_tolerance": tol})
    return x


def test_fold_run_refuses_kappa_beyond_the_range_with_exit_2(tmp_path):
    path = tmp_path / "k.h5"
    _two_spheres(path, 1e12, 1e-6, 0.05)
    proc = run_fold(path)
    assert proc.returncode == 2, proc.stderr
    kmax = kappa_range(16**3, 1e-6).kappa_max
    assert "/setup/resolved/stokes_kappa" in proc.stderr and f"allowed: kappa in [1, {kmax:10.3E}]" in proc.stderr
    with h5py.File(path) as f:
        assert "effective_viscosity" not in f


def test_untrustworthy_stress_ends_the_run_failed_keeping_the_last_good_records(tmp_path, monkeypatch):
    """kappa = 1e12 at tol 1e-6 on 16^3 (kappa tol = 1e6 times the allowed product), let
    through by the test-only FOLD_RUN_UNCHECKED_KAPPA: the warm-started solves give an
    effective viscosity of either sign (the error bound is 1e6 times the particles'
    contribution), and the first one below eta_f fails its step N with the cause; the
    records, snapshots and checkpoint end at step N - 1, and every kept record is >= eta_f."""
    path = tmp_path / "forced.h5"
    dt, t_end = 0.01, 0.2
    _two_spheres(path, 1e12, 1e-6, t_end)
    monkeypatch.setenv("FOLD_RUN_UNCHECKED_KAPPA", "1")
    proc = run_fold(path)
    assert proc.returncode == 1, (proc.returncode, proc.stdout[-500:], proc.stderr)
    assert "untrustworthy stress: effective viscosity" in proc.stderr and "Traceback" not in proc.stderr
    with h5py.File(path) as f:
        status = f.attrs["status"]
        status = status.decode() if isinstance(status, bytes) else str(status)
        m = re.match(r"failed: step (\d+), t = +([0-9.E+-]+): Stokes solve: untrustworthy stress: effective "
                     r"viscosity +(-?[0-9.E+-]+) Pa s below the fluid's", status)
        assert m, status
        step, eta_bad = int(m.group(1)), float(m.group(3))
        assert 1 <= step <= round(t_end / dt) and eta_bad < 1.0
        assert float(m.group(2)) == pytest.approx(step * dt, rel=1e-12)
        assert int(f.attrs["steps_done"]) == step - 1
        np.testing.assert_allclose(f["time"][()], dt * np.arange(step), rtol=0, atol=1e-12)
        eta = f["effective_viscosity"][()]
        assert np.all(eta >= 1.0), eta  # the failing solve's value is in no record
        np.testing.assert_array_equal(f["/checkpoint/x"][()], f["x"][-1])
        assert f["x"].shape[0] == step  # snapshots of steps 0 .. N - 1


@pytest.mark.parametrize("side", [-1, +1])
def test_kappa_bound_is_the_same_in_validate_and_fold_run(side, tmp_path):
    """Just above kappa_max both pyfold validate and fold_run refuse (exit 2), just below
    both accept: one Fortran function decides for both. 1e-9 relative is far outside the
    round-off of evaluating the bound and far inside its change with the tolerance."""
    from pyfold.scene import parse_scene

    base = (ROOT / "data/scenes/stokes_small.toml").read_text()
    grid = parse_scene(base).resolved_datasets()["stokes_grid"][0]
    kappa = kappa_range(int(np.prod([int(v) for v in grid])), 1e-6).kappa_max * (1.0 - side * 1e-9)
    scene = base.replace("kappa = 1e3 ", f"kappa = {kappa!r} ")
    if side > 0:
        parse_scene(scene)
    else:
        with pytest.raises(ValueError, match=r"numerics.stokes.kappa.*allowed: kappa in \[1, "):
            parse_scene(scene)
    path = tmp_path / "edge.h5"
    kappa = kappa_range(16**3, 1e-6).kappa_max * (1.0 - side * 1e-9)
    _two_spheres(path, kappa, 1e-6, 0.01)
    proc = run_fold(path)
    assert proc.returncode == (2 if side < 0 else 0), (proc.returncode, proc.stderr)
    if side < 0:
        assert "/setup/resolved/stokes_kappa" in proc.stderr, proc.stderr
