"""What to tell the user when a library cannot be loaded: usually not enough memory.

Kept free of third-party imports: it runs when numpy, JAX or OpenBLAS themselves
could not be loaded.
"""
from __future__ import annotations

import re

__all__ = ["describe_load_failure", "address_space_limit"]

#: Texts of loader and allocator failures that mean "out of (address-space) memory"
_NO_MEMORY = ("failed to map segment", "cannot allocate memory", "out of memory", "memory allocation",
              "cannot mmap", "cannot map", "errno 12", "enomem")


try:
    import resource
except ImportError:  # pragma: no cover - not POSIX
    resource = None


def address_space_limit() -> str:
    """The soft address-space limit as ``ulimit -v`` shows it (``400000 kB``), or ``unlimited``."""
    if resource is None:  # pragma: no cover
        return "unknown"
    try:
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (OSError, ValueError):  # pragma: no cover
        return "unknown"
    return "unlimited" if soft == resource.RLIM_INFINITY else f"{soft // 1024} kB"


def _chain(exc: BaseException) -> list[BaseException]:
    seen: list[BaseException] = []
    while exc is not None and exc not in seen:
        seen.append(exc)
        exc = exc.__cause__ or exc.__context__
    return seen


def _what(chain: list[BaseException]) -> str:
    """The module and shared library that failed to load (``jaxlib._jax (libjax_common.so)``)."""
    module = next((e.name for e in chain if isinstance(e, ImportError) and e.name), None)
    found = next((m.group(1) for m in (re.search(r"([\w.+-]+\.so[\w.]*)", str(e)) for e in chain) if m), None)
    if module and found:
        return f"{module} ({found})"
    return module or found or "a library"


def _module_loading(exc: BaseException) -> str | None:
    """The innermost module whose top level was running when ``exc`` was raised
    (a MemoryError while an import executes a module), if any."""
    name, tb = None, exc.__traceback__
    while tb is not None:
        frame = tb.tb_frame
        if frame.f_code.co_name == "<module>" and frame.f_globals.get("__name__") not in (None, "__main__"):
            name = frame.f_globals["__name__"]
        tb = tb.tb_next
    return name


def describe_load_failure(exc: BaseException) -> str:
    """One line (no traceback) for an ImportError or MemoryError met while loading pyfold's
    libraries (numpy, JAX, OpenBLAS, h5py, matplotlib, the native core)."""
    chain = _chain(exc)
    no_memory = any(isinstance(e, MemoryError) for e in chain) or any(
        getattr(e, "errno", None) == 12 or any(text in str(e).lower() for text in _NO_MEMORY) for e in chain)
    if no_memory:
        if any(isinstance(e, ImportError) for e in chain):
            what = _what(chain)
        else:
            what = next((m for m in map(_module_loading, chain) if m), None)
        return (f"not enough memory{' to load ' + what if what else ''}: raise the memory limit "
                f"(ulimit -v; now {address_space_limit()})")
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return f"cannot load {_what(chain)}: {first} (is the installation complete? see README.md)"
