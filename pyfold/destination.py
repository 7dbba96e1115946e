"""Safe destinations: an exclusive lock per output, name limits, links, input != output.

A command that writes a destination (``pyfold run -o OUT.h5``, ``pyfold report --out
DIR``, ``pyfold main --out DIR``) first takes :func:`acquire` on it: an exclusive
``flock`` on the lock file ``OUT.h5.lock`` (``DIR.lock``) beside it, held for the
command's life, with the holder's pid, host, start time and command written in it.
A second writer of the same destination is refused at once (:class:`~pyfold.errors.InputError`,
exit 2) with the holder named. The kernel releases the lock when the last process
holding the locked file descriptor ends: a killed pyfold leaves no stale lock, and
a child given the descriptor (``fold_run`` / ``mpirun`` through ``pass_fds``) keeps
the destination locked as long as it may still write it. The holder removes its
lock file on release (a leftover one from a killed holder is harmless: it is
locked afresh); a lock file is never removed by a process that does not hold it.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from pathlib import Path

from pyfold.errors import InputError

#: Suffix of the lock file beside a destination (``OUT.h5.lock``, ``DIR.lock``).
LOCK_SUFFIX = ".lock"
#: Seconds a refused writer waits for the holder to have written its pid and host.
HOLDER_INFO_WAIT = 1.0
#: Attempts to lock a lock file that its holder removes meanwhile (each one a few system calls).
LOCK_ATTEMPTS = 50
#: Errors of ``flock`` meaning "this file system has no locks" (the command then runs unlocked, with a warning).
NO_LOCKS = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL)


def lock_path(target: Path) -> Path:
    """The lock file of a destination: ``target`` + :data:`LOCK_SUFFIX`, beside it."""
    target = Path(os.path.abspath(target))
    if not target.name:  # the root folder
        return target / ("pyfold" + LOCK_SUFFIX)
    return target.with_name(target.name + LOCK_SUFFIX)


def name_limit(folder: Path) -> int:
    """NAME_MAX of ``folder``'s file system (bytes of one file name)."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError):  # pragma: no cover - no pathconf: the common Linux value
        return 255


def check_name_length(target: Path, suffixes: tuple[str, ...], option: str) -> None:
    """Refuse a destination whose name, with the longest of ``suffixes`` that the
    command adds, exceeds NAME_MAX of its folder (or whose path exceeds PATH_MAX)."""
    target = Path(target)
    folder = target.parent
    longest = max(suffixes, key=len, default="")
    limit = name_limit(folder)
    size = len(os.fsencode(target.name + longest))
    if size > limit:
        raise InputError(f"{option}: the file name {target.name[:40]}... is too long: {size} bytes with the "
                         f"{longest!r} the command adds beside it, beyond the limit of {limit} bytes (NAME_MAX) of "
                         f"the folder {folder}; choose a name of at most {limit - len(os.fsencode(longest))} bytes")
    try:
        path_limit = int(os.pathconf(folder, "PC_PATH_MAX"))
    except (OSError, ValueError):  # pragma: no cover
        return
    size = len(os.fsencode(os.path.abspath(target) + longest))
    if size >= path_limit:
        raise InputError(f"{option}: the path of {target.name[:40]}... is too long: {size} bytes with "
                         f"{longest!r}, beyond the limit of {path_limit} bytes (PATH_MAX)")


def same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` are one file: equal resolved paths, or (both existing)
    the same device and inode, so also through symbolic and hard links."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def refuse_input_as_output(source: Path, outputs: tuple[Path, ...], option: str, source_label: str) -> None:
    """Refuse (exit 2) when one of ``outputs`` is the input file ``source`` itself."""
    for out in outputs:
        if same_file(out, source):
            how = ""
            if os.path.islink(out):
                how = f" (a link to {os.path.realpath(out)})"
            elif os.path.realpath(out) != os.path.realpath(source):
                how = " (a hard link to it)"
            raise InputError(f"{option}: {out}{how} is the {source_label} {source} itself; a command never writes "
                             f"over its input: choose another {option}")


def _holder_text(fd: int) -> str:
    """The holder's record in a lock file. Waits up to :data:`HOLDER_INFO_WAIT` for
    it to appear, and for a record of an ended process on this host to be replaced
    (a new holder writes its record just after taking the lock)."""
    deadline = time.monotonic() + HOLDER_INFO_WAIT
    while True:
        try:
            text = os.pread(fd, 4096, 0).decode("utf-8", errors="replace").strip()
        except OSError:
            text = ""
        if time.monotonic() >= deadline or (text and not _ended_here(text)):
            return text
        time.sleep(0.02)


def _ended_here(text: str) -> bool:
    """Whether a lock file's record names a process of this host that has ended."""
    try:
        info = json.loads(text)
        return str(info["host"]) == socket.gethostname() and not _alive(int(info["pid"]))
    except (ValueError, KeyError, TypeError):
        return False


def describe_holder(text: str) -> str:
    """``pid N on host H, since T (command)`` from a lock file's record, saying when that
    process has ended but a child of it still holds the lock."""
    try:
        info = json.loads(text)
        pid, host = int(info["pid"]), str(info["host"])
    except (ValueError, KeyError, TypeError):
        return "another process (it has not recorded its pid yet)"
    words = f"pid {pid} on host {host}"
    if info.get("started"):
        words += f", since {info['started']}"
    if info.get("command"):
        words += f" ({info['command']})"
    if _ended_here(text):
        words += ("; that process has ended, but a process it started (fold_run, mpirun) still holds the lock "
                  "and may still write: wait for it to end, or end it")
    return words


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - another user's process
        return True
    return True


class DestinationLock:
    """An exclusive lock held on a destination; :meth:`release` (or leaving the
    ``with`` block) removes the lock file and drops the lock."""

    def __init__(self, target: Path, path: Path, fd: int | None):
        self.target = target
        self.path = path
        self._fd = fd

    @property
    def fd(self) -> int | None:
        """The locked file descriptor (give it to child processes that write the
        destination, ``pass_fds``); None when the file system has no locks."""
        return self._fd

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:  # remove the lock file only while holding it, and only if it is still ours
            held, current = os.fstat(fd), os.lstat(self.path)
            if (held.st_dev, held.st_ino) == (current.st_dev, current.st_ino):
                os.unlink(self.path)
        except OSError:
            pass
        finally:
            os.close(fd)

    def __enter__(self) -> DestinationLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def make_parent(target: Path, option: str) -> None:
    """Create the folder that holds ``target`` (and so its lock file), with its parents."""
    parent = Path(os.path.abspath(target)).parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option}: cannot create the folder {parent} for {target}: {exc.strerror or exc}") from None


def acquire(target: Path, option: str, command: str = "") -> DestinationLock:
    """Take the exclusive lock of the destination ``target`` (before anything is written).

    Refused with :class:`~pyfold.errors.InputError` naming ``option``: another process
    holds it (its pid, host, start time and command in the message), or the lock file
    cannot be made (a link, a folder, an unwritable place). On a file system without
    locks the command runs unlocked, with a warning on stderr.
    """
    import sys

    target = Path(target)
    path = lock_path(target)
    absolute = Path(os.path.abspath(target))
    if absolute.name:
        check_name_length(absolute, (LOCK_SUFFIX,), option)
    record = json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                         "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "command": command})
    for _ in range(LOCK_ATTEMPTS):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise InputError(f"{option}: the lock file {path} is a symbolic link (to {os.path.realpath(path)}); "
                                 "pyfold locks only a regular file there: remove the link") from None
            raise InputError(f"{option}: cannot create the lock file {path} beside {target}: "
                             f"{exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = describe_holder(_holder_text(fd))
            os.close(fd)
            raise InputError(f"{option}: {target} is being written by another process: {holder} (lock file {path}); "
                             f"wait for it to end, or choose another {option}") from None
        except OSError as exc:
            os.close(fd)
            if exc.errno in NO_LOCKS:
                print(f"pyfold: warning: {option}: the file system of {path} has no file locks ({exc.strerror}); "
                      "writing unlocked: do not start a second command on the same destination", file=sys.stderr)
                return DestinationLock(target, path, None)
            raise InputError(f"{option}: cannot lock {path}: {exc.strerror or exc}") from None
        held = os.fstat(fd)
        try:
            current = os.lstat(path)
        except FileNotFoundError:
            current = None
        if current is None or (current.st_dev, current.st_ino) != (held.st_dev, held.st_ino):
            os.close(fd)  # its holder removed that lock file just before we locked it: lock the new one
            continue
        try:  # the holder's description is for messages only: the flock is the lock
            os.ftruncate(fd, 0)
            os.pwrite(fd, (record + "\n").encode(), 0)
        except OSError:  # e.g. a full disk: the command's own writes report it
            pass
        return DestinationLock(target, path, fd)
    raise InputError(f"{option}: could not lock {path}: its holders kept replacing it")  # pragma: no cover


def file_lock_holders(path: Path) -> list[int]:
    """Pids holding a ``flock``/``fcntl`` lock on ``path`` (Linux ``/proc/locks``; [] elsewhere)."""
    try:
        st = os.stat(path)
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return []
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    pids = []
    for line in lines:
        fields = line.split()
        if len(fields) >= 6 and fields[5] == key and fields[4].lstrip("-").isdigit():
            pids.append(int(fields[4]))
    return sorted(set(p for p in pids if p > 0))


def process_name(pid: int) -> str:
    """``pid N (name)`` from /proc, or ``pid N``."""
    try:
        name = Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return f"pid {pid}"
    return f"pid {pid} ({name})"


def open_elsewhere(path: Path) -> str | None:
    """When another process holds ``path`` open under HDF5's file lock (a reader:
    ``h5py.File(path, "r")``, an xarray dataset not yet closed), a description of
    it (pids when known); None when the file can be locked for writing."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        pids = [p for p in file_lock_holders(path) if p != os.getpid()]
        return ", ".join(process_name(p) for p in pids) if pids else "another process"
    except OSError:  # no locks on this file system: nothing to detect
        return None
    finally:
        os.close(fd)  # drops a lock taken just now
    return None
