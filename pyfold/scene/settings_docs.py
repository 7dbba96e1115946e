"""The docs/scenes.md tables made from the settings registry (standard library only).

``scripts/generate_settings`` writes them between ``<!-- settings:<name> -->`` and
``<!-- /settings -->``; tests/micro/test_settings_registry.py fails when they are stale.
"""
from __future__ import annotations

from types import ModuleType


def _number(x: float | int) -> str:
    if isinstance(x, int) and abs(x) >= 10_000:
        return f"{x:.0e}".replace("e+0", "e").replace("e+", "e") if x % 10 ** (len(str(x)) - 1) == 0 else str(x)
    return f"{x:g}".replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def _range(s) -> str:
    if s.kind == "choice":
        return ", ".join(f'`"{w}"`' + (f" ({s.codes[w]})" if w in s.codes else "") for w in s.choices)
    if s.kind == "bool":
        return "bool (0, 1)"
    if s.path == "model.alpha":  # the upper bound depends on the particles (pyfold.scene.normalise)
        return "real in [0, smallest particle radius]"
    if s.kind == "integer" and s.values:
        return " or ".join(map(str, s.values))
    if s.kind == "text":
        lo, hi = s.size or (None, None)
        chars = f"{lo or 0} to {hi} characters" if hi is not None else f"at least {lo or 0} characters"
        return f"text, {chars}" + (f" matching `{s.pattern}`" if s.pattern else "")
    lo = "−∞" if s.lo is None else _number(s.lo)
    hi = "∞" if s.hi is None else _number(s.hi)
    interval = f"{'(' if s.lo_open or s.lo is None else '['}{lo}, {hi}{')' if s.hi_open or s.hi is None else ']'}"
    if s.kind == "vector":
        return f"{_count(s.size)} reals in {interval}"
    if s.kind == "matrix":
        rows = f"{_count(s.rows)} rows" if s.rows else "rows"
        return f"{rows} of {_count(s.size)} reals in {interval}" + (", or a .csv / .npy file" if s.file else "")
    return f"{s.kind} in {interval}"


def _count(size: tuple[int | None, int | None]) -> str:
    """``2-3``: the fewest and most entries."""
    lo, hi = size
    return str(lo) if lo == hi else f"{lo}-{hi}"


def _default(s) -> str:
    if s.default is None:
        return s.default_text or "required"
    if isinstance(s.default, bool):
        return "true" if s.default else "false"
    if isinstance(s.default, str):
        return f'`"{s.default}"`'
    return _number(s.default)


def settings_table(registry: ModuleType) -> str:
    """Every registered setting: range or words (with their codes), default, units, physics
    and the /setup/resolved dataset fold_run reads it from."""
    rows = ["| key | range / words (code) | default | units | used by | `/setup/resolved` |", "|---|---|---|---|---|---|"]
    for s in registry.SETTINGS:
        dataset = f"`{s.resolved}`" + (" (optional)" if s.optional else "") if s.resolved else ""
        rows.append(f"| `{s.path}` | {_range(s)} | {_default(s)} | {s.units} | {s.physics} | {dataset} |")
    return "\n".join(rows) + "\n"


def backends_table(registry: ModuleType) -> str:
    """What each Stokes backend can do (the capability table the checks ask)."""
    rows = ["| backend (code) | walls | Lees–Edwards lattice | deforming lattice | FFT precisions | MPI | rigidity |",
            "|---|---|---|---|---|---|---|"]
    yes = {True: "yes", False: "no"}
    for b in registry.BACKENDS.values():
        rows.append(f"| `{b.name}` ({b.code}) | {yes[b.walls]} | {yes[b.lees_edwards]} | {yes[b.deforming_lattice]} | "
                    f"{', '.join(b.fft_precisions) or '—'} | {yes[b.mpi]} | {', '.join(b.rigidities)} |")
    return "\n".join(rows) + "\n"


def docs_tables(registry: ModuleType) -> dict[str, str]:
    """Name of a marked table in docs/scenes.md -> its text."""
    return {"reference": settings_table(registry), "backends": backends_table(registry)}
