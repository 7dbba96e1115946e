"""Every ``from pyfold... import name`` (and every import from a test helper module such as
``test_run_common``) in the project names something that exists.

A test helper or a rarely run path (a study, a benchmark, an ``except ImportError``
fallback) can import a name that was renamed or never defined; the import then fails
only when that path runs, or, behind a broad ``except``, silently changes behaviour.
This test reads every Python file of the project statically (``ast``), including
imports inside functions, and resolves each pyfold import: the module must import and
each imported name must be an attribute of it or a submodule.
"""
from __future__ import annotations

import ast
import importlib
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Folders whose Python files are checked.
CHECKED = ("pyfold", "tests", "studies", "benchmarks", "scripts")


def project_python_files() -> list[Path]:
    try:
        listed = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.split()
        files = [ROOT / f for f in listed]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout (e.g. an sdist)
        files = list(ROOT.rglob("*.py"))
    return sorted(f for f in files if f.exists() and f.relative_to(ROOT).parts[0] in CHECKED)


def helper_modules() -> dict[str, Path]:
    """The test-suite helper modules that tests, benchmarks and studies import by bare
    name after putting their folder on ``sys.path`` (``test_run_common``, ...)."""
    return {f.stem: f for f in (ROOT / "tests").rglob("*.py") if not f.name.startswith("test_") or f.stem == "test_run_common"}


def pyfold_imports(path: Path) -> list[tuple[int, str, str | None]]:
    """(line, module, name) of each absolute pyfold import, and of each import from a
    test helper module; name is None for ``import m``."""
    helpers = helper_modules()
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and (node.module.split(".")[0] == "pyfold" or node.module in helpers):
            out += [(node.lineno, node.module, alias.name) for alias in node.names if alias.name != "*"]
        elif isinstance(node, ast.Import):
            out += [(node.lineno, alias.name, None) for alias in node.names if alias.name.split(".")[0] == "pyfold"]
    return out


def unresolved(module: str, name: str | None) -> str | None:
    helpers = helper_modules()
    if module in helpers:
        # a helper module: read its top-level names statically (no import side effects)
        tree = ast.parse(helpers[module].read_text(encoding="utf-8"))
        defined = set()
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                defined.add(node.name)
            elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                defined |= {t.id for t in targets if isinstance(t, ast.Name)}
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                defined |= {(a.asname or a.name).split(".")[0] for a in node.names}
        return None if name in defined else f"{module} ({helpers[module].relative_to(ROOT)}) defines no {name!r}"
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        return f"module {module} does not import ({exc})"
    if name is None or hasattr(mod, name):
        return None
    try:
        importlib.import_module(f"{module}.{name}")
    except ModuleNotFoundError:
        return f"{module} has no attribute or submodule {name!r}"
    return None


def test_every_pyfold_import_in_the_project_resolves():
    files = project_python_files()
    assert len(files) > 50, "the project's Python files were not found"
    problems = []
    for path in files:
        for line, module, name in pyfold_imports(path):
            why = unresolved(module, name)
            if why:
                problems.append(f"{path.relative_to(ROOT)}:{line}: {why}")
    assert not problems, "unresolved pyfold imports:\n" + "\n".join(problems)


def test_the_import_check_catches_a_missing_name():
    assert unresolved("pyfold.native", "fold_run_executable")
    assert unresolved("pyfold.no_such_module", "x")
    assert unresolved("pyfold.native", "stats") is None  # a submodule
    assert unresolved("pyfold.commands.run", "find_fold_run") is None
    assert unresolved("test_run_common", "fold_run_path")  # removed: found as pyfold run finds it
    assert unresolved("test_run_common", "write_run_file") is None
