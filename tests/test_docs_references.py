"""Every documentation reference in the project points at something that exists.

Comments, docstrings, scenes and docs cite the project's own documents as
``docs/<name>.md#<anchor>`` (inside ``docs/*.md``: relative links such as
``[text](<name>.md#<anchor>)`` or ``[text](#<anchor>)``). These tests check, over
every text file of the project, that

* the cited file exists and, when an anchor is given, that it has a heading whose
  GitHub slug is that anchor (so a renamed heading cannot leave dangling links);
* the physics reference is never cited without its ``docs/`` prefix, which would
  point at a document outside the project;
* no comment carries process provenance (who wrote it, under which work item):
  a comment says why, about the code.

Pure text scanning: no JAX, no native code, well under a second.
"""
from __future__ import annotations

import functools
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: File suffixes scanned (plus every file under SCANNED_DIRS, whatever its suffix).
SUFFIXES = {".py", ".f90", ".F90", ".pyf", ".md", ".toml", ".txt", ".build", ".cfg"}
SCANNED_DIRS = ("scripts", ".ci")
#: Never scanned when walking the tree without git (environments, build and output trees).
EXCLUDED_DIRS = {".venv", "build", ".git", "out"}

#: ``docs/<name>.md`` optionally followed by ``#anchor``, not part of a longer path.
DOCS_REFERENCE = re.compile(r"(?<![\w./-])docs/([\w.-]+?\.md)(?:#([\w-]*))?")
#: Inside docs/*.md: a relative link target ``(<name>.md)`` / ``(<name>.md#anchor)``.
RELATIVE_LINK = re.compile(r"\]\(([\w.-]+?\.md)(?:#([\w-]*))?\)")
#: Inside docs/*.md: a link to a heading of the same page, ``(#anchor)``.
SELF_LINK = re.compile(r"\]\(#([\w-]+)\)")
#: The physics reference by its bare file name (the name is split so that this
#: file does not match itself).
PHYSICS_NAME = "physics" + ".md"
BARE_PHYSICS = re.compile(re.escape(PHYSICS_NAME))
#: Process provenance: an engineer named by a capital letter, or a numbered issue.
PROVENANCE = re.compile(r"\b[Ee]ngineer [A-Z]\b|\b[Ii]ssue [0-9]+\b")

HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
FENCE = re.compile(r"^ {0,3}(```|~~~)")
MARKDOWN_LINK = re.compile(r"\[([^\]]*)\]\([^)]*\)")


def github_slug(heading: str) -> str:
    """GitHub's anchor for a heading: link text kept, lowercase, every character
    that is not a letter, digit, space, ``-`` or ``_`` removed, spaces -> ``-``."""
    text = MARKDOWN_LINK.sub(r"\1", heading).strip().lower()
    text = "".join(ch for ch in text if ch.isalnum() or ch in " -_")
    return text.replace(" ", "-")


def _project_files() -> list[Path]:
    """Project text files to scan: git's tracked and not-ignored untracked files
    (so new documents are checked before they are committed), else a tree walk."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT, capture_output=True, check=True, timeout=30,
        ).stdout.decode("utf-8", "replace")
        rel = [Path(p) for p in out.split("\0") if p]
    except (OSError, subprocess.SubprocessError):
        rel = [
            p.relative_to(ROOT) for p in ROOT.rglob("*")
            if p.is_file() and not EXCLUDED_DIRS.intersection(p.relative_to(ROOT).parts)
        ]
    files = []
    for p in sorted(set(rel)):
        if EXCLUDED_DIRS.intersection(p.parts) or not (ROOT / p).is_file():
            continue
        if p.suffix in SUFFIXES or (p.parts and p.parts[0] in SCANNED_DIRS):
            files.append(p)
    return files


@functools.lru_cache(maxsize=None)
def _scanned() -> tuple[tuple[Path, tuple[str, ...]], ...]:
    return tuple(
        (p, tuple((ROOT / p).read_text(encoding="utf-8", errors="replace").splitlines()))
        for p in _project_files()
    )


@functools.lru_cache(maxsize=None)
def _anchors(doc: Path) -> frozenset[str]:
    """Slugs of the ATX headings of a Markdown file (outside fenced code), with
    GitHub's ``-1``, ``-2`` suffixes for repeated headings."""
    seen: dict[str, int] = {}
    anchors = set()
    in_fence = False
    for line in (ROOT / doc).read_text(encoding="utf-8", errors="replace").splitlines():
        if FENCE.match(line):
            in_fence = not in_fence
            continue
        m = None if in_fence else HEADING.match(line)
        if m:
            slug = github_slug(m.group(2))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            anchors.add(slug if n == 0 else f"{slug}-{n}")
    return frozenset(anchors)


def _is_docs_page(path: Path) -> bool:
    return len(path.parts) == 2 and path.parts[0] == "docs" and path.suffix == ".md"


def _check_target(doc: Path, anchor: str | None) -> str | None:
    """Why a reference to ``doc`` (relative to the root) with ``anchor`` is broken, or None."""
    if not (ROOT / doc).is_file():
        return f"{doc.as_posix()} does not exist"
    if anchor and anchor not in _anchors(doc):
        return f"{doc.as_posix()} has no heading with the anchor #{anchor}"
    return None


def _report(problems: list[str], what: str) -> str:
    return f"{len(problems)} {what}:\n  " + "\n  ".join(problems)


def test_project_files_are_found():
    names = {p.as_posix() for p, _ in _scanned()}
    assert "README.md" in names and "meson.build" in names and "scripts/test" in names, sorted(names)[:20]
    assert Path(__file__).resolve().relative_to(ROOT).as_posix() in names


def test_slug_follows_github_rules():
    assert github_slug("Numerical limits and pitfalls") == "numerical-limits-and-pitfalls"
    assert github_slug("Published C_I values and correlations") == "published-c_i-values-and-correlations"
    assert github_slug("The seed's Couette disks") == "the-seeds-couette-disks"
    assert github_slug("The 3-D natural closure") == "the-3-d-natural-closure"
    assert github_slug("`a4` from [a link](x.md)") == "a4-from-a-link"


def test_every_docs_reference_points_at_an_existing_heading():
    problems = []
    for path, lines in _scanned():
        for no, line in enumerate(lines, 1):
            targets = [(Path("docs") / m.group(1), m.group(2)) for m in DOCS_REFERENCE.finditer(line)]
            if _is_docs_page(path):
                targets += [(Path("docs") / m.group(1), m.group(2)) for m in RELATIVE_LINK.finditer(line)]
                targets += [(path, m.group(1)) for m in SELF_LINK.finditer(line)]
            for doc, anchor in targets:
                why = _check_target(doc, anchor)
                if why:
                    problems.append(f"{path.as_posix()}:{no}: {why}")
    assert not problems, _report(problems, "broken documentation references")


def test_physics_reference_is_always_cited_under_docs():
    problems = []
    for path, lines in _scanned():
        for no, line in enumerate(lines, 1):
            for m in BARE_PHYSICS.finditer(line):
                before = line[: m.start()]
                if before.endswith("docs/"):
                    continue
                if _is_docs_page(path) and before.endswith("]("):
                    continue  # relative link target inside docs/
                problems.append(f"{path.as_posix()}:{no}: bare {PHYSICS_NAME}: {line.strip()[:100]}")
    assert not problems, _report(
        problems, f"references to {PHYSICS_NAME} without docs/ (use docs/{PHYSICS_NAME}#<anchor>)"
    )


def test_no_process_provenance_in_code_or_docs():
    problems = [
        f"{path.as_posix()}:{no}: {line.strip()[:100]}"
        for path, lines in _scanned()
        for no, line in enumerate(lines, 1)
        if PROVENANCE.search(line)
    ]
    assert not problems, _report(problems, "lines with process provenance (drop the author / work item)")


@pytest.mark.parametrize("anchor", ["numerical-limits-and-pitfalls", "time-step", "resolution"])
def test_physics_reference_has_the_core_sections(anchor):
    doc = Path("docs") / PHYSICS_NAME
    assert (ROOT / doc).is_file(), f"{doc.as_posix()} is missing"
    assert anchor in _anchors(doc), f"{doc.as_posix()} has no heading with the anchor #{anchor}"
