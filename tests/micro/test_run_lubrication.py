"""fold_run with sphere lubrication (lubrication = 1, Stokes path): the correction of
fortran/contact/fold_lubrication.f90 reaches the run, and only where the rule says.

Two spheres (R = 0.1) in a unit cell in simple shear, 24^3 grid (voxel h = 1/24, so the
threshold h_c = 2 h = 1/12 and the floor max(alpha, 1e-3 h_c) = alpha = 0.01), along the
compressional axis (1, -1, 0)/sqrt 2 of the shear, where the flow pushes them together.
One Euler step; /checkpoint/v holds the velocities of that step. The flow solve of the
starting configuration is the same with and without lubrication, so:

* gap 0.03 < h_c: the relative normal velocity with lubrication is the flow's times
  M/(M + 2c) (equal spheres, isolated-sphere mobility M = 6 pi eta R, the closed form of
  the module header) with c = (3/2) pi eta R^2 (1/gap - 1/h_c) written out here; the sum
  of the two velocities (the pair's momentum) is unchanged;
* gap 0.12 > h_c: no pair, the run is bitwise the run without lubrication.

Cost: four 24^3 runs of one step, a few seconds.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from test_run_common import run_fold, write_run_file

R = 0.1
N = 24
ETA = 1.0  # the viscosity write_run_file writes
ALPHA = 0.01
EPS = np.finfo(float).eps


def _write(path, gap: float, lubrication: int, steps: int = 1) -> None:
    n = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    half = 0.5 * (2.0 * R + gap)
    x = np.array([[0.5, 0.5, 0.5]]) + np.array([[-1.0], [1.0]]) * half * n
    write_run_file(path, x=x, p=[[1.0, 0.0, 0.0]] * 2, radius=R, length=2.0 * R, xi=0.0, shape=[2, 2],
                   dt=0.01, t_end=0.01 * steps, collisions=2, alpha=ALPHA, lubrication=lubrication,
                   checkpoint_every=1,
                   # FFTW_ESTIMATE plans: the runs with and without lubrication must share the
                   # flow solve bit for bit; measured plans may pick other algorithms in each
                   # process and differ at the CG tolerance
                   stokes={"stokes_grid": (N, N, N), "time_scheme": np.int64(1), "stokes_fft_plan": np.int64(0)})


def _run(tmp_path, name: str, gap: float, lubrication: int) -> h5py.File:
    path = tmp_path / f"{name}.h5"
    _write(path, gap, lubrication)
    proc = run_fold(path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return h5py.File(path)


def _velocities(f: h5py.File) -> np.ndarray:
    return f["/checkpoint/v"][()]


def test_lubrication_slows_the_approach_by_the_closed_form_factor(tmp_path):
    gap = 0.03
    with _run(tmp_path, "off", gap, 0) as off, _run(tmp_path, "on", gap, 1) as on:
        v_off, v_on = _velocities(off), _velocities(on)
        x0 = off["/initial/x"][()]
        # the records of the lubrication (only in the run that has it): record 0 holds the
        # solve of the starting configuration, whose correction the step used
        assert "lubricated_pairs" not in off and "lubrication_correction" not in off
        pairs, corr = on["lubricated_pairs"][()], on["lubrication_correction"][()]
        assert on["lubrication_correction"].attrs["units"] in (b"m/s", "m/s")
    assert pairs[0] == 1
    assert corr[0] == pytest.approx(np.linalg.norm(v_on[0] - v_off[0]), rel=1e-12)
    n = (x0[0] - x0[1]) / np.linalg.norm(x0[0] - x0[1])  # from sphere 2 to sphere 1
    w_off = np.dot(v_off[0] - v_off[1], n)
    w_on = np.dot(v_on[0] - v_on[1], n)
    assert w_off < 0.0  # the flow pushes the pair together (compressional axis)
    h_c = 2.0 / N
    m = 6.0 * np.pi * ETA * R
    c = 1.5 * np.pi * ETA * R**2 * (1.0 / gap - 1.0 / h_c)
    factor = m / (m + 2.0 * c)
    # The solver's residual bound 64 eps (a |dv| + |b|) over M gives a relative error of
    # 64 eps (a/M + 2c/M) ~ 64 eps * 8 here (a/M <= 1 + 2 sqrt 3 c/M, c/M = 0.6); the
    # velocity differences add a few eps |v|/|w|. 1e-12 is ten times the sum.
    assert w_on / w_off == pytest.approx(factor, rel=1e-12)
    assert 0.0 < factor < 1.0
    # equal and opposite corrections: the pair's momentum is the flow's
    np.testing.assert_allclose(v_on.sum(axis=0), v_off.sum(axis=0), rtol=0, atol=16 * EPS * np.abs(v_off).max())
    # only the normal component changes
    t_off = (v_off[0] - v_off[1]) - w_off * n
    t_on = (v_on[0] - v_on[1]) - w_on * n
    np.testing.assert_allclose(t_on, t_off, rtol=0, atol=16 * EPS * np.abs(v_off).max())


def test_lubrication_beyond_the_threshold_leaves_the_run_bitwise_unchanged(tmp_path):
    gap = 0.12  # > h_c = 1/12
    with _run(tmp_path, "off", gap, 0) as off, _run(tmp_path, "on", gap, 1) as on:
        assert np.array_equal(_velocities(on), _velocities(off))
        assert np.array_equal(on["/checkpoint/x"][()], off["/checkpoint/x"][()])
        assert np.array_equal(on["stress"][()], off["stress"][()])
        assert np.all(on["lubricated_pairs"][()] == 0) and np.all(on["lubrication_correction"][()] == 0.0)


def _scene(dim=3, cell=1.0, hydrodynamics="stokes", cells_per_diameter=4, shape="sphere"):
    import tomli_w

    from pyfold.scene import parse_scene

    part = {"name": "balls", "shape": shape, "radius": 0.1, "count": 4}
    if shape == "fibre":
        part["length"] = 0.3
    data = {
        "cell": {"dim": dim, "size": [cell] * dim},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [part],
        "model": {"hydrodynamics": hydrodynamics, "lubrication": True},
        "numerics": {"dt": 0.01, "t_end": 0.1, "stokes": {"cells_per_diameter": cells_per_diameter}},
    }
    return parse_scene(tomli_w.dumps(data))


def test_lubrication_threshold_rule_is_the_fortran_one():
    """The scene layer's copy of h_c / voxel (for its cell-size check) equals the Fortran parameter."""
    import re
    from pathlib import Path

    from pyfold.scene.normalise import LUBRICATION_THRESHOLD_VOXELS

    src = (Path(__file__).resolve().parents[2] / "fortran/contact/fold_lubrication.f90").read_text()
    found = re.search(r"LUB_THRESHOLD_VOXELS\s*=\s*([0-9.]+)_dp", src)
    assert found and float(found.group(1)) == LUBRICATION_THRESHOLD_VOXELS


def test_lubrication_is_refused_without_spheres_in_3d_and_warned_without_stokes():
    from pyfold.errors import InputError

    with pytest.raises(InputError, match=r"model\.lubrication.*dim = 2"):
        _scene(dim=2, hydrodynamics="jeffery")
    with pytest.raises(InputError, match=r"model\.lubrication.*no sphere family"):
        _scene(shape="fibre", hydrodynamics="jeffery")
    jeffery = _scene(hydrodynamics="jeffery")
    assert any(w.startswith("model.lubrication: has no effect") for w in jeffery.warnings)
    stokes = _scene()
    assert stokes.lubrication and not any(w.startswith("model.lubrication: has no effect") for w in stokes.warnings)
    # the measured over-correction (docs/physics.md#lubrication-between-spheres) is said
    assert any(w.startswith("model.lubrication: qualitative only") for w in stokes.warnings)


def test_lubrication_pair_range_must_fit_the_cell():
    """1 voxel per diameter: h = 0.2, h_c = 0.4, range 2R + h_c = 0.6 > half the unit cell."""
    from pyfold.errors import InputError

    with pytest.raises(InputError, match=r"model\.lubrication: the lubrication pair search range 2 R \+ h_c = 0\.6"):
        _scene(cells_per_diameter=1)


def test_lubrication_records_survive_a_resume(tmp_path):
    """0 -> 4 steps in one go and 0 -> 2 then --resume to 4: the lubrication records are
    truncated and continued like the others (5 records), and agree with the uninterrupted
    run to the Stokes tolerance (the resumed CG starts from zero: not bitwise)."""
    full, part = tmp_path / "full.h5", tmp_path / "part.h5"
    _write(full, 0.03, 1, steps=4)
    _write(part, 0.03, 1, steps=2)
    for path in (full, part):
        proc = run_fold(path)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    with h5py.File(part, "a") as f:
        f["/setup/resolved/t_end"][()] = 0.04
    proc = run_fold(part, resume=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    with h5py.File(full) as a, h5py.File(part) as b:
        assert a["lubricated_pairs"].shape == b["lubricated_pairs"].shape == (5,)
        assert np.all(b["lubricated_pairs"][()] == 1)
        # Stokes tolerance 1e-6 on velocities of order 0.1 m/s
        np.testing.assert_allclose(b["lubrication_correction"][()], a["lubrication_correction"][()], rtol=0,
                                   atol=1e-6)


def test_lubrication_is_off_by_default():
    """A scene that does not ask for lubrication gets none: the resolved run file says 0,
    so fold_run takes the flow's velocities unchanged (the run with lubrication = 0 above
    is the one the closed-form factor is measured against)."""
    import tomli_w

    from pyfold.scene import parse_scene

    data = {
        "cell": {"dim": 3, "size": [1.0] * 3},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [{"name": "balls", "shape": "sphere", "radius": 0.1, "count": 4}],
        "model": {"hydrodynamics": "stokes"},
        "numerics": {"dt": 0.01, "t_end": 0.1},
    }
    res = parse_scene(tomli_w.dumps(data))
    assert res.scene.model.lubrication is False
    assert int(res.resolved_datasets()["lubrication"][0]) == 0
