"""Files pyfold reads and writes: input paths that must be regular files, and
output files that appear complete or not at all.

:func:`regular_file` refuses what is not a regular file (a folder, a FIFO, a
device such as ``/dev/zero``) before anything opens it: opening a FIFO for reading
blocks until a writer comes, and reading a device never ends.

:func:`atomic_output` is the one way pyfold writes a secondary output (the XDMF
beside a run file, figures, ``results.nc``, summaries): the writer fills a
temporary file in the destination's folder, which is flushed to disk (fsync) and
renamed over the destination only when complete. A failed write (a full disk, a
quota, a folder that vanished) removes the temporary and raises
:class:`pyfold.errors.PyfoldError` naming the destination and the cause
(``No space left on device (ENOSPC)``): the destination keeps its earlier
content, or stays absent.
"""
from __future__ import annotations

import contextlib
import errno
import itertools
import os
import re
import stat
from pathlib import Path
from typing import Iterator

from pyfold.errors import InputError, PyfoldError

__all__ = ["regular_file", "read_bounded", "atomic_output", "fsync_file", "describe_os_error"]

#: Prefix of the temporaries :func:`atomic_output` leaves while it writes (hidden files)
TEMP_PREFIX = ".pyfold-tmp-"

_serial = itertools.count()

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def describe_os_error(exc: BaseException) -> str:
    """``strerror (ENAME)`` of an OSError (``No space left on device (ENOSPC)``), else its text.

    Libraries that wrap the C error sometimes drop ``errno``: HDF5's text carries
    ``errno = 28``, which is used; other texts are kept whole, a full disk named in
    them named again as ENOSPC."""
    code = getattr(exc, "errno", None)
    if isinstance(exc, OSError) and code in errno.errorcode:
        return f"{os.strerror(code)} ({errno.errorcode[code]})"  # not exc.strerror: h5py puts its whole text there
    text = str(exc) or type(exc).__name__
    found = re.search(r"errno = (\d+)", text)  # HDF5's "file write failed: ..., errno = 28, ..."
    if found and int(found.group(1)) in errno.errorcode:
        code = int(found.group(1))
        return f"{os.strerror(code)} ({errno.errorcode[code]})"
    if "No space left on device" in text and "ENOSPC" not in text:
        text += " (ENOSPC)"
    return text


def regular_file(path: str | Path, what: str) -> Path:
    """``path`` if it names an existing regular file (symbolic links followed), else
    :class:`InputError` (``what``: the argument or key, e.g. ``SCENE``) saying what it is.

    Only ``stat`` is called: nothing is opened, so a FIFO cannot block."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise InputError(f"{what}: no such file: {path}") from None
    except OSError as exc:
        raise InputError(f"{what}: cannot read {path}: {describe_os_error(exc)}") from None
    if not stat.S_ISREG(mode):
        raise InputError(f"{what}: {path} is {_kind(mode)}, not a regular file")
    return path


def read_bounded(path: str | Path, what: str, limit: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them.

    Opened without blocking (a FIFO put in place after a check cannot hang the read),
    checked to be a regular file on the open descriptor, then read with a bound: a
    file larger than ``limit`` bytes (or growing past it while read) is an
    :class:`InputError` stating the limit; so is anything that is not a regular file."""
    path = regular_file(path, what)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputError(f"{what}: cannot read {path}: {describe_os_error(exc)}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise InputError(f"{what}: {path} is {_kind(info.st_mode)}, not a regular file")
        if info.st_size > limit:
            raise InputError(f"{what}: {path} is {info.st_size} bytes; allowed: at most {limit} bytes")
        os.set_blocking(fd, True)
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > limit:
            raise InputError(f"{what}: {path} grew past {limit} bytes while read; allowed: at most {limit} bytes")
        return b"".join(chunks)
    except OSError as exc:
        raise InputError(f"{what}: cannot read {path}: {describe_os_error(exc)}") from None
    finally:
        os.close(fd)


def fsync_file(path: str | Path) -> None:
    """Flush a written file's data to disk (``fsync``): a full disk that the page cache
    hid so far fails here, before the file is renamed into place."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable; best effort (not every file system allows it)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Write ``path`` whole or not at all.

    Yields a temporary path in the same folder (same suffix, so writers that go by
    the suffix, such as ``savefig``, pick the right format) for the caller to write;
    when the block ends without an exception the temporary is fsynced and renamed to
    ``path`` (replacing an earlier file). On any exception the temporary is removed;
    an OSError (HDF5's and PIL's failed writes are OSErrors too) becomes a
    :class:`PyfoldError` ``cannot write PATH: CAUSE``; other exceptions (an
    interruption, a bug) pass unchanged.

    >>> with atomic_output("figure.png") as tmp:       # doctest: +SKIP
    ...     fig.savefig(tmp)
    """
    path = Path(path)
    folder = path.parent
    # short whatever the name: any destination name within NAME_MAX has a temporary within it too
    tmp = folder / f"{TEMP_PREFIX}{os.getpid()}-{next(_serial)}{path.suffix[:16]}"
    try:
        try:
            yield tmp
            fsync_file(tmp)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
    except OSError as exc:
        raise PyfoldError(f"cannot write {path}: {describe_os_error(exc)}") from None
    _fsync_folder(folder)
