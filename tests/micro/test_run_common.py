"""Shared helpers of the fold_run tests: write run files with h5py, run fold_run.

The run files follow the layout of pyfold/run_input.py (/setup/resolved + /initial, root
attributes); they are written directly here so that the executable can be tested
independently of the scene layer. The executable is found exactly as ``pyfold run``
finds it (:func:`pyfold.commands.run.find_fold_run`).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest


def require_fold_run() -> Path:
    """The fold_run executable, found as ``pyfold run`` finds it (one rule in one place);
    a missing executable is a failure, never a silent skip."""
    from pyfold.commands.run import find_fold_run
    from pyfold.errors import PyfoldError

    try:
        return find_fold_run()
    except PyfoldError as exc:
        pytest.fail(f"fold_run executable not built (see fortran/app/README.md): {exc}")


def run_fold(path, np_ranks: int = 1, resume: bool = False, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """Run fold_run on ``path`` (through mpiexec when np_ranks > 1)."""
    exe = require_fold_run()
    cmd = [str(exe), str(path)] + (["--resume"] if resume else [])
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    if np_ranks > 1:
        mpiexec = shutil.which("mpiexec") or shutil.which("mpirun")
        if mpiexec is None:
            pytest.fail("mpiexec not found (Open MPI is installed by scripts/bootstrap)")
        cmd = [mpiexec, "-np", str(np_ranks), "--oversubscribe"] + cmd
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)


def shear(rate: float) -> np.ndarray:
    g = np.zeros((3, 3))
    g[0, 1] = rate
    return g


#: FFTW planning of every Stokes solve in the tests: "estimate" (default: the same plan
#: every time) or "measure" (timed at start-up, so the transform algorithm, and with it
#: the round-off, may change from one run to the next). ``PYFOLD_TEST_FFT_PLAN=measure``
#: runs the suite with timed plans: no outcome may depend on the choice.
FFT_PLAN = os.environ.get("PYFOLD_TEST_FFT_PLAN", "estimate")
if FFT_PLAN not in ("estimate", "measure"):
    raise ValueError(f"PYFOLD_TEST_FFT_PLAN: 'estimate' or 'measure', got {FFT_PLAN!r}")


def one_sphere_scene(path: Path, **over) -> Path:
    """Write a one-sphere scene (radius 1/8 of a unit cell) with Stokes hydrodynamics to ``path``.
    ``over``: ``{"table.key": value}`` replacements (``"cell.boundary": "couette"``); ``None`` removes the key."""
    import tomli_w

    scene: dict = {
        "cell": {"dim": 3, "size": [1.0, 1.0, 1.0]},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [{"name": "ball", "shape": "sphere", "radius": 0.125, "count": 1,
                       "orientation": "aligned", "direction": [1.0, 0.0, 0.0]}],
        "model": {"hydrodynamics": "stokes", "collisions": "none"},
        "numerics": {"dt": 0.05, "t_end": 0.2, "seed": 5, "time_scheme": "ab2",
                     "stokes": {"cells_per_diameter": 8, "fft_plan": FFT_PLAN}},
        "output": {"interval": 0.05, "snapshot_interval": 0.2, "checkpoint_interval": 0.2},
    }
    for key, value in over.items():
        table, _, leaf = key.rpartition(".")
        node = scene
        for part in table.split(".") if table else []:
            node = node.setdefault(part, {})
        if value is None:
            node.pop(leaf, None)
        else:
            node[leaf] = value
    path.write_text(tomli_w.dumps(scene), encoding="utf-8")
    return path


def jeffery_scene(particles: list[dict], size, *, t_end: float, seed: int, **model) -> dict:
    """A scene (as a dict) of ``particles`` in a periodic cell of edges ``size``: simple
    shear at rate 1, Jeffery hydrodynamics plus the ``model`` keys, ``dt = 0.01``."""
    return {
        "cell": {"size": list(size)},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": particles,
        "model": {"hydrodynamics": "jeffery", **model},
        "numerics": {"dt": 0.01, "t_end": t_end, "seed": seed},
    }


def stokes_settings(**kw):
    """``pyfold.native.stokes.StokesSettings`` with the suite's FFTW planning."""
    from pyfold.native.stokes import StokesSettings

    return StokesSettings(measure_plans=FFT_PLAN == "measure", **kw)


#: Stokes settings of /setup/resolved (what the scene layer writes for hydrodynamics = stokes)
STOKES_DEFAULTS = {
    "stokes_grid": (32, 32, 32),
    "stokes_backend": np.int64(1),
    "stokes_tolerance": 1e-6,
    "stokes_max_iterations": np.int64(1000),
    "stokes_kappa": 1e3,
    "stokes_derivative": np.int64(1),
    "stokes_fft_plan": np.int64(FFT_PLAN == "measure"),
    "stokes_mixing": np.int64(1),
    "stokes_subsamples": np.int64(3),
    "stokes_fibre_ends": np.int64(0),
    "stokes_warm_start": np.int64(1),
    "time_scheme": np.int64(2),
}


#: /setup/resolved integers that write_run_file takes as keywords, with their defaults
INTEGER_SETTINGS = {
    "walls": 0, "seed": 1, "collisions": 0, "contact_max_iter": 50, "on_contact_cap": 0, "lubrication": 0,
    "output_every": 1, "snapshot_every": 0, "checkpoint_every": 0,
}


def write_run_file(path, *, x, p, radius, length, xi, shape=None, family=None, family_names=("fibres",), dim=3,
                   cell_lengths=(1.0, 1.0, 1.0), shear_rate=1.0, dt=0.01, t_end=0.1, alpha=0.0, drop=(),
                   override=None, stokes=None, **integers):
    """Write a run file. ``integers`` sets keys of INTEGER_SETTINGS (the others keep
    their defaults). ``drop`` lists /setup/resolved or /initial datasets to leave
    out, ``override`` maps dataset paths to replacement values (to make bad files).
    ``stokes``: a dict of Stokes settings (keys of STOKES_DEFAULTS) switches
    hydrodynamics to 1 (stokes) and writes them."""
    unknown = sorted(set(integers) - set(INTEGER_SETTINGS))
    if unknown:
        raise TypeError(f"write_run_file: unknown settings {unknown}; allowed: {sorted(INTEGER_SETTINGS)}")
    ints = {key: np.int64(value) for key, value in {**INTEGER_SETTINGS, **integers}.items()}
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    shape = np.full(n, 1) if shape is None else np.asarray(shape)
    family = np.zeros(n, dtype=np.int64) if family is None else np.asarray(family)
    cell = np.asarray(cell_lengths, dtype=float)
    resolved = {
        "dim": np.int64(dim),
        "cell_lengths": cell,
        "wall_speed": 0.5 * shear_rate * cell[1],
        "velocity_gradient": shear(shear_rate),
        "shear_rate": float(shear_rate),
        "viscosity": 1.0,
        "dt": float(dt),
        "t_end": float(t_end),
        "hydrodynamics": np.int64(0),
        "hydrodynamics_reason": "test: jeffery requested",
        "alpha": float(alpha),
        **ints,
        "family_names": np.array(list(family_names), dtype=object),
    }
    if stokes is not None:
        resolved["hydrodynamics"] = np.int64(1)
        resolved["hydrodynamics_reason"] = "test: stokes requested"
        for key, val in {**STOKES_DEFAULTS, **stokes}.items():
            resolved[key] = np.asarray(val, dtype=np.int64) if key == "stokes_grid" else val
    initial = {
        "x": x,
        "p": np.asarray(p, dtype=float),
        "shape": shape.astype(np.int64),
        "family": family.astype(np.int64),
        "radius": np.broadcast_to(np.asarray(radius, dtype=float), (n,)).copy(),
        "length": np.broadcast_to(np.asarray(length, dtype=float), (n,)).copy(),
        "xi": np.broadcast_to(np.asarray(xi, dtype=float), (n,)).copy(),
    }
    override = override or {}
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "pyfold.run"
        f.attrs["format_version"] = "1.0"
        f.attrs["creator"] = "tests/micro/test_run_common.py"
        f.attrs["created"] = "1970-01-01T00:00:00Z"
        f.attrs["command"] = " ".join(sys.argv[:1])
        setup = f.create_group("setup")
        setup.attrs["scene_toml"] = "# written by the fold_run tests"
        res = setup.create_group("resolved")
        for key, val in resolved.items():
            full = f"/setup/resolved/{key}"
            if key in drop or full in drop:
                continue
            val = override.get(full, val)
            if isinstance(val, np.ndarray) and val.dtype == object:
                res.create_dataset(key, data=val, dtype=h5py.string_dtype())
            else:
                res.create_dataset(key, data=val)
        ini = f.create_group("initial")
        for key, val in initial.items():
            full = f"/initial/{key}"
            if key in drop or full in drop:
                continue
            ini.create_dataset(key, data=override.get(full, val))


def random_unit(rng, n: int, dim: int) -> np.ndarray:
    v = rng.normal(size=(n, dim))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def xi_of(beta: float) -> float:
    return (beta**2 - 1.0) / (beta**2 + 1.0)


def test_writer_produces_the_run_file_layout(tmp_path):
    """The helper itself writes the layout fold_run reads (guards the other tests)."""
    rng = np.random.default_rng(0)
    path = tmp_path / "r.h5"
    write_run_file(path, x=rng.uniform(size=(3, 3)), p=random_unit(rng, 3, 3), radius=0.01, length=0.1, xi=0.9)
    with h5py.File(path) as f:
        assert f["/setup/resolved/velocity_gradient"][0, 1] == 1.0
        assert f["/initial/x"].shape == (3, 3)
        assert f.attrs["format"] == "pyfold.run"
