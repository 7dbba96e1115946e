"""The solver seam: a Stokes backend or rigidity formulation is its registry entry
(pyfold/scene/registry.py BACKENDS, RIGIDITIES) and its own module in fortran/stokes.

The construction that chooses one by its code is generated from the registry:
scripts/generate_settings lists each entry's module, constructor and code constant in
fortran/stokes/solver_modules.txt, and fortran/stokes/meson.build compiles the modules
and writes the constructor calls into the templates fold_stokes_build.f90.in
(formulations) and fold_stokes_factory.f90.in (backends not on an FFT transport).
Nothing in the hand-written Fortran names an entry's module, constructor or code
constant outside its own module, so nothing branches on it by name; the few places that
legitimately do (its own tests, a module built on another) are listed in ALLOWED with
the reason. Adding a solver then touches its module, its registry entry, its tests and
its docs only.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from pyfold.scene import registry

REPO = Path(__file__).resolve().parents[2]
FORTRAN = REPO / "fortran"
STOKES = FORTRAN / "stokes"

#: the Fortran file scripts/generate_settings writes from the registry: it names every entry
GENERATED = {"fortran/core/fold_settings.f90"}

#: Every entry of RIGIDITIES and BACKENDS: (label, module or None, constructor or None,
#: code constant)
ENTRIES = [(f"rigidity {r.name}", r.fortran_module, r.constructor, r.fortran_code)
           for r in registry.RIGIDITIES.values()] + \
          [(f"backend {b.name}", b.fortran_module, b.constructor, b.fortran_code)
           for b in registry.BACKENDS.values()]

_TESTS = "fortran/stokes/tests/"
_FFT_TESTS = "the penalised FFT solver's own tests, which drive stokes_fft_t directly"

#: The module of the penalised FFT solver, whose type (stokes_fft_t: the transport, the CG
#: and the operator tables) the other formulations on an FFT transport extend: a
#: formulation's own module may use it (as fold_stokes_rigid does), no other module.
FFT_BASE = registry.RIGIDITIES["penalty"].fortran_module

#: (file, name) -> why that hand-written file names an entry's module, constructor or code.
#: Each is needed (test_every_exception_is_still_needed), so the list stays narrow.
ALLOWED: dict[tuple[str, str], str] = {
    ("fortran/stokes/fold_stokes_trust.f90", "fold_stokes_fft"):
        "the bound on the single-precision rounding (FOLD_SINGLE_ROUNDOFF) of the FFT solver's transforms",
    (_TESTS + "stokes_test_solver.f90", "fold_stokes_fft"): _FFT_TESTS,
    (_TESTS + "test_stokes_mpi.f90", "fold_stokes_fft"): _FFT_TESTS,
    (_TESTS + "test_stokes_single.f90", "fold_stokes_fft"): _FFT_TESTS,
    (_TESTS + "test_stokes_stencil.f90", "fold_stokes_fft"): _FFT_TESTS,
    (_TESTS + "bench_stokes_fft.f90", "fold_stokes_fft"): _FFT_TESTS,
    (_TESTS + "test_stokes_rigid.f90", "fold_stokes_rigid"): "the exact formulation's own test",
    (_TESTS + "test_stokes_rigid.f90", "FOLD_RIGIDITY_EXACT"): "the exact formulation's own test",
    (_TESTS + "test_stokes_hypre.f90", "fold_stokes_hypre"): "the hypre backend's own test",
    (_TESTS + "test_stokes_hypre.f90", "FOLD_STOKES_HYPRE"): "the hypre backend's own test",
    (_TESTS + "test_stokes_hypre.f90", "FOLD_STOKES_FFT"): "the hypre backend's own test compares it with fft",
    (_TESTS + "bench_stokes_hypre.f90", "fold_stokes_hypre"): "the hypre backend's own benchmark",
    (_TESTS + "bench_stokes_hypre.f90", "FOLD_STOKES_HYPRE"): "the hypre backend's own benchmark",
    (_TESTS + "bench_stokes_hypre.f90", "FOLD_STOKES_FFT"): "the hypre backend's own benchmark runs fft too",
}

_STRING_OR_COMMENT = re.compile(r"""'(?:[^']|'')*'|"(?:[^"]|"")*"|!.*""")


def _code(text: str) -> str:
    """Fortran source without its comments (string literals kept)."""
    return _STRING_OR_COMMENT.sub(lambda m: "" if m.group(0).startswith("!") else m.group(0), text)


def _hand_written() -> dict[str, str]:
    """Relative path -> code (comments removed) of every hand-written Fortran source."""
    files = sorted(FORTRAN.rglob("*.f90")) + sorted(FORTRAN.rglob("*.f90.in"))
    return {rel: _code(p.read_text(encoding="utf-8"))
            for p in files if (rel := p.relative_to(REPO).as_posix()) not in GENERATED}


SOURCES = _hand_written()


def _own_module(module: str | None) -> str | None:
    return f"fortran/stokes/{module}.f90" if module else None


def _allowed(rel: str, name: str) -> bool:
    """Whether file rel may name name: a listed exception, or a formulation's module
    building on the FFT solver's type."""
    formulations = {_own_module(r.fortran_module) for r in registry.RIGIDITIES.values()}
    return (rel, name) in ALLOWED or (name == FFT_BASE and rel in formulations)


_MODULE_REF = re.compile(r"\b(use|module)\s+(\w+)", re.IGNORECASE)


def _names_outside(label: str, module: str | None, constructor: str | None, constant: str):
    """(file, name) of each place outside the entry's own module that names it. Fortran
    names are case-insensitive, and a module may share its name with a code constant
    (fold_stokes_fft, FOLD_STOKES_FFT): a module is named after ``use``, the others
    anywhere else."""
    for rel, code in SOURCES.items():
        if rel == _own_module(module):
            continue
        used = {m.group(2).lower() for m in _MODULE_REF.finditer(code) if m.group(1).lower() == "use"}
        rest = _MODULE_REF.sub(r"\1", code)
        if module and module.lower() in used:
            yield rel, module
        for name in (constructor, constant):
            if name and re.search(rf"\b{name}\b", rest, re.IGNORECASE):
                yield rel, name


@pytest.mark.parametrize("label, module, constructor, constant", ENTRIES, ids=[e[0] for e in ENTRIES])
def test_nothing_outside_an_entry_names_it(label, module, constructor, constant):
    """No hand-written Fortran outside the entry's module names its module, constructor or
    code constant, except the exceptions of ALLOWED."""
    found = [f"{rel}: {name}" for rel, name in _names_outside(label, module, constructor, constant)
             if not _allowed(rel, name)]
    assert not found, f"{label} is named outside its module (branch on a capability instead): {found}"


def test_every_exception_is_still_needed():
    used = {place for entry in ENTRIES for place in _names_outside(*entry)}
    assert not set(ALLOWED) - used, f"stale exceptions: {sorted(set(ALLOWED) - used)}"


@pytest.mark.parametrize("label, module, constructor, constant", ENTRIES, ids=[e[0] for e in ENTRIES])
def test_an_entry_module_defines_its_constructor_with_the_signature_of_its_kind(label, module, constructor,
                                                                                constant):
    """A formulation's constructor takes (fft, set, solver, stat, errmsg), the constructor
    of a backend not on an FFT transport (set, dim, n, comm, solver, stat, errmsg); an
    FFT-transport backend has none (its formulations make it)."""
    backend = registry.BACKENDS.get(label.split()[1]) if label.startswith("backend") else None
    if backend is not None and backend.fft_transport:
        assert module is None and constructor is None, label
        return
    assert module and constructor, f"{label}: no fortran_module / constructor in the registry"
    path = STOKES / f"{module}.f90"
    assert path.is_file(), f"{label}: {path.relative_to(REPO)} missing"
    code = re.sub(r"&\s*\n\s*", "", _code(path.read_text(encoding="utf-8")))
    assert re.search(rf"^\s*module\s+{module}\s*$", code, re.IGNORECASE | re.MULTILINE), f"{label}: no module {module}"
    args = "set, dim, n, comm, solver, stat, errmsg" if backend is not None else "fft, set, solver, stat, errmsg"
    assert re.search(rf"subroutine\s+{constructor}\s*\(\s*{re.escape(args)}\s*\)", code, re.IGNORECASE), \
        f"{label}: {module} has no subroutine {constructor}({args})"
    assert re.search(rf"public\s*::.*\b{constructor}\b", code, re.IGNORECASE), f"{label}: {constructor} not public"


def test_the_construction_and_the_meson_sources_are_generated_from_the_entries():
    """Each formulation and each backend not on an FFT transport is a line of the generated
    solver list, which fortran/stokes/meson.build reads to compile its module and to write
    its constructor call into the construction templates; neither meson.build nor a
    template names one."""
    listed = [line.split() for line in (STOKES / "solver_modules.txt").read_text(encoding="utf-8").splitlines()
              if line and not line.startswith("#")]
    expected = [["formulation", r.fortran_module, r.constructor, r.fortran_code]
                for r in sorted(registry.RIGIDITIES.values(), key=lambda r: r.code)]
    expected += [["backend", b.fortran_module, b.constructor, b.fortran_code]
                 for b in sorted(registry.BACKENDS.values(), key=lambda b: b.code) if not b.fft_transport]
    assert listed == expected
    meson = (STOKES / "meson.build").read_text(encoding="utf-8")
    assert "fs.read('solver_modules.txt')" in meson
    for _, module, constructor, constant in expected:
        assert module not in meson and constructor not in meson and constant not in meson, module
    for template, kind in (("fold_stokes_build.f90.in", "FORMULATION"), ("fold_stokes_factory.f90.in", "BACKEND")):
        text = (STOKES / template).read_text(encoding="utf-8")
        assert f"\n@{kind}_USES@\n" in text and f"\n@{kind}_CASES@\n" in text, template
