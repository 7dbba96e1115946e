"""JAX set-up shared by the macro layer.

Imported first by every module that builds JAX arrays: orientation tensors are
integrated to rtol ~1e-8 and fitted to ~1e-6, which float32 cannot carry, so
64-bit mode is switched on before any array exists (JAX silently truncates to
float32 otherwise).

Compiled programs are kept in JAX's persistent compilation cache, a per-user
folder (``$PYFOLD_JAX_CACHE``, default ``$XDG_CACHE_HOME/pyfold/jax`` or
``~/.cache/pyfold/jax``): compiling a closure or an orientation solve costs seconds,
running it milliseconds, so every new process (the CLI, a study, the test suite)
would otherwise pay the compilation again. ``PYFOLD_JAX_CACHE=off`` disables it.
The cache key covers the program, the JAX/XLA versions and the backend, so a cached
program is the one a fresh compilation would produce.

The persistent cache still needs the program traced and lowered to find it (for the
RK4 fit of :mod:`pyfold.fast_fit` that is seconds of Python per process).
:func:`exported_call` skips both: the first call of a program on given argument shapes
exports it (``jax.export``: its StableHLO, serialised) into ``export/`` of the same
folder; a later process reads that file, and only the compilation (a hit in the
persistent cache) is left. The file's name is a hash of everything the program text
depends on: the name given, the versions of jax, jaxlib, equinox and numpy, the backend,
the x64 switch, the argument shapes and dtypes, and every source file of the
:mod:`pyfold` package. A file whose content does not verify (its SHA-256, the shapes
it declares, the platform) is ignored and written again: a damaged or foreign file
costs a new export, never a different program.
"""
import hashlib
import json
import os
import threading
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)


def _cache_dir() -> Path | None:
    explicit = os.environ.get("PYFOLD_JAX_CACHE", "")
    if explicit.lower() == "off":
        return None
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "pyfold" / "jax"


_CACHE = _cache_dir()
if _CACHE is not None:
    try:
        _CACHE.mkdir(parents=True, exist_ok=True)
    except OSError:  # read-only home: run without the cache
        _CACHE = None
if _CACHE is not None:
    jax.config.update("jax_compilation_cache_dir", str(_CACHE))
    # keep every program that took noticeable time to compile (default: 1 s)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)

import jax.numpy as jnp  # noqa: E402  (must follow the x64 switch)

__all__ = ["jax", "jnp", "exported_call"]

#: Export files kept per program name (argument shapes, versions and source states
#: together); beyond it the least recently used are removed when a new one is written, so
#: that editing the package or analysing runs of many size classes does not grow the
#: folder without bound.
MAX_EXPORTS_PER_NAME = 8
#: First line of an export file; the format of what follows it (bump on any change).
_EXPORT_MAGIC = b"pyfold-jax-export 1\n"
_SOURCE_DIGEST: str | None = None
_LOADED: dict[str, object] = {}


def _source_digest() -> str:
    """SHA-256 of every ``*.py`` file of the installed :mod:`pyfold` package (paths and
    contents): the traced program depends on the modules it calls, and listing those
    by hand would go stale; any edit of the package invalidates every export."""
    global _SOURCE_DIGEST
    if _SOURCE_DIGEST is None:
        root = Path(__file__).resolve().parent
        h = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root)).encode())
            h.update(b"\0")
            h.update(path.read_bytes())
            h.update(b"\0")
        _SOURCE_DIGEST = h.hexdigest()
    return _SOURCE_DIGEST


def _avals(args) -> tuple[list[tuple[tuple[int, ...], str]], object]:
    # the tree of (args, kwargs), as jax.export records it
    leaves, tree = jax.tree_util.tree_flatten((tuple(args), {}))
    return [(tuple(int(n) for n in np.shape(x)), str(np.result_type(x))) for x in leaves], tree


def _export_key(name: str, avals, tree) -> str:
    import equinox
    import jaxlib

    facts = {
        "format": _EXPORT_MAGIC.decode().strip(),
        "name": name,
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "equinox": equinox.__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
        "x64": bool(jax.config.jax_enable_x64),
        "matmul_precision": str(jax.config.jax_default_matmul_precision),
        "args": avals,
        "tree": str(tree),
        "source": _source_digest(),
    }
    return hashlib.sha256(json.dumps(facts, sort_keys=True).encode()).hexdigest()[:40]


def _read_export(path: Path, avals, tree):
    """The :class:`jax.export.Exported` in ``path``, or None if it is missing or does
    not verify (checksum, argument shapes and dtypes, tree, platform)."""
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    head = len(_EXPORT_MAGIC)
    if not blob.startswith(_EXPORT_MAGIC) or len(blob) < head + 65 or blob[head + 64:head + 65] != b"\n":
        return None
    payload = blob[head + 65:]
    if hashlib.sha256(payload).hexdigest().encode() != blob[head:head + 64]:
        return None
    try:
        exported = jax.export.deserialize(bytearray(payload))
    except Exception:  # a payload that verifies but does not parse (another jax): re-export
        return None
    declared = [(tuple(int(n) for n in a.shape), str(a.dtype)) for a in exported.in_avals]
    if declared != avals or str(exported.in_tree) != str(tree) or jax.default_backend() not in exported.platforms:
        return None
    return exported


def _write_export(path: Path, exported) -> None:
    payload = bytes(exported.serialize())
    blob = _EXPORT_MAGIC + hashlib.sha256(payload).hexdigest().encode() + b"\n" + payload
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(blob)
        os.replace(tmp, path)  # atomic: a concurrent reader sees the old file or the new one
    except OSError:  # a read-only or full cache folder: this process keeps its program
        tmp.unlink(missing_ok=True)
        return
    _prune(path)


def _prune(path: Path) -> None:
    """Remove the least recently used exports of the same program name beyond
    :data:`MAX_EXPORTS_PER_NAME` (a read marks a file used: :func:`exported_call`)."""
    name = path.name.rsplit("-", 1)[0]
    try:
        siblings = [p for p in path.parent.glob(f"{name}-*.jaxexport") if p.name.rsplit("-", 1)[0] == name]
        siblings.sort(key=lambda p: p.stat().st_mtime, reverse=True)
        for old in siblings[MAX_EXPORTS_PER_NAME:]:
            old.unlink(missing_ok=True)
    except OSError:  # a file removed meanwhile by another process
        pass


def _can_serialise() -> bool:
    """Whether this jax can (de)serialise exports: it needs the ``flatbuffers`` package."""
    try:
        import jax.export  # noqa: F401
        from jax._src.export import serialization  # noqa: F401  (raises ImportError without flatbuffers)
    except ImportError:
        return False
    return True


def exported_call(name: str, build, args: tuple):
    """``build()(*args)`` through a serialised export of the program (module notes).

    ``build`` returns the ``jax.jit`` function; it is called only when no valid export
    exists for ``name`` and the shapes and dtypes of ``args`` (a tuple of arrays, or of
    tuples of arrays). Without the persistent cache (``PYFOLD_JAX_CACHE=off``), or
    without the ``flatbuffers`` package that serialisation needs, the program is simply
    traced and run. Both ways run the same program text.
    """
    if _CACHE is None or not _can_serialise():
        return build()(*args)
    avals, tree = _avals(args)
    key = f"{name}-{_export_key(name, avals, tree)}"
    call = _LOADED.get(key)
    if call is None:
        path = _CACHE / "export" / f"{key}.jaxexport"
        exported = _read_export(path, avals, tree)
        if exported is not None:
            try:
                os.utime(path)  # used: kept by _prune
            except OSError:
                pass
        else:
            specs = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(np.shape(x), np.result_type(x)), args)
            exported = jax.export.export(build())(*specs)
            _write_export(path, exported)
        call = _LOADED[key] = jax.jit(exported.call)
    return call(*args)
