"""An attempt killed without a chance to write its line still counts (pyfold.sweep.worker,
pyfold.sweep.store.attempts).

A worker renews its open attempt (``attempt.<host>.<pid>.open.json``) every ``--heartbeat``
seconds with its wall and CPU time so far, its children's included. SIGKILLed together with
its children (the process group, as when a machine is stopped), it leaves the open file;
once the file has not been renewed for ``STALE_BEATS`` intervals, the attempt is listed as
``killed`` with its last renewal's costs, so that the run's CPU time is not short by the
killed attempt's. The stand-in fold_run here only burns CPU, so its cost is known from its
own clock; a run that continued a donor and was killed says so in ``pyfold sweep status``.
"""
from __future__ import annotations

import json
import os
import shlex
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _sweep_helpers import EXAMPLE_SCENE, wait_for, write_sweep
from pyfold.sweep import donors, store, worker
from pyfold.sweep.plan import plan
from pyfold.sweep.spec import read_sweep

HEARTBEAT = 0.2


def _one_run(tmp_path: Path) -> Path:
    sweep = write_sweep(tmp_path / "one.toml", f'''[sweep]
name = "one"
scene = "{EXAMPLE_SCENE}"
seeds = [1]

[arguments]
"particles[0].count" = 16
"numerics.t_end" = 2.0
"output.snapshot_interval" = 1.0
''')
    spec = read_sweep(sweep)
    runs = plan(spec)
    root = tmp_path / "sweep"
    store.prepare(root, spec, runs)
    return store.run_folder(root, runs[0].run_id)


def _burner(tmp_path: Path) -> tuple[Path, Path]:
    """A stand-in fold_run that burns CPU until killed, writing its own CPU time to a file."""
    clock = tmp_path / "burner_cpu.txt"
    script = tmp_path / "bin" / "fold_run"
    script.parent.mkdir()
    code = """import os, sys, time
n = 0
while True:
    n += 1
    if n % 200000 == 0:
        with open(sys.argv[1] + ".tmp", "w") as f:
            f.write(repr(time.process_time()))
        os.replace(sys.argv[1] + ".tmp", sys.argv[1])
"""
    script.write_text(f"#!/bin/sh\nexec {shlex.join([sys.executable, '-c', code, str(clock)])}\n")
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script, clock


def test_descendants_cpu_time_is_the_childs_own_clock(tmp_path):
    """/proc's ticks of a live child against the CPU time the child reads itself (one tick apart)."""
    if not Path("/proc/self/stat").exists():
        pytest.skip("no /proc here: the worker records no CPU time for a killed attempt")
    script, clock = _burner(tmp_path)
    child = subprocess.Popen([str(script)])
    try:
        wait_for(lambda: clock.exists() and float(clock.read_text() or 0) > 0.3, 60, "the child's CPU time")
        own = float(clock.read_text())
        seen = worker.descendants_cpu_seconds()
        tick = 1.0 / os.sysconf("SC_CLK_TCK")
        assert seen >= own - 2 * tick  # the child read its clock before /proc was read
    finally:
        child.kill()
        child.wait()


def test_killed_attempt_counts_with_its_cpu_time(tmp_path):
    folder = _one_run(tmp_path)
    script, clock = _burner(tmp_path)
    env = dict(os.environ, PYFOLD_FOLD_RUN=str(script))
    proc = subprocess.Popen([sys.executable, "-m", "pyfold.sweep.worker", str(folder), "--heartbeat", str(HEARTBEAT)],
                            env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_for(lambda: clock.exists() and float(clock.read_text() or 0) > 0.3, 120, "the stand-in's CPU time")
        seen_at, seen = time.time(), float(clock.read_text())

        def renewed_since():
            for path in folder.glob(store.OPEN_GLOB):
                entry = json.loads(path.read_text(encoding="utf-8"))
                if entry.get("beat", 0.0) > seen_at:
                    return entry
            return None

        wait_for(renewed_since, 60, "a renewal of the open attempt")
        assert store.attempts(folder) == []  # under way: not an attempt yet
        assert store.run_state(folder).state == "running"
    finally:
        # the worker and all its descendants at once (pyfold run starts fold_run in a session of its
        # own), as a stopped machine does: no clean-up
        for pid in [proc.pid, *worker.descendants(proc.pid, worker.process_table())]:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.communicate()
    burned = float(clock.read_text())
    (opened,) = folder.glob(store.OPEN_GLOB)
    last = json.loads(opened.read_text(encoding="utf-8"))
    assert last["pid"] == proc.pid and last["from"] == "queued"
    # not yet stale: the kill is seen only once the renewals have stopped for STALE_BEATS intervals
    assert store.attempts(folder, now=last["beat"]) == []
    (killed,) = store.attempts(folder, now=last["beat"] + (store.STALE_BEATS + 1) * HEARTBEAT)
    assert killed["state"] == "killed" and killed["end"] == last["beat"]
    # the last renewal's CPU time: at least what the stand-in had burned before it (to a tick of
    # /proc), and no more than the processes could have used in that wall time
    tick = 1.0 / os.sysconf("SC_CLK_TCK")
    assert seen - 2 * tick <= killed["cpu_s"] <= killed["wall_s"] * (os.cpu_count() or 1) + 2 * tick
    assert killed["cpu_s"] <= burned + killed["wall_s"]  # the stand-in's, plus the worker's own at most
    time.sleep((store.STALE_BEATS + 1) * HEARTBEAT)
    assert store.cpu_seconds(folder) == pytest.approx(killed["cpu_s"])
    assert store.run_state(folder).state in ("interrupted", "queued")  # a partial file, or none yet


def test_open_attempts_stale_fresh_and_closed(tmp_path):
    """Only a stale open attempt is killed; one whose line was written (a kill between the line and
    the removal of the open file) counts once; a killed extension names its donor."""
    folder = tmp_path / "run"
    folder.mkdir()
    now = 1.0e9
    donor = donors.Donor("abc", tmp_path / "donor" / "run.h5", 2.0)
    base = {"executor": "local", "host": "h", "np": 1, "heartbeat_s": 1.0}
    closed = dict(base, pid=1, start=now - 500, end=now - 400, beat=now - 401, cpu_s=90.0, wall_s=100.0,
                  state="interrupted", **{"from": "queued"})
    killed = dict(base, pid=2, start=now - 300, beat=now - 100, cpu_s=150.0, wall_s=200.0, donor=donor.record(),
                  **{"from": donors.EXTENDED})
    fresh = dict(base, pid=3, start=now - 50, beat=now - 1, cpu_s=40.0, wall_s=49.0, **{"from": "interrupted"})
    store.record_attempt(folder, closed)
    for entry in (closed, killed, fresh):
        store.write_atomic(store.open_attempt(folder, entry["host"], entry["pid"]), json.dumps(entry))
    got = store.attempts(folder, now=now)
    assert [a["pid"] for a in got] == [1, 2] and got[1]["state"] == "killed" and got[0]["state"] == "interrupted"
    assert sum(a["cpu_s"] for a in got) == 240.0
    # the killed attempt continued a donor, and the next one resumed its partial: the run is an
    # extension, which `pyfold sweep status` says (before, with no line for the killed attempt, it did not)
    store.write_atomic(store.open_attempt(folder, "h", 3), json.dumps(dict(fresh, beat=now - 100)))
    assert [a["pid"] for a in store.attempts(folder, now=now)] == [1, 2, 3]
    assert donors.extended_from(folder) == donor
    assert donors.describe(folder, "interrupted") == f" (extended from abc at t = 2)"


def test_an_error_in_the_donor_step_is_recorded_as_an_attempt(tmp_path, monkeypatch):
    """An exception while a queued run is started from its donor propagates, and the attempt is
    closed with exit status 1: its line is written and no open file is left behind to be taken
    for a killed attempt."""
    folder = _one_run(tmp_path)

    def broken(folder, entry):
        raise RuntimeError("donor copy failed")

    monkeypatch.setattr(worker, "_start_from_donor", broken)
    with pytest.raises(RuntimeError, match="donor copy failed"):
        worker.run_folder(folder, 1, heartbeat=HEARTBEAT)
    assert not list(folder.glob("attempt.*.open.json"))
    lines = [json.loads(x) for x in (folder / store.ATTEMPTS).read_text().splitlines()]
    assert len(lines) == 1 and lines[0]["rc"] == 1 and lines[0]["from"] == "queued"
    assert [a["state"] for a in store.attempts(folder)] == [lines[0]["state"]]
