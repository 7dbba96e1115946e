"""The initial particle state of a resolved scene, from the Fortran placement kernel.

``fold_placement`` (``fortran/particles/fold_placement.f90``) draws the
axes (given, isotropic, or uniform in a plane) and places the centres by random
sequential addition, then, for dense targets, relaxation sweeps that push
overlapping pairs apart, so every surface gap is >= alpha (alpha/2 to walls). It
is seeded: the same scene gives the same initial state, so the run file holds
the full initial state and a run is reproducible from the scene's seed.
Families with given ``positions`` skip the kernel: the state is exactly the given one
(validation checked its gaps; mixing given and random families is refused there).

The kernel is one uninterruptible native call (it holds the GIL, and it cannot
be resumed: every call starts again from the seed), and a dense target can keep it
busy for minutes. :func:`initial_state` therefore runs it in a forked child
process (POSIX) with the very same arguments, so the result is bit for bit the
one of a direct call, while the parent shows the kernel's progress on stderr
(``PLACEMENT`` lines: particles tried and placed, the fraction reached, then the
relaxation sweeps and the overlap left; at most once a second, after the first
second) and stays responsive: KeyboardInterrupt (Ctrl-C) or any other exception
(``pyfold.cli`` turns SIGTERM and SIGHUP into one) kills the child at once and
propagates. Nothing is written before the placement ends. A hopeless target
fails early: the kernel stops relaxation sweeps that stall (see
``fortran/particles/fold_placement.f90``), and the error names the scene key.
"""
from __future__ import annotations

import ctypes
import os
import pickle
import select
import signal
import sys
import time
import warnings
from typing import Callable, TextIO

import numpy as np

from pyfold.native.geometry import ORIENT_GIVEN, ORIENT_ISOTROPIC, ORIENT_PLANAR
from pyfold.errors import InputError, PyfoldError
from pyfold.run_input import InitialState
from pyfold.scene.normalise import ResolvedScene

#: Random positions tried per particle before it is left to the relaxation sweeps.
MAX_ATTEMPTS = 2000
#: Relaxation sweeps allowed to remove the overlaps RSA could not avoid.
RELAX_SWEEPS = 5000
#: Seconds between progress lines of a long placement (the first after as long).
PROGRESS_EVERY = 1.0
#: Environment variable that makes the placement kernel print PLACEMENT progress lines.
PROGRESS_ENV = "PYFOLD_PLACEMENT_PROGRESS"


def particle_arrays(resolved: ResolvedScene) -> dict[str, np.ndarray]:
    """Per-particle ``shape``, ``family``, ``radius``, ``length``, ``xi`` (in family order),
    and the placement kernel's ``orient_mode`` and ``axis`` ``(n, dim)``."""
    fams, dim = resolved.families, resolved.dim
    counts = [f.count for f in fams]
    modes, axes = [], []
    for f in fams:
        if f.positions is not None:  # given positions: the axes are fixed already (given or drawn by normalise)
            modes.append(np.full(f.count, ORIENT_GIVEN))
            axes.append(np.broadcast_to(f.axes, (f.count, dim)))
        elif f.orientation == "isotropic" or (f.orientation == "planar_random" and dim == 2):
            modes.append(np.full(f.count, ORIENT_ISOTROPIC))
            axes.append(np.zeros((f.count, dim)))
        elif f.orientation == "planar_random":  # uniform in the x-y plane: the plane normal to z
            modes.append(np.full(f.count, ORIENT_PLANAR))
            axes.append(np.tile([0.0, 0.0, 1.0], (f.count, 1)))
        else:  # aligned (one axis for all) or given (one each), already normalised
            modes.append(np.full(f.count, ORIENT_GIVEN))
            axes.append(np.broadcast_to(f.axes, (f.count, dim)))
    return {
        "shape": np.repeat([f.shape_code for f in fams], counts).astype(np.int32),
        "family": np.repeat([f.index for f in fams], counts).astype(np.int32),
        "radius": np.repeat([f.radius for f in fams], counts).astype(np.float64),
        "length": np.repeat([f.length for f in fams], counts).astype(np.float64),
        "xi": np.repeat([f.xi for f in fams], counts).astype(np.float64),
        "orient_mode": np.concatenate(modes).astype(np.int32),
        "axis": np.concatenate(axes).astype(np.float64),
    }


def initial_state(resolved: ResolvedScene, progress: TextIO | None = None) -> InitialState:
    """Draw the axes and place the centres without overlap (gaps >= alpha).

    The kernel runs in a child process (see the module docstring); ``progress``
    (default ``sys.stderr``) receives a line at most every :data:`PROGRESS_EVERY`
    seconds while it works.

    Raises
    ------
    InputError
        The kernel could not reach the scene's volume fraction: the message names
        ``particles[k].volume_fraction`` (or ``.count``), the fraction random
        sequential addition reached and what to change.
    KeyboardInterrupt
        Interrupted (the child is killed first; nothing is left behind).
    PyfoldError
        The native extension is not built, or the child died.
    """
    a = particle_arrays(resolved)
    fams = resolved.families
    if fams and all(f.positions is not None for f in fams):
        # given positions (and axes, given or drawn by the family's rule in normalise, whose
        # gaps validation checked): no placement, the state exactly as given
        x = np.concatenate([np.asarray(f.positions, dtype=np.float64) for f in fams])
        p = np.ascontiguousarray(a["axis"], dtype=np.float64)
        return InitialState(x=x, p=p, shape=a["shape"], family=a["family"], radius=a["radius"],
                            length=a["length"], xi=a["xi"])

    from pyfold.native import load
    from pyfold.native.geometry import Cell, place_particles

    load("_fold_geometry")  # imported before the fork: the child imports nothing
    # the full gradient: a non-shear flow places in its deforming lattice at t = 0
    cell = Cell(tuple(resolved.cell_lengths[: resolved.dim]), walls=resolved.walls,
                velocity_gradient=resolved.velocity_gradient)

    def place():
        return place_particles(cell, a["shape"], a["radius"], a["length"], alpha=resolved.alpha, seed=resolved.seed,
                               orientation=a["orient_mode"], axis=a["axis"], max_attempts=MAX_ATTEMPTS,
                               relax_sweeps=RELAX_SWEEPS)

    phi = sum(f.volume_fraction for f in fams)
    what = (f"{resolved.n_particles} particles in {len(fams)} families" if len(fams) > 1
            else f"{fams[0].count} {fams[0].shape}s" if fams else "no particles")
    try:
        placed = run_interruptibly(place, f"placement of {what} (volume fraction {phi:.4g})", progress)
    except InputError as exc:
        raise InputError(_placement_failure(resolved, str(exc))) from None
    return InitialState(x=placed.x, p=placed.p, shape=a["shape"], family=a["family"], radius=a["radius"],
                        length=a["length"], xi=a["xi"])


def _placement_failure(resolved: ResolvedScene, message: str) -> str:
    """The kernel's failure message (it gives the fraction reached) under the scene keys
    that set the fraction, with a hint."""
    keys = []
    for f in resolved.families:
        given = resolved.scene.particles[f.index]
        keys.append(f"particles[{f.index}].{'count' if getattr(given, 'count', None) is not None else 'volume_fraction'}")
    text = message.removeprefix("placement: ").rstrip(". ")
    return (f"{', '.join(keys) or 'particles'}: the random placement failed: {text}. Hint: lower the volume "
            f"fraction (or count) or model.alpha ({resolved.alpha:g}): particles placed at random jam below the "
            "packing limit the validation allows, the more so the longer they are")


def _describe_kernel_progress(line: str) -> str | None:
    """A ``PLACEMENT ...`` line of the kernel (``fold_placement.f90``) as text, or None."""
    f = line.split()
    try:
        if len(f) == 7 and f[1] == "rsa":
            return (f"random sequential addition: {int(f[2])} of {int(f[3])} particles tried, {int(f[4])} placed, "
                    f"volume fraction reached {float(f[5]):.4f} of {float(f[6]):.4f}")
        if len(f) == 6 and f[1] == "relax":
            return (f"relaxation sweep {int(f[2])} (at most {int(f[3])}): {int(f[4])} pairs still closer than "
                    f"alpha, total overlap {float(f[5]):.3g} m")
    except ValueError:
        pass
    return None


def run_interruptibly(call: Callable, what: str, progress: TextIO | None = None, every: float = PROGRESS_EVERY):
    """Return ``call()`` computed in a forked child, and keep the parent responsive.

    The child runs with ``PYFOLD_PLACEMENT_PROGRESS=1`` and its stderr captured: the
    placement kernel's ``PLACEMENT`` lines (and any other line) are shown on
    ``progress`` (default stderr) as ``pyfold: <what>: <state>, <elapsed> s``, at
    most every ``every`` seconds and only after the first ``every`` seconds. Any
    exception in the parent (KeyboardInterrupt, a signal raised as an exception by
    :mod:`pyfold.cli`) kills the child at once (SIGKILL) and propagates; the child
    also dies with the parent. An exception of ``call`` that can be pickled (the
    pyfold errors) is re-raised in the parent. Without ``os.fork`` the call is made
    directly.
    """
    if not hasattr(os, "fork"):  # pragma: no cover - not POSIX
        return call()
    stream = progress if progress is not None else sys.stderr
    result_r, result_w = os.pipe()
    err_r, err_w = os.pipe()
    parent_pid = os.getpid()
    with warnings.catch_warnings():
        # JAX (imported with pyfold) warns at every fork; the child runs only the
        # native kernel, numpy and pickle, all imported already, and never JAX.
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
        pid = os.fork()
    if pid == 0:  # child: compute, send the pickled outcome, leave without any clean-up of the parent's
        status = 0
        try:
            os.close(result_r)
            os.close(err_r)
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # the parent decides, and kills us
                signal.signal(sig, signal.SIG_IGN)
            _die_with_parent(parent_pid)
            os.dup2(err_w, 2)
            os.close(err_w)
            os.environ[PROGRESS_ENV] = "1"
            try:
                outcome = ("ok", call())
            except BaseException as exc:  # noqa: BLE001 - sent to the parent
                outcome = ("error", exc)
            try:
                data = pickle.dumps(outcome)
            except Exception:  # noqa: BLE001 - an unpicklable exception
                data = pickle.dumps(("error", RuntimeError(f"{type(outcome[1]).__name__}: {outcome[1]}")))
            view = memoryview(data)
            while view:
                view = view[os.write(result_w, view):]
        except BaseException:  # noqa: BLE001
            status = 1
        finally:
            os._exit(status)
    os.close(result_w)
    os.close(err_w)
    chunks: list[bytes] = []
    err_buffer = b""
    state = "started"
    start = time.monotonic()
    next_report = start + every
    reported = False
    open_fds = {result_r, err_r}
    try:
        while result_r in open_fds:
            ready, _, _ = select.select(list(open_fds), [], [], min(0.1, every))
            for fd in ready:
                chunk = os.read(fd, 1 << 20)
                if not chunk:
                    open_fds.discard(fd)
                elif fd == result_r:
                    chunks.append(chunk)
                else:
                    err_buffer += chunk
                    *lines, err_buffer = err_buffer.split(b"\n")
                    for raw in lines:
                        line = raw.decode(errors="replace").strip()
                        text = _describe_kernel_progress(line) if line.startswith("PLACEMENT ") else None
                        if text is not None:
                            state = text
                        elif line:
                            print(line, file=stream, flush=True)
            now = time.monotonic()
            if now >= next_report:
                print(f"pyfold: {what}: {state}, {now - start:.0f} s (Ctrl-C stops it)", file=stream, flush=True)
                reported = True
                next_report = now + every
        _, wait_status = os.waitpid(pid, 0)
    except BaseException:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:  # pragma: no cover
            pass
        os.waitpid(pid, 0)
        raise
    finally:
        os.close(result_r)
        os.close(err_r)
    if not chunks:
        raise PyfoldError(f"{what}: the placement process died without a result (wait status {wait_status})")
    kind, value = pickle.loads(b"".join(chunks))
    if reported:
        print(f"pyfold: {what}: {'done' if kind == 'ok' else 'failed'} after {time.monotonic() - start:.1f} s",
              file=stream, flush=True)
    if kind == "ok":
        return value
    raise value


def _die_with_parent(parent_pid: int) -> None:
    """Linux: the child gets SIGKILL when the parent dies (even by SIGKILL)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        pass
    if os.getppid() != parent_pid:  # the parent died before prctl
        os._exit(1)
