"""Checksums of run files, and their verification.

Every dataset of a run file (format_version >= 1.1) carries a checksum:

* the datasets ``pyfold run`` writes in Python (``/setup/*``, ``/setup/resolved/*``,
  ``/initial/*``) have a ``checksum`` attribute, the CRC-32 (:func:`zlib.crc32`) of
  their raw bytes as stored, then of their ``units`` and ``long_name`` attributes and
  their path (:func:`content_checksum`, the one place it is computed);
* the datasets ``fold_run`` writes at the root (results and dimension scales) are
  chunked with HDF5's Fletcher32 filter: h5py raises ``OSError`` when a chunk does not
  match its checksum, which :func:`verify_file` turns into the dataset's name; every
  chunk up to the complete entries must be found through the chunk index (a damaged
  index would read as fill values), and the dataset's name must be one of
  :data:`RESULT_NAMES` (a damaged link name);
* ``/checkpoint`` and ``/checkpoint_shadow`` carry their own ``checksum`` dataset,
  verified by ``fold_run --resume`` (fortran/io/fold_output.f90); they are not
  read by :func:`pyfold.run_results.open_run`.

Root attributes are covered by consistency, not by a checksum: ``format`` and
``format_version`` by :func:`pyfold.run_input.check_format` (and a 1.0 file whose
datasets carry checksums is refused), ``status`` must be ``ok``, ``running`` or
``failed...``, and a finished run (``status = "ok"``) must have ``records_complete``
/ ``snapshots_complete`` equal to the lengths of its records / snapshots and (when
``fold_run`` wrote it: ``records_complete`` present) ``steps_done`` equal to its
last record's ``step``.
Not covered: the text attributes ``creator``, ``created``, ``command``,
``fortran_creator``, ``mpi_ranks``, the ``units`` / ``long_name`` of the results
written by ``fold_run``, and the counts of a run that did not finish (a lowered
``records_complete`` there hides records, as a kill does).

Files of format_version 1.0 have no checksums: they are read as before, reported as
"no checksums: not verified".
"""
from __future__ import annotations

import contextlib
import contextvars
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from pyfold.errors import InputError

__all__ = [
    "CHECKSUM_ATTR",
    "CHECKSUM_SINCE",
    "SELF_CHECKED_GROUPS",
    "Damage",
    "DamagedRunError",
    "Integrity",
    "content_checksum",
    "dataset_checksum",
    "seal",
    "checked_read",
    "verify_file",
    "verify_path",
    "has_checksums",
    "tolerate_damage",
    "tolerating_damage",
    "refuse",
    "RESULT_NAMES",
]

#: Attribute holding the CRC-32 of a dataset written in Python.
CHECKSUM_ATTR = "checksum"
#: First format_version (major, minor) whose datasets all carry checksums.
CHECKSUM_SINCE = (1, 1)
#: Groups verified by their own checksum dataset (by ``fold_run --resume``), not here.
SELF_CHECKED_GROUPS = ("/checkpoint", "/checkpoint_shadow")
#: Groups whose datasets are written in Python and carry a ``checksum`` attribute.
PYTHON_GROUPS = ("/setup", "/initial")
#: Names of the datasets fold_run writes at the root (fortran/io/fold_output.f90: the
#: dimension scales, SCALAR_VARS, the tensors, STOKES_VARS and stress, LUBRICATION_VARS,
#: SNAPSHOT_VARS; tests/cli/test_run_damage.py checks this against that file).
RESULT_NAMES = frozenset((
    "time", "i", "j", "k", "l", "xyz", "family", "particle", "snapshot",
    "step", "n_corrections", "contact_iterations", "pairs_left", "capped_steps", "min_gap", "min_gap_over_alpha",
    "length_drift", "unit_norm_drift", "a2", "a4", "a2_family", "a4_family",
    "stokes_iterations", "stokes_residual", "rigidity_max", "rigidity_mean", "effective_viscosity", "stress",
    "lubricated_pairs", "lubrication_correction", "snapshot_time", "x", "p"))
#: Root attributes a finished run's counts are checked against its datasets with.
COUNT_ATTRS = {"time": "records_complete", "snapshot": "snapshots_complete"}


#: Set by :func:`tolerate_damage`: readers keep the intact part of a damaged run file.
_TOLERATE: contextvars.ContextVar[bool] = contextvars.ContextVar("pyfold_tolerate_damage", default=False)


@contextlib.contextmanager
def tolerate_damage(enabled: bool = True):
    """Within this block, :func:`pyfold.run_results.open_run` and :func:`pyfold.run_input.read_setup`
    read the intact part of a damaged run file (as with ``allow_damaged=True``) instead of
    refusing it: ``pyfold analyse --allow-damaged`` and ``pyfold report --allow-damaged``."""
    token = _TOLERATE.set(bool(enabled))
    try:
        yield
    finally:
        _TOLERATE.reset(token)


def tolerating_damage() -> bool:
    """True inside :func:`tolerate_damage`."""
    return _TOLERATE.get()


class DamagedRunError(InputError):
    """A run file with damaged datasets (checksum mismatch, unreadable data or metadata).

    ``damage`` lists what is damaged, each naming the dataset or attribute."""

    def __init__(self, message: str, damage: list[Damage]):
        super().__init__(message)
        self.damage = damage


@dataclass(frozen=True)
class Damage:
    """One damaged object: ``name`` is its HDF5 path (``/a2``, ``/setup/resolved/dt``,
    ``attribute records_complete``), ``cause`` says what is wrong. For a chunked dataset
    over ``time`` or ``snapshot`` whose chunks could be read one by one, ``first_bad`` is
    the first entry (along that dimension) of its first damaged chunk; None when the
    whole object is lost."""

    name: str
    cause: str
    first_bad: int | None = None

    def __str__(self) -> str:
        tail = f" (entries from {self.first_bad} on)" if self.first_bad is not None else ""
        return f"{self.name}: {self.cause}{tail}"


@dataclass
class Integrity:
    """Outcome of :func:`verify_file`."""

    #: The file carries checksums (format_version >= 1.1)
    checksummed: bool
    #: Datasets whose checksum was verified
    verified: int = 0
    damage: list[Damage] = field(default_factory=list)

    def summary(self) -> str:
        if self.damage:
            return "damaged: " + "; ".join(map(str, self.damage))
        if not self.checksummed:
            return "no checksums: not verified"
        return f"verified: {self.verified} datasets match their checksums"


def _text_bytes(value) -> bytes:
    if value is None:
        return b""
    if isinstance(value, bytes | np.bytes_):
        return bytes(value)
    if isinstance(value, np.ndarray) and value.shape == ():
        return _text_bytes(value[()])
    return str(value).encode("utf-8")


def content_checksum(raw: bytes, units=None, long_name=None, name: str = "") -> int:
    """CRC-32 of a dataset's raw bytes, then of a NUL and its ``units``, a NUL and its
    ``long_name`` (absent: empty), a NUL and its full path ``name`` (a damaged link name
    fails it too)."""
    crc = zlib.crc32(raw)
    for text in (units, long_name, name):
        crc = zlib.crc32(b"\0" + _text_bytes(text), crc)
    return crc


def _raw(ds: h5py.Dataset) -> np.ndarray:
    """The dataset's values in their stored type (fixed-length strings with their padding)."""
    arr = np.empty(ds.shape, dtype=ds.dtype)
    if arr.size:
        ds.read_direct(arr)
    return arr


#: Values read at a time when a result dataset is verified (blocks of whole entries)
READ_BLOCK = 1 << 23


def _read_all(ds: h5py.Dataset) -> None:
    """Read every value of a dataset (HDF5 checks each chunk's Fletcher32 checksum), in
    blocks of whole entries along the first axis of at most READ_BLOCK values."""
    if ds.ndim == 0 or ds.size == 0:
        _raw(ds)
        return
    per_entry = max(1, ds.size // ds.shape[0])
    rows = max(1, READ_BLOCK // per_entry)
    for start in range(0, ds.shape[0], rows):
        ds[start:start + rows]


def dataset_checksum(ds: h5py.Dataset) -> int:
    """:func:`content_checksum` of a dataset as stored in the file (variable-length
    strings: their UTF-8 bytes, NUL-separated)."""
    if ds.dtype.kind == "O":
        raw = b"\0".join(_text_bytes(v) for v in np.asarray(ds[()], dtype=object).reshape(-1))
    else:
        raw = _raw(ds).tobytes()
    return content_checksum(raw, ds.attrs.get("units"), ds.attrs.get("long_name"), ds.name)


def seal(ds: h5py.Dataset) -> None:
    """Set the ``checksum`` attribute of a dataset written in Python (after its
    ``units`` and ``long_name``)."""
    ds.attrs[CHECKSUM_ATTR] = np.uint32(dataset_checksum(ds))


def has_checksums(version: str) -> bool:
    """True for a format_version (``MAJOR.MINOR``) whose datasets carry checksums."""
    major, minor = (int(v) for v in version.split("."))
    return (major, minor) >= CHECKSUM_SINCE


def _cause(exc: BaseException, fletcher: bool = False) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    low = text.lower()
    # h5py reports a failed Fletcher32 check as "filter returned failure during read"
    if "fletcher" in low or "checksum" in low or (fletcher and "filter" in low):
        return f"data fails its Fletcher32 checksum ({text})"
    return f"cannot read ({text})"


def checked_read(ds: h5py.Dataset, required: bool):
    """Read a dataset written in Python and verify its ``checksum`` attribute.

    ``required``: the file's format carries checksums, so a missing attribute is damage.
    Returns the value as h5py reads it (``ds[()]``); raises :class:`DamagedRunError`
    naming the dataset."""
    name = ds.name
    try:
        stored = ds.attrs.get(CHECKSUM_ATTR)
        if stored is None:
            if required:
                raise DamagedRunError(f"{name}: damaged: its checksum attribute is missing",
                                      [Damage(name, "checksum attribute missing")])
        elif int(np.asarray(stored).reshape(-1)[0]) != dataset_checksum(ds):
            raise DamagedRunError(f"{name}: damaged: its content does not match its checksum",
                                  [Damage(name, "content does not match its checksum")])
        return ds[()]
    except DamagedRunError:
        raise
    except Exception as exc:  # noqa: BLE001 - damaged metadata raises anything
        raise DamagedRunError(f"{name}: damaged: {_cause(exc)}", [Damage(name, _cause(exc))]) from None


def _growing_dim(ds: h5py.Dataset) -> str | None:
    """``time`` / ``snapshot`` when the dataset's first axis is that dimension."""
    for dim in COUNT_ATTRS:
        if ds.name == "/" + dim:
            return dim
        try:
            scales = ds.dims[0] if ds.ndim else []
            if len(scales) and scales[0].name == "/" + dim:
                return dim
        except Exception:  # noqa: BLE001
            continue
    return None


def _first_bad_chunk(ds: h5py.Dataset) -> int | None:
    """First index along axis 0 of a chunked dataset whose chunk cannot be read."""
    if ds.chunks is None or ds.ndim == 0:
        return None
    step = ds.chunks[0]
    for start in range(0, ds.shape[0], step):
        try:
            ds[start:start + step]
        except Exception:  # noqa: BLE001
            return start
    return None


def _missing_chunk(ds: h5py.Dataset, whole: dict[str, int]) -> int | None:
    """First entry (along axis 0) of a chunk the dataset should have and whose entry in
    the chunk index is missing or misplaced (HDF5 would read it as fill values): every
    chunk of a dataset ``fold_run`` wrote is allocated, up to the ``whole`` entries of
    a growing dimension. None when all are there."""
    if ds.chunks is None or ds.ndim == 0 or ds.size == 0:
        return None
    dim = _growing_dim(ds)
    extent = list(ds.shape)
    if dim is not None and dim in whole:
        extent[0] = min(extent[0], whole[dim])
    counts = [-(-n // c) for n, c in zip(extent, ds.chunks)]
    if 0 in counts:
        return None
    for index in np.ndindex(*counts):
        try:  # looked up through the chunk index, as a read does
            found = len(ds.id.read_direct_chunk(tuple(i * c for i, c in zip(index, ds.chunks)))[1]) > 0
        except Exception:  # noqa: BLE001 - "chunk storage is not allocated"
            found = False
        if not found:
            return index[0] * ds.chunks[0]
    return None


def _check_dataset(ds: h5py.Dataset, checksummed: bool, report: Integrity, whole: dict[str, int]) -> None:
    name = ds.name
    python = name.startswith(tuple(g + "/" for g in PYTHON_GROUPS))
    try:
        limit = 2 * Path(ds.file.filename).stat().st_size + (1 << 20)
        if ds.size * ds.dtype.itemsize > limit:  # a damaged dataspace: do not allocate it
            report.damage.append(Damage(name, f"its shape {ds.shape} is larger than the file can hold "
                                              "(damaged dataspace)"))
            return
        if python:
            checked_read(ds, required=checksummed)
            report.verified += int(CHECKSUM_ATTR in ds.attrs)
            return
        fletcher = bool(ds.fletcher32)
        if checksummed and name.count("/") == 1 and name[1:] not in RESULT_NAMES:
            report.damage.append(Damage(name, "not a dataset fold_run writes (a damaged link name?)"))
            return
        if checksummed and not fletcher:
            report.damage.append(Damage(name, "no Fletcher32 checksum filter (a checksummed file has one on "
                                              "every result dataset)"))
            return
        problem = _dimension_problem(ds) if checksummed and name.count("/") == 1 else None
        if problem:
            report.damage.append(Damage(name, problem))
            return
        try:
            _read_all(ds)
        except Exception as exc:  # noqa: BLE001
            first = _first_bad_chunk(ds) if _growing_dim(ds) else None
            report.damage.append(Damage(name, _cause(exc, fletcher), first))
            return
        if fletcher:
            first = _missing_chunk(ds, whole)
            if first is not None:
                report.damage.append(Damage(name, "a chunk is missing from its chunk index (damaged index: it "
                                                  "would read as fill values)", first))
                return
        report.verified += int(fletcher)
    except DamagedRunError as exc:
        report.damage.extend(exc.damage)
    except Exception as exc:  # noqa: BLE001
        report.damage.append(Damage(name, _cause(exc)))


def _dimension_problem(ds: h5py.Dataset) -> str | None:
    """What is wrong with the dimension scales of a result dataset fold_run writes, or None: each axis
    carries exactly one scale, no scale twice, and a scale is as long as its axis (the growing time
    or snapshot axis excepted: a running run's readers may see it mid-record). The scale references
    are metadata no chunk checksum covers; a damaged one would make a reader lay the data out on
    the wrong dimensions (a2_family(time, i, i, j) instead of (time, family, i, j)) silently."""
    if ds.is_scale or ds.ndim == 0:
        return None
    names = []
    for axis, dim in enumerate(ds.dims):
        if len(dim) != 1:
            return f"axis {axis} has {len(dim)} dimension scales attached (one expected; damaged DIMENSION_LIST)"
        scale = dim[0]
        names.append(scale.name)
        grows = axis == 0 and scale.name.lstrip("/") in COUNT_ATTRS
        if not grows and scale.shape != (ds.shape[axis],):
            return (f"axis {axis} has length {ds.shape[axis]} but its dimension scale {scale.name} has shape "
                    f"{scale.shape} (damaged DIMENSION_LIST)")
    if len(set(names)) != len(names):
        return f"its dimension scales {names} name one twice (damaged DIMENSION_LIST)"
    return None


def _walk(group: h5py.Group, checksummed: bool, report: Integrity, whole: dict[str, int]) -> None:
    try:
        names = list(group.keys())
    except Exception as exc:  # noqa: BLE001
        report.damage.append(Damage(group.name or "/", f"cannot list the group ({_cause(exc)})"))
        return
    for key in names:
        path = (group.name.rstrip("/") + "/" + key) if group.name else "/" + key
        if path in SELF_CHECKED_GROUPS:
            continue
        try:
            obj = group[key]
        except Exception as exc:  # noqa: BLE001
            report.damage.append(Damage(path, _cause(exc)))
            continue
        if isinstance(obj, h5py.Group):
            _walk(obj, checksummed, report, whole)
        elif isinstance(obj, h5py.Dataset):
            _check_dataset(obj, checksummed, report, whole)


def _attr_int(f: h5py.File, name: str) -> int | None:
    value = f.attrs.get(name)
    if value is None:
        return None
    return int(np.asarray(value).reshape(-1)[0])


def _check_counts(f: h5py.File, report: Integrity) -> None:
    """Root attributes of a finished run against its datasets (see the module doc)."""
    status = f.attrs.get("status")
    if status is None:
        return
    text = _text_bytes(status).decode("utf-8", errors="replace").strip()
    if text not in ("ok", "running") and not text.startswith("failed"):
        report.damage.append(Damage("attribute status", f"{text!r} is none of ok, running, failed: ..."))
        return
    if text != "ok":
        return
    lost = {d.name for d in report.damage}
    for dim, attr in COUNT_ATTRS.items():
        count = _attr_int(f, attr)
        if count is None or "/" + dim in lost:
            continue
        lengths = {d.name: d.shape[0] for d in f.values()
                   if isinstance(d, h5py.Dataset) and d.name not in lost and _growing_dim(d) == dim}
        odd = sorted(n for n, length in lengths.items() if length != count)
        if odd:
            report.damage.append(Damage(f"attribute {attr}", f"= {count} in a finished run, but "
                                        + ", ".join(f"{n} has {lengths[n]}" for n in odd[:3])))
    steps = _attr_int(f, "steps_done")
    if _attr_int(f, COUNT_ATTRS["time"]) is None:
        return  # not laid out by fold_run (which always sets records_complete): no step counts to compare
    if steps is not None and "/step" not in lost and isinstance(f.get("step"), h5py.Dataset) and f["step"].shape[0]:
        last = int(f["step"][-1])
        if last != steps:
            report.damage.append(Damage("attribute steps_done", f"= {steps}, but the last record is of step {last}"))


def verify_file(f: h5py.File, version: str) -> Integrity:
    """Verify every dataset of an open run file (``version``: its format_version, from
    :func:`pyfold.run_input.check_format`): read it whole, compare its checksum, and
    check the root attributes (module doc). Never raises for damage: it is listed in
    the result."""
    checksummed = has_checksums(version)
    report = Integrity(checksummed=checksummed)
    if not checksummed:
        try:
            marked = any(CHECKSUM_ATTR in f[g][k].attrs for g in PYTHON_GROUPS if g in f for k in f[g]
                         if isinstance(f[g][k], h5py.Dataset))
        except Exception:  # noqa: BLE001
            marked = False
        if marked:
            report.checksummed = True
            report.damage.append(Damage("attribute format_version", f"= {version!r}, a format without checksums, "
                                        "but the datasets carry checksums"))
    whole = {}
    for dim, attr in COUNT_ATTRS.items():
        try:
            count = _attr_int(f, attr)
        except Exception:  # noqa: BLE001 - reported by _check_counts
            count = None
        if count is not None:
            whole[dim] = max(count, 0)
    _walk(f, report.checksummed, report, whole)
    try:
        _check_counts(f, report)
    except Exception as exc:  # noqa: BLE001
        report.damage.append(Damage("root attributes", _cause(exc)))
    return report


def verify_path(path: str | Path) -> Integrity:
    """:func:`verify_file` of a run file by path; raises :class:`InputError` when it is
    not a readable pyfold run file."""
    from pyfold.run_input import check_format

    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            version = check_format(f, path)
            return verify_file(f, version)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001
        held = held_by_writer(path, exc)
        if held is not None:
            raise held from None
        raise DamagedRunError(f"{path}: not a readable HDF5 file (damaged, or not a run file): "
                              f"{' '.join(str(exc).split())}", [Damage(str(path), "cannot open")]) from None


def held_by_writer(path: str | Path, exc: BaseException) -> InputError | None:
    """The error to raise when opening ``path`` for reading failed with ``exc`` because another
    process holds HDF5's exclusive file lock on it (a simulation still writing it): nothing is
    damaged, so the message names the holder instead; None for any other failure."""
    if "unable to lock file" not in " ".join(str(exc).split()):
        return None
    from pyfold.destination import open_elsewhere

    holder = open_elsewhere(Path(path)) or "another process"
    return InputError(f"{path}: open for writing by {holder} (HDF5's file lock; a simulation still running?): "
                      "read it once that process has ended")


def refuse(path: str | Path, report: Integrity, hint: str) -> None:
    """Raise :class:`DamagedRunError` listing the damage of ``report`` (nothing when intact)."""
    if report.damage:
        raise DamagedRunError(f"{path}: {report.summary()}; {hint}", report.damage)
