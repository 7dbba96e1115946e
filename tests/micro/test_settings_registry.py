"""The settings registry (pyfold/scene/registry.py) is the one declaration of each setting:
its generated copies are current, fold_run reads every registered dataset within the
registry's range, and a value `pyfold validate` accepts at a bound is run by fold_run."""
from __future__ import annotations

import re
import subprocess
import sys
import typing
from pathlib import Path

import numpy as np
import pytest
from test_run_common import require_fold_run, run_fold, write_run_file, xi_of

from pyfold.native import stokes
from pyfold.scene import registry, schema

REPO = Path(__file__).resolve().parents[2]
READER = REPO / "fortran" / "io" / "fold_run_file.f90"


def test_generated_fortran_module_and_docs_tables_are_current():
    """fortran/core/fold_settings.f90, the marked tables of docs/scenes.md and the solver
    list fortran/stokes/solver_modules.txt (from which meson writes the construction) are
    what scripts/generate_settings makes from the registry now."""
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "generate_settings"), "--check"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def _reader_text() -> str:
    # one statement per line: Fortran continuation lines joined
    return re.sub(r"&\s*\n\s*", "", READER.read_text())


@pytest.mark.parametrize("s", [s for s in registry.SETTINGS if s.fortran and s.resolved and s.path != "particles.shape"],
                         ids=lambda s: s.path)
def test_the_run_file_reader_takes_each_range_from_the_registry(s):
    """Every registered /setup/resolved dataset is read within FOLD_LO_<stem> ... FOLD_HI_<stem>
    (fortran/core/fold_settings.f90), never a literal range."""
    call = re.compile(rf'get_(?:int|real)\(file, R//"{s.resolved}", FOLD_LO_{s.fortran}, FOLD_HI_{s.fortran},')
    assert call.search(_reader_text()), f"{s.resolved}: not read within FOLD_LO_{s.fortran} ... FOLD_HI_{s.fortran}"


def test_optional_datasets_default_to_the_registry():
    text = _reader_text()
    for s in registry.SETTINGS:
        if s.optional:
            # assigned before the read, or given to get_int as the value of an absent dataset
            assert f"= FOLD_DEF_{s.fortran}" in text or f"if_absent=FOLD_DEF_{s.fortran}" in text, s.path


def _table_of(annotation) -> type[schema.BaseModel] | None:
    """The schema model of a field that is a table or an array of tables, else None."""
    if isinstance(annotation, type) and issubclass(annotation, schema.BaseModel):
        return annotation
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    return next((m for m in map(_table_of, args) if m is not None), None)


def _fields(model: type[schema.BaseModel], prefix: str = ""):
    """(TOML path, field) of every key of ``model`` that is not a table, descending into tables."""
    for name, info in model.model_fields.items():
        table = _table_of(info.annotation)
        path = prefix + name
        if table is None:
            yield path, info
        else:
            yield from _fields(table, f"{path}.")


SCHEMA_FIELDS = dict(_fields(schema.Scene))


def test_every_schema_key_is_a_registry_setting_and_every_setting_a_schema_key():
    """A scene key cannot bypass the registry: the keys of the schema's models and the
    registered settings are the same set."""
    assert set(SCHEMA_FIELDS) == {s.path for s in registry.SETTINGS}


@pytest.mark.parametrize("path", sorted(SCHEMA_FIELDS))
def test_each_schema_field_has_the_registered_default(path):
    """A field with a registered default has it; one without is required or None."""
    info, default = SCHEMA_FIELDS[path], registry.setting(path).default
    if default is None:
        assert info.is_required() or info.default is None, path
    else:
        assert info.default == default and type(info.default) is type(default), path


def test_backend_for_follows_the_capability_table():
    for walls in (False, True):
        chosen = registry.BACKENDS[registry.backend_for(walls)]
        assert (chosen.walls if walls else chosen.lees_edwards)
        assert stokes.backend_for(walls) == chosen.name
    assert stokes.BACKENDS == {b.name: b.code for b in registry.BACKENDS.values()}


# the largest double below 1: the top of numerics.stokes.tolerance in (0, 1)
_BELOW_ONE = float(np.nextafter(1.0, 0.0))

#: (scene key, dataset, value at a bound of the registry's range); each a cheap run. A
#: tolerance near 1 carries kappa <= 2 only (pyfold.native.stokes.kappa_range): kappa = 1 there.
BOUNDS = [
    ("tolerance", "stokes_tolerance", _BELOW_ONE),
    ("kappa", "stokes_kappa", registry.KAPPA_MIN),
    ("max_iterations", "stokes_max_iterations", registry.setting("numerics.stokes.max_iterations").hi),
    ("subsamples", "stokes_subsamples", registry.setting("numerics.stokes.subsamples").lo),
    ("subsamples", "stokes_subsamples", registry.setting("numerics.stokes.subsamples").hi),
    ("solve_every", "stokes_solve_every", registry.setting("numerics.stokes.solve_every").hi),
    ("fibre_radius_scale", "stokes_fibre_radius_scale", registry.setting("numerics.stokes.fibre_radius_scale").lo),
    ("fibre_radius_scale", "stokes_fibre_radius_scale", registry.setting("numerics.stokes.fibre_radius_scale").hi),
]


@pytest.mark.parametrize("key, dataset, value", BOUNDS, ids=[f"{d}={v:g}" for _, d, v in BOUNDS])
def test_a_setting_validate_accepts_at_its_bound_is_run_by_fold_run(key, dataset, value, tmp_path):
    assert getattr(schema.StokesSettings(**{key: value}), key) == value
    require_fold_run()
    path = tmp_path / "bound.h5"
    val = np.int64(value) if isinstance(value, int) else float(value)
    write_run_file(path, x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=0.1, length=0.6, xi=xi_of(3.0),
                   shape=[3], t_end=0.02,
                   stokes={"stokes_grid": (8, 8, 8), **({"stokes_kappa": 1.0} if key == "tolerance" else {}), dataset: val})
    proc = run_fold(path)
    assert proc.returncode == 0, (proc.returncode, proc.stderr)


_CAP = registry.setting("model.contact_max_iter").hi


@pytest.mark.parametrize("dataset, value, accepted", [("contact_max_iter", _CAP, True), ("alpha", 0.0, True),
                                                      ("contact_max_iter", _CAP + 1, False), ("alpha", -1e-300, False)])
def test_a_contact_setting_is_run_at_its_bound_and_refused_beyond(dataset, value, accepted, tmp_path):
    """fold_run runs a contact setting at the bound of the schema's range (exit 0) and refuses
    it just beyond, naming the dataset (exit 2)."""
    s = registry.resolved(dataset)
    if accepted:
        assert getattr(schema.Model(**{s.key: value}), s.key) == value
    require_fold_run()
    path = tmp_path / "contact.h5"
    write_run_file(path, x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=0.05, length=0.5, xi=xi_of(5.0),
                   t_end=0.02, collisions=2, **{dataset: value})
    proc = run_fold(path)
    assert proc.returncode == (0 if accepted else 2), (proc.returncode, proc.stderr)
    if not accepted:
        assert f"/setup/resolved/{dataset}" in proc.stderr, proc.stderr


_VISCOSITY = registry.setting("fluid.viscosity")


@pytest.mark.parametrize("dataset, value, accepted", [
    ("viscosity", _VISCOSITY.hi, True), ("viscosity", _VISCOSITY.lo, True),
    ("viscosity", float(np.nextafter(_VISCOSITY.hi, np.inf)), False),
    ("viscosity", float(np.nextafter(_VISCOSITY.lo, 0.0)), False),
    ("dim", np.int32(registry.setting("cell.dim").hi + 1), False)])
def test_a_cell_or_fluid_setting_is_run_within_the_registry_range_and_refused_beyond(dataset, value, accepted,
                                                                                     tmp_path):
    """fold_run reads the viscosity and the dimension within the range `pyfold validate`
    accepts (exit 0 at a bound) and refuses a value beyond it, naming the dataset (exit 2)."""
    require_fold_run()
    path = tmp_path / "cell.h5"
    write_run_file(path, x=[[0.5, 0.5, 0.5]], p=[[1.0, 0.0, 0.0]], radius=0.05, length=0.5, xi=xi_of(5.0),
                   t_end=0.02, override={f"/setup/resolved/{dataset}": value})
    proc = run_fold(path)
    assert proc.returncode == (0 if accepted else 2), (proc.returncode, proc.stderr)
    if not accepted:
        assert f"/setup/resolved/{dataset}" in proc.stderr, proc.stderr


def test_every_rigidity_word_has_a_formulation_entry_and_the_fortran_table_follows_it():
    """The rigidity formulations (registry.RIGIDITIES) cover the words of
    numerics.stokes.rigidity, and the generated Fortran names/kappa flags, indexed by
    code, are theirs: fold_run asks them instead of testing a formulation's name."""
    words = set(registry.setting("numerics.stokes.rigidity").choices)
    assert set(registry.RIGIDITIES) == words
    text = (REPO / "fortran" / "core" / "fold_settings.f90").read_text(encoding="utf-8")
    ordered = sorted(registry.RIGIDITIES.values(), key=lambda r: r.code)
    names = ", ".join(f'"{r.name}"' for r in ordered)
    flags = ", ".join(".true." if r.uses_kappa else ".false." for r in ordered)
    assert f":: {names}]" in text
    assert f"FOLD_RIGIDITY_USES_KAPPA({ordered[0].code}:{ordered[-1].code}) = [{flags}]" in text


def test_the_staleness_check_covers_the_solver_list(tmp_path):
    """A solver list that differs from the registry is reported stale by --check."""
    import shutil
    root = tmp_path / "repo"
    for rel in ("scripts/generate_settings", "pyfold/scene/registry.py", "pyfold/scene/settings_docs.py",
                "fortran/core/fold_settings.f90", "docs/scenes.md", "fortran/stokes/solver_modules.txt"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / rel, root / rel)
    script = [sys.executable, str(root / "scripts" / "generate_settings"), "--check"]
    assert subprocess.run(script, capture_output=True, text=True).returncode == 0
    listed = root / "fortran" / "stokes" / "solver_modules.txt"
    listed.write_text(listed.read_text(encoding="utf-8").replace("stokes_rigid_new", "stokes_rigid_make"),
                      encoding="utf-8")
    proc = subprocess.run(script, capture_output=True, text=True)
    assert proc.returncode == 1 and "solver_modules.txt is stale" in proc.stderr, proc.stderr
