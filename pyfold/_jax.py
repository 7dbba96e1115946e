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
"""
import os
from pathlib import Path

import jax

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

__all__ = ["jax", "jnp"]
