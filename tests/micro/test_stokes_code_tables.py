"""The integer codes of /setup/resolved and of the bindings are the same in Python and
Fortran, and both sides refuse the same Stokes settings.

Each enumeration is declared once, in the settings registry (pyfold/scene/registry.py),
whose views are pyfold.native.stokes, pyfold.scene.normalise and pyfold.scene.shapes; its
Fortran constants are generated into fortran/core/fold_settings.f90 or, for modules not
generated (fold_time_scheme, fold_fft_transport, fold_contacts, fold_particles), written by
hand. The tables are compared in both directions against the Fortran sources, so a
constant added on one side only (a new backend, a new mixing rule) fails here. The kappa
range is stated once (the registry's KAPPA_MIN, KAPPA_MAX); the scene schema must accept
exactly that range and fold_run must refuse a run file outside it with exit 2 naming the
dataset.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError
from test_run_common import STOKES_DEFAULTS, require_fold_run, run_fold, write_run_file, xi_of

from pyfold.native import stokes
from pyfold.scene import parse_scene, shapes
from pyfold.scene.normalise import COLLISION_CODES, HYDRODYNAMICS_CODES, ON_CAP_CODES
from pyfold.scene.schema import StokesSettings

REPO = Path(__file__).resolve().parents[2]
FORTRAN = REPO / "fortran"

#: (Python table, Fortran source, prefix of the Fortran constants, Python name -> suffix)
TABLES = {
    "backend": (stokes.BACKENDS, "core/fold_settings.f90", "FOLD_STOKES_", None),
    "derivative": (stokes.DERIVATIVES, "core/fold_settings.f90", "FOLD_DERIV_", {"fd": "FD"}),
    "mixing": (stokes.MIXINGS, "core/fold_settings.f90", "FOLD_MIX_", None),
    "fibre_ends": (stokes.FIBRE_ENDS, "core/fold_settings.f90", "FOLD_ENDS_", None),
    "initial_guess": (stokes.GUESSES, "core/fold_settings.f90", "FOLD_GUESS_", None),
    "time_scheme": (stokes.SCHEMES, "stokes/fold_time_scheme.f90", "FOLD_", {"euler": "EULER", "ab2": "AB2"}),
    "fft_plan": (stokes.FFT_PLANS, "stokes/fold_fft_transport.f90", "FOLD_PLAN_", None),
    "fft_precision": (stokes.FFT_PRECISIONS, "core/fold_settings.f90", "FOLD_FFT_", None),
    "rigidity": (stokes.RIGIDITIES, "core/fold_settings.f90", "FOLD_RIGIDITY_", None),
    "hydrodynamics": (HYDRODYNAMICS_CODES, "core/fold_settings.f90", "FOLD_HYDRO_", None),
    "collisions": (COLLISION_CODES, "contact/fold_contacts.f90", "FOLD_CONTACT_", None),
    "on_contact_cap": (ON_CAP_CODES, "contact/fold_contacts.f90", "FOLD_ON_CAP_", None),
    "shape": (shapes.SHAPE_CODES, "particles/fold_particles.f90", "FOLD_", None),
}

_CONST = re.compile(r"\b(FOLD_[A-Z0-9_]+)\s*=\s*([-+]?\d[0-9.eEdD+-]*)(?:_dp)?")


def fortran_constants(source: str) -> dict[str, float]:
    """Every ``FOLD_* = number`` of the ``parameter`` statements of a Fortran source."""
    out = {}
    for line in (FORTRAN / source).read_text().splitlines():
        code = line.split("!", 1)[0]
        if "parameter" not in code:
            continue
        for name, value in _CONST.findall(code):
            out[name] = float(value.replace("d", "e").replace("D", "e"))
    return out


@pytest.mark.parametrize("key", sorted(TABLES))
def test_stokes_and_run_file_code_tables_agree_with_fortran(key):
    table, source, prefix, rename = TABLES[key]
    consts = fortran_constants(source)
    expected = {prefix + (rename or {}).get(name, name.upper()): code for name, code in table.items()}
    for fname, code in expected.items():
        assert fname in consts, f"{key}: {fname} missing from fortran/{source}"
        assert consts[fname] == code, f"{key}: {fname} = {consts[fname]} in Fortran, {code} in Python"
    if key == "time_scheme":
        # the prefix FOLD_ is shared with other constants of the module: check the value set
        assert set(consts.values()) == set(table.values())
    elif key == "shape":
        assert {consts[n] for n in ("FOLD_FIBRE", "FOLD_SPHERE", "FOLD_SPHEROID")} == set(table.values())
    else:
        extra = {n for n in consts if n.startswith(prefix)} - set(expected)
        assert not extra, f"{key}: Fortran constants without a Python name: {sorted(extra)}"


def test_scene_choices_are_the_keys_of_the_stokes_code_tables():
    """Every word the scene accepts for a Stokes setting has a code, and every code a word,
    except the backend's "auto", which the normaliser resolves to a coded backend."""
    fields = StokesSettings.model_fields
    for key, table in (("backend", stokes.BACKENDS), ("derivative", stokes.DERIVATIVES),
                       ("mixing", stokes.MIXINGS), ("fibre_ends", stokes.FIBRE_ENDS),
                       ("initial_guess", stokes.GUESSES), ("fft_plan", stokes.FFT_PLANS),
                       ("fft_precision", stokes.FFT_PRECISIONS)):
        words = set(fields[key].annotation.__args__)
        if key == "backend":
            assert stokes.AUTO_BACKEND in words and stokes.AUTO_BACKEND not in table
            assert set(stokes.BACKEND_CHOICES) == words
            words -= {stokes.AUTO_BACKEND}
        assert words == set(table), key


@pytest.mark.parametrize("walls", [False, True])
def test_auto_backend_resolves_to_the_coded_backend_of_the_cell(walls):
    """"auto" is hypre with walls, fft without; the other backend is refused for that cell."""
    chosen = stokes.backend_for(walls)
    assert chosen in stokes.BACKENDS and chosen == ("hypre" if walls else "fft")
    boundary = "couette" if walls else "periodic"
    text = (REPO / "data/scenes/stokes_small.toml").read_text().replace(
        "[cell]", f'[cell]\nboundary = "{boundary}"').replace('hydrodynamics = "auto"', 'hydrodynamics = "stokes"')
    res = parse_scene(text)
    assert int(res.resolved_datasets()["stokes_backend"][0]) == stokes.BACKENDS[chosen]
    other = next(b for b in stokes.BACKENDS if b != chosen)
    with pytest.raises(ValueError, match=rf"numerics.stokes.backend: '{other}'.*allowed: '{chosen}' or 'auto'"):
        parse_scene(text.replace("[numerics.stokes]", f'[numerics.stokes]\nbackend = "{other}"'))


def test_stokes_defaults_have_one_source():
    scene, native = StokesSettings(), stokes.StokesSettings()
    d = stokes.DEFAULTS
    assert {k: getattr(scene, k) for k in d} == d
    assert (native.tol, native.max_iter, native.kappa, native.derivative, native.mixing, native.subsamples,
            native.fibre_ends, native.warm_start, native.guess, native.backend) == (
        d["tolerance"], d["max_iterations"], d["kappa"], d["derivative"], d["mixing"], d["subsamples"],
        d["fibre_ends"], d["warm_start"], d["initial_guess"], d["backend"])
    assert native.measure_plans == (d["fft_plan"] == "measure")


def test_stokes_kappa_bounds_are_stated_once_and_fortran_uses_them():
    consts = fortran_constants("core/fold_settings.f90")
    assert (consts["FOLD_KAPPA_MIN"], consts["FOLD_KAPPA_MAX"]) == (stokes.KAPPA_MIN, stokes.KAPPA_MAX)
    assert (consts["FOLD_LO_STOKES_KAPPA"], consts["FOLD_HI_STOKES_KAPPA"]) == (stokes.KAPPA_MIN, stokes.KAPPA_MAX)
    # the run-file reader takes its range from those constants, not from literals
    assert "FOLD_LO_STOKES_KAPPA, FOLD_HI_STOKES_KAPPA, s%stokes%kappa" in (FORTRAN / "io/fold_run_file.f90").read_text()


# the next representable numbers outside the range: the smallest violation there is
BELOW, ABOVE = np.nextafter(stokes.KAPPA_MIN, 0.0), np.nextafter(stokes.KAPPA_MAX, np.inf)


@pytest.mark.parametrize("kappa", [stokes.KAPPA_MIN, stokes.KAPPA_MAX])
def test_stokes_kappa_at_the_bounds_is_accepted_by_scene_and_bindings(kappa):
    assert StokesSettings(kappa=kappa).kappa == kappa
    assert stokes.StokesSettings(kappa=kappa).kappa == kappa


@pytest.mark.parametrize("kappa", [BELOW, ABOVE])
def test_stokes_kappa_outside_the_bounds_is_refused_by_scene_bindings_and_fold_run(kappa, tmp_path):
    with pytest.raises(ValidationError, match="kappa"):
        StokesSettings(kappa=float(kappa))
    with pytest.raises(ValueError, match="kappa"):
        stokes.StokesSettings(kappa=float(kappa))
    require_fold_run()
    path = tmp_path / "kappa.h5"
    write_run_file(path, x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=0.1, length=0.6, xi=xi_of(3.0),
                   shape=[3], stokes={"stokes_grid": (8, 8, 8), "stokes_kappa": float(kappa)})
    proc = run_fold(path)
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert "/setup/resolved/stokes_kappa" in proc.stderr, proc.stderr


@pytest.mark.parametrize("key", ["stokes_backend", "stokes_mixing", "stokes_subsamples", "stokes_fibre_ends",
                                 "stokes_warm_start"])
def test_stokes_setting_missing_from_the_run_file_is_refused_not_defaulted(key, tmp_path):
    assert key in STOKES_DEFAULTS
    require_fold_run()
    path = tmp_path / "missing.h5"
    write_run_file(path, x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=0.1, length=0.6, xi=xi_of(3.0),
                   shape=[3], stokes={"stokes_grid": (8, 8, 8)}, drop=(key,))
    proc = run_fold(path)
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert f"/setup/resolved/{key}" in proc.stderr, proc.stderr


def test_normalised_stokes_scene_writes_every_solver_setting():
    """What the scene sets reaches /setup/resolved as codes of the shared tables."""
    text = (REPO / "data/scenes/stokes_small.toml").read_text().replace(
        "[numerics.stokes]", '[numerics.stokes]\nmixing = "geometric"\nsubsamples = 5\n'
        'fibre_ends = "capped"\nwarm_start = false\nfft_plan = "estimate"')
    res = parse_scene(text).resolved_datasets()
    got = {k: int(res[k][0]) for k in ("stokes_backend", "stokes_mixing", "stokes_subsamples", "stokes_fibre_ends",
                                       "stokes_warm_start", "stokes_fft_plan")}
    assert got == {"stokes_backend": stokes.BACKENDS["fft"], "stokes_mixing": stokes.MIXINGS["geometric"],
                   "stokes_subsamples": 5, "stokes_fibre_ends": stokes.FIBRE_ENDS["capped"], "stokes_warm_start": 0,
                   "stokes_fft_plan": stokes.FFT_PLANS["estimate"]}


def test_the_bindings_refuse_a_backend_they_do_not_run():
    """The bindings solve periodic cells with the FFT solver only: 'hypre' must not pass
    validation there and then be solved by FFT."""
    assert stokes.StokesSettings(backend="auto").backend == "auto"
    assert stokes.StokesSettings(backend="fft").backend == "fft"
    with pytest.raises(ValueError, match="backend.*'fft' or 'auto'"):
        stokes.StokesSettings(backend="hypre")


@pytest.mark.parametrize("side", [-1, +1])
def test_single_precision_tolerance_bound_is_the_same_in_validate_and_fold_run(side, tmp_path):
    """fft_precision = 'single' is refused below (2 log2 N + 4) 2^-24 by both pyfold
    validate (pyfold.native.stokes.single_tolerance_min) and fold_run (fold_stokes_fft
    single_tol_min); just above the bound both accept. 1e-9 relative is far outside the
    round-off of evaluating the bound (a few ulps) and far inside its change between
    grids."""
    base = (REPO / "data/scenes/stokes_small.toml").read_text()

    def scene(tol):
        return base.replace("tolerance = 1e-6", f'fft_precision = "single"\ntolerance = {tol!r}')

    # the grid only (1e-4: a single-precision tolerance at which the scene's kappa = 1e3 is
    # allowed, pyfold.native.stokes.kappa_range)
    grid = parse_scene(scene(1e-4)).resolved_datasets()["stokes_grid"][0]
    tol = stokes.single_tolerance_min(int(np.prod([int(v) for v in grid]))) * (1.0 + side * 1e-9)
    if side > 0:
        parse_scene(scene(tol))
    else:
        with pytest.raises(ValueError, match=r"numerics.stokes.tolerance.*fft_precision"):
            parse_scene(scene(tol))
    require_fold_run()
    n = 8
    path = tmp_path / "single.h5"
    write_run_file(path, x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=0.1, length=0.6, xi=xi_of(3.0),
                   shape=[3], t_end=0.01,
                   stokes={"stokes_grid": (n, n, n), "stokes_fft_precision": 1,
                           "stokes_tolerance": stokes.single_tolerance_min(n**3) * (1.0 + side * 1e-9)})
    proc = run_fold(path)
    assert proc.returncode == (2 if side < 0 else 0), (proc.returncode, proc.stderr)
    if side < 0:
        assert "fft_precision" in proc.stderr, proc.stderr
