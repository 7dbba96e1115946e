"""The input part of an HDF5 run file, what ``pyfold run`` hands to ``fold_run``: its writer
(:func:`write_run_file`, :func:`write_setup`) and the reader of ``/setup`` (:func:`read_setup`,
:func:`check_format`). The results ``fold_run`` appends are read by :mod:`pyfold.run_results`.

Python writes the root attributes, ``/setup`` (the scene verbatim, the
normalised scene, and ``/setup/resolved``: every number Fortran needs, with
``units``) and ``/initial`` (the full initial particle state); ``fold_run``
appends the results at the root. Arrays are ``(n, dim)`` here, ``x(dim, n)`` in
Fortran. Strings are fixed-length UTF-8 (null-padded), which Fortran HDF5 reads
without variable-length machinery.

Since format_version 1.1 every dataset written here carries a ``checksum``
attribute (:mod:`pyfold.integrity`), and :func:`read_setup` verifies the ones it reads.
"""
from __future__ import annotations

import json
import re
import subprocess
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from pyfold import __version__
from pyfold.errors import InputError
from pyfold.integrity import DamagedRunError, checked_read, has_checksums, seal, tolerating_damage

if TYPE_CHECKING:  # only an annotation here: readers of run files need not load the scene schema
    from pyfold.scene import ResolvedScene

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "InitialState",
    "RunSetup",
    "creator",
    "write_run_file",
    "write_setup",
    "read_setup",
    "check_format",
    "fixed_string",
    "attr_text",
]

FORMAT = "pyfold.run"
#: 1.1: every dataset carries a checksum (pyfold.integrity); 1.0 files are read unverified.
FORMAT_VERSION = "1.1"


@dataclass(frozen=True)
class InitialState:
    """The initial particle state, ``(n, dim)`` arrays in family order."""

    x: np.ndarray
    p: np.ndarray
    shape: np.ndarray
    family: np.ndarray
    radius: np.ndarray
    length: np.ndarray
    xi: np.ndarray

    def check(self, dim: int) -> None:
        n = self.x.shape[0]
        for name in ("x", "p"):
            arr = getattr(self, name)
            if arr.shape != (n, dim) or not np.all(np.isfinite(arr)):
                raise InputError(f"initial.{name}: expected finite ({n}, {dim}) array, got shape {arr.shape}")
        for name in ("shape", "family", "radius", "length", "xi"):
            if getattr(self, name).shape != (n,):
                raise InputError(f"initial.{name}: expected shape ({n},), got {getattr(self, name).shape}")
        if not np.allclose(np.linalg.norm(self.p, axis=1), 1.0, rtol=0, atol=1e-12):
            raise InputError("initial.p: axes must be unit vectors")


@dataclass(frozen=True)
class RunSetup:
    """What ``/setup`` holds, read back."""

    scene_toml: str
    scene: dict
    resolved: dict


def _git_describe() -> str:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "-C", str(here), "describe", "--always", "--dirty", "--abbrev=12"],
                             capture_output=True, text=True, timeout=5, check=True)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def creator() -> str:
    """``"pyfold <version> (<git describe>)"``."""
    return f"pyfold {__version__} ({_git_describe()})"


def fixed_string(text: str) -> np.ndarray:
    """A scalar fixed-length UTF-8 string (length >= 1, as HDF5 requires)."""
    data = text.encode("utf-8")
    return np.array(data, dtype=h5py.string_dtype("utf-8", max(1, len(data))))


def _fixed_strings(texts: list[str]) -> np.ndarray:
    data = [t.encode("utf-8") for t in texts]
    return np.array(data, dtype=h5py.string_dtype("utf-8", max([1, *map(len, data)])))


def _dataset(group: h5py.Group, name: str, value, units: str, long_name: str) -> None:
    if isinstance(value, str):
        ds = group.create_dataset(name, data=fixed_string(value))
    elif isinstance(value, list) and all(isinstance(v, str) for v in value):
        ds = group.create_dataset(name, data=_fixed_strings(value))
    else:
        ds = group.create_dataset(name, data=value)
    if units:
        ds.attrs["units"] = fixed_string(units)
    ds.attrs["long_name"] = fixed_string(long_name)
    seal(ds)


def write_run_file(path: str | Path, resolved: ResolvedScene, initial: InitialState, command: str) -> None:
    """Write a new run file with the root attributes, ``/setup`` and ``/initial``.

    Parameters
    ----------
    path : path
        File to create (truncated if it exists: the caller decides about overwriting).
    resolved : ResolvedScene
        The validated scene (``resolved.toml`` is stored verbatim).
    initial : InitialState
        The initial particle state, ``(n, dim)`` arrays.
    command : str
        The command line that made the file.
    """
    initial.check(resolved.dim)
    if initial.x.shape[0] != resolved.n_particles:
        raise InputError(f"initial: {initial.x.shape[0]} particles, the scene has {resolved.n_particles}")
    with h5py.File(path, "w", libver="earliest") as f:
        for key, value in (("format", FORMAT), ("format_version", FORMAT_VERSION), ("creator", creator()),
                           ("created", datetime.now(timezone.utc).isoformat(timespec="seconds")),
                           ("command", command)):
            f.attrs[key] = fixed_string(value)
        write_setup(f, resolved)
        init = f.create_group("initial")
        for name, units, long_name, dtype in (
            ("x", "m", "particle centres", np.float64), ("p", "1", "particle unit axes", np.float64),
            ("shape", "1", "shape code: 1 fibre, 2 sphere, 3 spheroid", np.int32),
            ("family", "1", "family index (0-based)", np.int32), ("radius", "m", "radius", np.float64),
            ("length", "m", "fibre length, spheroid major axis, 2R for spheres", np.float64),
            ("xi", "1", "Jeffery shape factor", np.float64),
        ):
            _dataset(init, name, np.ascontiguousarray(getattr(initial, name), dtype=dtype), units, long_name)


def write_setup(f: h5py.File, resolved: ResolvedScene) -> None:
    """Create ``/setup`` in ``f``: the scene verbatim, the normalised scene and
    ``/setup/resolved``, every dataset sealed with its checksum."""
    setup = f.create_group("setup")
    seal(setup.create_dataset("scene_toml", data=fixed_string(resolved.toml)))
    seal(setup.create_dataset("scene_json", data=fixed_string(resolved.scene_json())))
    res = setup.create_group("resolved")
    for name, (value, units, long_name) in resolved.resolved_datasets().items():
        _dataset(res, name, value, units, long_name)


def attr_text(value) -> str:
    """An HDF5 attribute or scalar dataset value as ``str``: bytes decoded as UTF-8 (an
    invalid byte becomes U+FFFD, so a damaged text is reported, not raised on), a 0-d
    array by its element."""
    if isinstance(value, bytes | np.bytes_):
        return bytes(value).decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray) and value.shape == ():
        return attr_text(value[()])
    return str(value)


def check_format(f: h5py.File, path: str | Path) -> str:
    """Refuse a file that is not a pyfold run file or has an unknown major version."""
    fmt = attr_text(f.attrs.get("format", b""))
    version = attr_text(f.attrs.get("format_version", b""))
    if fmt != FORMAT:
        raise InputError(f"{path}: not a pyfold run file (format attribute {fmt!r}, expected {FORMAT!r})")
    if not re.fullmatch(r"[0-9]+\.[0-9]+", version):
        raise InputError(f"{path}: run file format_version {version!r} is not of the form MAJOR.MINOR "
                         f"(this pyfold writes {FORMAT_VERSION})")
    if version.split(".")[0] != FORMAT_VERSION.split(".")[0]:
        raise InputError(f"{path}: run file format_version {version!r}; this pyfold reads "
                         f"{FORMAT_VERSION.split('.')[0]}.x")
    return version


def _setup_value(ds: h5py.Dataset, required: bool):
    """A /setup dataset's value, its checksum verified (strings as ``str`` / list of ``str``)."""
    value = checked_read(ds, required)
    if h5py.check_string_dtype(ds.dtype) is not None:
        value = ds.asstr()[()]
        value = value.tolist() if isinstance(value, np.ndarray) else str(value)
    return value


class ResolvedValues(dict):
    """``/setup/resolved`` as read, without the damaged datasets a tolerant reader left
    out: looking one of those up raises :class:`DamagedRunError` naming it."""

    def __init__(self, values: dict, damaged: dict[str, DamagedRunError]):
        super().__init__(values)
        self.damaged = damaged

    def __missing__(self, key):
        if key in self.damaged:
            raise self.damaged[key]
        raise KeyError(key)


def read_setup(path: str | Path, allow_damaged: bool | None = None) -> RunSetup:
    """Read ``/setup`` back: the scene verbatim, the normalised scene, the resolved values.

    Each dataset's checksum is verified (format_version >= 1.1): a damaged one raises
    :class:`pyfold.integrity.DamagedRunError` (an InputError) naming it, unless
    ``allow_damaged`` (default: inside :func:`pyfold.integrity.tolerate_damage`): then
    it is left out (looking it up in ``resolved`` raises that error; a damaged
    ``scene_toml`` / ``scene_json`` reads as empty)."""
    tolerant = tolerating_damage() if allow_damaged is None else allow_damaged
    damaged: dict[str, DamagedRunError] = {}

    def value(ds: h5py.Dataset, key: str, empty=None):
        try:
            return _setup_value(ds, required)
        except DamagedRunError as exc:
            if not tolerant:
                raise
            damaged[key] = exc
            return empty

    with h5py.File(path, "r") as f:
        required = has_checksums(check_format(f, path))
        setup = f["setup"]
        resolved = {}
        for name, ds in setup["resolved"].items():
            v = value(ds, name)
            if name not in damaged:
                resolved[name] = v
        scene_toml = value(setup["scene_toml"], "scene_toml", "")
        scene_json = value(setup["scene_json"], "scene_json", "")
        return RunSetup(scene_toml=scene_toml, scene=json.loads(scene_json) if scene_json else {},
                        resolved=ResolvedValues(resolved, damaged))
