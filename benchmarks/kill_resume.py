"""Randomized SIGKILL / --resume of fold_run against an uninterrupted run.

Question: whatever moment a run is killed at (also inside a record, snapshot or
checkpoint write, also while it is resuming), does ``fold_run RUN --resume`` either
finish with results identical bit for bit to an uninterrupted run, or refuse with
exit 2 naming the cause, and never finish "ok" with different results?

Command (a few minutes on 2 cores; each try costs about one to two runs of the scene,
~3 s each):
    .venv/bin/python benchmarks/kill_resume.py [--tries 40] [--seed 1] [--max-kills 3]
        [--again 0.5] [--n 64] [--steps 3000] [--checkpoint-every 2] [--out out/kill_resume]
        [--concurrent 0] [--corrupt]
    (a small form: --tries 2 --concurrent 6 --steps 1000, about a minute)

Scene: N fibres (aspect ratio 20, L = 1) in a periodic 5^3 cell, simple shear, Jeffery
kinematics with the collision strategy (collisions = 1, alpha = 0.005), dt = 0.01; a
record every step, a snapshot every 7 steps, a checkpoint every `--checkpoint-every`
steps (frequent: many kills land inside a checkpoint write). The uninterrupted
reference is run twice (and must agree with itself bit for bit, else nothing can be
concluded and the script stops).

A try: write the run file, start fold_run, SIGKILL it at a time drawn uniformly over
[0, 0.15 s + 1.05 x the reference's wall time] from its start (so also during start-up
and layout, and sometimes after it ended), then `fold_run RUN --resume`; with
probability `--again` that resume is killed too (uniform over 0.15 s + the part of the
run still to go after the previous kill), up to `--max-kills` kills per try; the last
resume runs to its end. Outcome of a try:
  * "resumed bitwise": exit 0, status "ok", every record/snapshot dataset, the
    checkpoint and records_complete equal to the reference's;
  * "refused": a resume exited 2 with a "fold_run: ..." message (the cause is kept,
    e.g. a kill before the first checkpoint: nothing to resume from);
  * "wrong": exit 0 with different results (must be 0);
  * "other": anything else (exit 1, a signal, a file h5py cannot open) -- also a
    defect to look at.

Concurrent writers (`--concurrent N`, N tries; `--tries 0 --concurrent N` runs only
these): `pyfold run SCENE -o TRY.h5`, SCENE the tries' fibres in their cell as a scene
(pyfold.scene.sheared_fibres: beta 20, N fibres in 5^3, dt 0.01), and at a
time drawn uniformly over [0, 1.05 x the wall time of a reference `pyfold run`]
after its start a second `pyfold run` on the same destination, plain or
`--resume` (even odds). Outcome of a try:
  * "refused naming holder": one exits 0 with results bit for bit the reference's,
    the other exits 2 naming the winner's pid (the destination lock);
  * "refused otherwise": one exits 0 bitwise, the other exits 2 for the state it
    found (it started after the winner ended: OUT.h5 exists / nothing to resume);
  * "wrong": no exit 0, both exit 0, or the winner's results differ (must be 0);
  * "other": anything else.

With `--corrupt` (corrupted-record case): each try is killed once; then one byte is
flipped in a record written before the checkpoint (a random record dataset of
CORRUPTED, a random whole record with step <= /checkpoint/step, the byte located
through HDF5's chunk index) and `fold_run RUN --resume` runs to its end. Outcome:
  * "refused naming it": exit 2 with a message naming the flipped dataset as damaged;
  * "wrong": exit 0 (the corrupted record passed into an "ok" run: must be 0);
  * "other": anything else (also a refusal naming something else);
  * "not corrupted": the kill left no checkpoint or no record before it (nothing to flip).

Outputs: the counts, the load average (before / after), the command to reproduce on
stdout; one CSV row per try in OUT/kill_resume_seed<seed>.csv (try, kills, kill times
and the phase reached (last PROGRESS step) at each kill, resume exit codes, outcome,
cause, seconds). out/ is never committed. Exit status 1 when a try is "wrong" or
"other". Not a test (tests/micro/test_run_integrity.py runs a bounded version).
"""
from __future__ import annotations

import argparse
import csv
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import h5py
import numpy as np

from pyfold.scene.sheared_fibres import sheared_fibres
from pyfold.xdmf_files import xdmf_paths

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "micro"))
sys.path.insert(0, str(ROOT / "tests" / "cli"))
from _corrupt import data_offset, flip  # noqa: E402
from test_run_common import random_unit, write_run_file, xi_of  # noqa: E402

#: Datasets an uninterrupted and a resumed run must agree on bit for bit
COMPARED = ("step", "time", "a2", "a4", "a2_family", "a4_family", "min_gap", "min_gap_over_alpha", "n_corrections",
            "contact_iterations", "pairs_left", "capped_steps", "length_drift", "unit_norm_drift", "snapshot",
            "snapshot_time", "x", "p")
CHECKPOINT = ("step", "time", "x", "p", "v", "omega", "checksum")
#: Record datasets a --corrupt try flips a byte in
CORRUPTED = ("time", "step", "a2", "a4", "a2_family", "min_gap", "n_corrections", "unit_norm_drift")
#: Start-up time of fold_run added to every kill window [s]
START = 0.15
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def fold_run() -> Path:
    from pyfold.commands.run import find_fold_run

    return find_fold_run()


def scene(path: Path, n: int, steps: int, checkpoint_every: int) -> None:
    rng = np.random.default_rng(7)
    cell = 5.0
    write_run_file(path, x=rng.uniform(0, cell, size=(n, 3)), p=random_unit(rng, n, 3), radius=0.025, length=1.0,
                   xi=xi_of(20.0), family=np.arange(n) % 2, family_names=("a", "b"),
                   cell_lengths=(cell, cell, cell), dt=0.01, t_end=steps * 0.01, collisions=1, alpha=0.005,
                   output_every=1, snapshot_every=7, checkpoint_every=checkpoint_every)


class Running:
    """fold_run started in its own process group; remembers the last PROGRESS step."""

    def __init__(self, exe: Path, path: Path, resume: bool):
        cmd = [str(exe), str(path)] + (["--resume"] if resume else [])
        self.start = time.monotonic()
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
                                     start_new_session=True)
        self.last_step = -1
        self.err = ""
        self._out = threading.Thread(target=self._read_out, daemon=True)
        self._err = threading.Thread(target=self._read_err, daemon=True)
        self._out.start()
        self._err.start()

    def _read_out(self):
        for line in self.proc.stdout:
            if line.startswith("PROGRESS"):
                self.last_step = int(line.split()[1])

    def _read_err(self):
        self.err = self.proc.stderr.read()

    def wait(self, timeout=None) -> int:
        rc = self.proc.wait(timeout=timeout)
        self._out.join()
        self._err.join()
        return rc

    def kill_at(self, delay: float) -> tuple[bool, int]:
        """SIGKILL `delay` s after the start; (killed while running, last PROGRESS step)."""
        try:
            self.proc.wait(timeout=max(0.0, self.start + delay - time.monotonic()))
            running = False
        except subprocess.TimeoutExpired:
            running = True
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.wait()
        return running, self.last_step


def same_run(ref: Path, path: Path, steps: int) -> str:
    """"" when `path` equals the reference bit for bit, else the first difference."""
    with h5py.File(ref) as a, h5py.File(path) as b:
        status = b.attrs.get("status")
        status = status.decode() if isinstance(status, bytes) else str(status)
        if status != "ok":
            return f"status {status!r}"
        if int(b.attrs.get("steps_done", -1)) != steps:
            return f"steps_done {b.attrs.get('steps_done')}"
        if int(b.attrs.get("records_complete", -1)) != a["step"].shape[0]:
            return f"records_complete {b.attrs.get('records_complete')} != {a['step'].shape[0]}"
        for name in COMPARED:
            x, y = a[name][()], b[name][()]
            if x.shape != y.shape or not np.array_equal(x, y):
                return f"/{name} differs"
        for group in ("checkpoint", "checkpoint_shadow"):
            for name in CHECKPOINT:
                if not np.array_equal(a["checkpoint"][name][()], b[group][name][()]):
                    return f"/{group}/{name} differs"
    return ""


def pyfold_run(*args: str) -> subprocess.Popen:
    """`pyfold run ...` as a child process (stdout discarded, stderr kept)."""
    return subprocess.Popen([sys.executable, "-m", "pyfold.cli", "run", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env=ENV)


def same_records(ref: Path, path: Path) -> str:
    """"" when `path` has status ok and every record/snapshot dataset of `ref` bit for bit."""
    try:
        with h5py.File(ref) as a, h5py.File(path) as b:
            status = b.attrs.get("status")
            status = status.decode() if isinstance(status, bytes) else str(status)
            if status != "ok":
                return f"status {status!r}"
            for name in COMPARED:
                if name in a and (name not in b or not np.array_equal(a[name][()], b[name][()])):
                    return f"/{name} differs"
    except OSError as exc:
        return f"unreadable: {exc}"
    return ""


def concurrent_tries(args, rng, tmp: Path, w) -> dict[str, int]:
    """`--concurrent` tries: a second `pyfold run` / `--resume` on a destination being written."""
    counts = {"refused naming holder": 0, "refused otherwise": 0, "wrong": 0, "other": 0}
    toml = tmp / "concurrent.toml"
    # the tries' fibres (beta 20, dt 0.01) in the same 5^3 cell, as a scene for `pyfold run`
    toml.write_text(sheared_fibres(20.0, args.n / 125.0, seed=7, t_end=args.steps * 0.01, dt=0.01,
                                   min_side=5.0, title="kill_resume: concurrent writers").toml)
    ref = tmp / "concurrent_ref.h5"
    t0 = time.monotonic()
    first = pyfold_run(str(toml), "-o", str(ref))
    _, err = first.communicate()
    wall = time.monotonic() - t0
    if first.returncode != 0:
        print(f"reference pyfold run failed (exit {first.returncode}): {err}", file=sys.stderr)
        counts["other"] += 1
        return counts
    print(f"concurrent writers: reference `pyfold run` {wall:.2f} s", flush=True)
    for t in range(args.concurrent):
        t_start = time.monotonic()
        out = tmp / f"concurrent{t}.h5"
        mode = "--resume" if rng.uniform() < 0.5 else "plain"
        delay = float(rng.uniform(0.0, 1.05 * wall))
        first = pyfold_run(str(toml), "-o", str(out))
        time.sleep(delay)
        first_ended = first.poll() is not None
        second = pyfold_run(str(toml), "-o", str(out), *(["--resume"] if mode == "--resume" else []))
        err1, err2 = first.communicate()[1], second.communicate()[1]
        codes = (first.returncode, second.returncode)
        pids = (first.pid, second.pid)
        errs = (err1, err2)
        winners = [k for k in (0, 1) if codes[k] == 0]
        if len(winners) != 1:
            outcome, cause = "wrong", f"exit codes {codes}: {err1.strip()[-200:]} | {err2.strip()[-200:]}"
        else:
            win = winners[0]
            lose = 1 - win
            diff = same_records(ref, out)
            if diff:
                outcome, cause = "wrong", diff
            elif codes[lose] == 2 and f"pid {pids[win]} on host" in errs[lose]:
                outcome, cause = "refused naming holder", errs[lose].strip().splitlines()[-1][:200]
            elif codes[lose] == 2:
                outcome, cause = "refused otherwise", errs[lose].strip().splitlines()[-1][:200]
            else:
                outcome, cause = "other", f"loser exit {codes[lose]}: {errs[lose].strip()[-300:]}"
        counts[outcome] += 1
        w.writerow([f"concurrent {t}", mode, f"{delay:.3f}", int(first_ended), "", " ".join(map(str, codes)),
                    outcome, cause, f"{time.monotonic() - t_start:.2f}"])
        print(f"concurrent {t:3d}: second ({mode}) after {delay:.2f} s"
              f"{' (first had ended)' if first_ended else ''}: exits {codes}: {outcome}: {cause}", flush=True)
        for path in (out, *xdmf_paths(out)):
            path.unlink(missing_ok=True)
    return counts


def corrupt_record(path: Path, rng: np.random.Generator) -> tuple[str, int] | None:
    """Flip one byte of a whole record written before the checkpoint of a killed run:
    ``(dataset, record)``, or None when there is no checkpoint or no such record."""
    try:
        with h5py.File(path, "r") as f:
            if "checkpoint" not in f or "step" not in f["checkpoint"] or "step" not in f:
                return None
            ckpt = int(f["checkpoint/step"][()])
            whole = min(int(f.attrs.get("records_complete", 0)), f["step"].shape[0])
            steps = f["step"][:whole]
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        print(f"  (not corrupted: {exc})", file=sys.stderr)
        return None
    before = np.flatnonzero(steps <= ckpt)
    if before.size == 0:
        return None
    name = str(rng.choice(CORRUPTED))
    record = int(rng.choice(before))
    with h5py.File(path, "r") as f:
        size = f[name].dtype.itemsize * int(np.prod(f[name].shape[1:], dtype=np.int64))
    flip(path, data_offset(path, "/" + name, record) + int(rng.integers(size)), mask=1 << int(rng.integers(8)))
    return name, record


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tries", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-kills", type=int, default=3, help="kills per try at most (the first always)")
    ap.add_argument("--again", type=float, default=0.5, help="probability that a resume is killed too")
    ap.add_argument("--n", type=int, default=64, help="fibres")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--checkpoint-every", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "out" / "kill_resume"))
    ap.add_argument("--concurrent", type=int, default=0,
                    help="tries of the concurrent-writer case (a second pyfold run / --resume on the destination)")
    ap.add_argument("--corrupt", action="store_true",
                    help="after the kill, flip a byte in a record before the checkpoint: the resume must refuse")
    args = ap.parse_args(argv)
    command = "python benchmarks/kill_resume.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    if "--seed" not in command:
        command += f" --seed {args.seed}"

    exe = fold_run()
    load_before = os.getloadavg()
    rng = np.random.default_rng(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = out / f"kill_resume{'_corrupt' if args.corrupt else ''}_seed{args.seed}.csv"
    counts = {"resumed bitwise": 0, "refused": 0, "wrong": 0, "other": 0}
    if args.corrupt:
        counts = {"refused naming it": 0, "not corrupted": 0, "wrong": 0, "other": 0}
    with tempfile.TemporaryDirectory(prefix="kill_resume_") as tmp:
        tmp = Path(tmp)
        refs = []
        walls = []
        for k in range(2):
            ref = tmp / f"ref{k}.h5"
            scene(ref, args.n, args.steps, args.checkpoint_every)
            run = Running(exe, ref, resume=False)
            rc = run.wait()
            walls.append(time.monotonic() - run.start)
            if rc != 0:
                print(f"reference run failed (exit {rc}): {run.err}", file=sys.stderr)
                return 1
            refs.append(ref)
        diff = same_run(refs[0], refs[1], args.steps)
        if diff:
            print(f"the uninterrupted run is not reproducible ({diff}): nothing to compare with", file=sys.stderr)
            return 1
        ref = refs[0]
        span = 1.05 * max(walls)
        print(f"fold_run: {exe}\nscene: {args.n} fibres, {args.steps} steps, checkpoint every "
              f"{args.checkpoint_every}; reference run {min(walls):.2f} / {max(walls):.2f} s (twice, bitwise equal)")
        with open(table, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["try", "kills", "kill_times_s", "killed_while_running", "last_progress_step_at_kill",
                        "resume_exit_codes", "outcome", "cause", "seconds"])
            for t in range(args.tries):
                t0 = time.monotonic()
                path = tmp / f"try{t}.h5"
                scene(path, args.n, args.steps, args.checkpoint_every)
                times, running, steps_at, codes = [], [], [], []
                run = Running(exe, path, resume=False)
                outcome, cause = None, ""
                left = 1.0  # fraction of the run still to go (a resume starts near the last kill)
                while True:
                    delay = float(rng.uniform(0.0, START + span * left))
                    alive, last = run.kill_at(delay)
                    times.append(f"{delay:.3f}")
                    running.append(str(int(alive)))
                    steps_at.append(str(last))
                    if alive and last >= 0:
                        left = 1.0 - last / args.steps
                    if args.corrupt:
                        flipped = corrupt_record(path, rng)
                        run = Running(exe, path, resume=True)
                        rc = run.wait(timeout=600)
                        codes.append(str(rc))
                        break
                    run = Running(exe, path, resume=True)
                    if len(times) < args.max_kills and rng.uniform() < args.again:
                        continue  # this resume is killed too (unless it ends first)
                    rc = run.wait(timeout=600)
                    codes.append(str(rc))
                    break
                if args.corrupt:
                    if flipped is None:
                        outcome, cause = "not corrupted", f"exit {rc}: " + (run.err.strip().splitlines() or [""])[0]
                    elif rc == 0:
                        outcome, cause = "wrong", f"/{flipped[0]} record {flipped[1]} flipped, resume finished"
                    elif rc == 2 and f"/{flipped[0]}: damaged" in run.err:
                        outcome, cause = "refused naming it", run.err.strip().splitlines()[0]
                    else:
                        outcome, cause = "other", f"/{flipped[0]} record {flipped[1]}: exit {rc}: {run.err.strip()[:300]}"
                elif rc == 0:
                    diff = same_run(ref, path, args.steps)
                    outcome, cause = ("resumed bitwise", "") if not diff else ("wrong", diff)
                elif rc == 2 and run.err.startswith("fold_run:"):
                    outcome, cause = "refused", run.err.strip().splitlines()[0]
                else:
                    outcome, cause = "other", f"exit {rc}: {run.err.strip()[:300]}"
                counts[outcome] += 1
                w.writerow([t, len(times), " ".join(times), " ".join(running), " ".join(steps_at),
                            " ".join(codes), outcome, cause, f"{time.monotonic() - t0:.2f}"])
                fh.flush()
                print(f"try {t:3d}: {len(times)} kill(s) at {', '.join(times)} s (steps {', '.join(steps_at)}): "
                      f"{outcome}{': ' + cause if cause else ''}", flush=True)
                path.unlink(missing_ok=True)
            concurrent = concurrent_tries(args, rng, tmp, w) if args.concurrent > 0 else None
    load_after = os.getloadavg()
    print("\ncounts: " + ", ".join(f"{k} {v}" for k, v in counts.items()) + f" (of {args.tries} tries)")
    if concurrent is not None:
        print("concurrent writers: " + ", ".join(f"{k} {v}" for k, v in concurrent.items())
              + f" (of {args.concurrent} tries)")
    print("load average (1, 5, 15 min): before " + " ".join(f"{x:.2f}" for x in load_before)
          + ", after " + " ".join(f"{x:.2f}" for x in load_after) + f" on {os.cpu_count()} cores")
    print(f"table: {table}")
    print(f"reproduce: {command}")
    bad = counts["wrong"] + counts["other"] + (concurrent["wrong"] + concurrent["other"] if concurrent else 0)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
