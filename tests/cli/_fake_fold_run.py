"""Stand-in for the fold_run executable (tests only): `fold_run RUNFILE`.

Reads /setup/resolved and /initial, appends contract-shaped results (the
orientation tensor of the initial axes at every record, snapshots equal to the
initial state), prints PROGRESS lines, and exits with $FAKE_FOLD_RUN_EXIT:
0 status "ok"; 1 status "failed: ..." after half the records; 2 rejects the file.
$FAKE_FOLD_RUN_SLEEP seconds (default 0) pass after the first PROGRESS line, before
the results are written: a run that lasts while another process tries the same file.
"""
import os
import sys
import time

import h5py
import numpy as np

from _fake_results import append_results

path = sys.argv[1]
code = int(os.environ.get("FAKE_FOLD_RUN_EXIT", "0"))
if code == 2:
    print("fold_run: error: /setup/resolved/dt: must be > 0 (stand-in rejection)", file=sys.stderr)
    sys.exit(2)
with h5py.File(path, "r") as f:
    r = f["setup/resolved"]
    dim, n_steps, every = int(r["dim"][()]), int(r["n_steps"][()]), int(r["output_every"][()])
    snap_every, dt = int(r["snapshot_every"][()]), float(r["dt"][()])
    n_fam = len(r["family_names"][()])
    x, p = f["initial/x"][()], f["initial/p"][()]
steps = list(range(0, n_steps + 1, every))
if code == 1:
    steps = steps[: max(1, len(steps) // 2)]
a2 = np.einsum("ni,nj->ij", p, p) / len(p)
snaps = list(range(0, steps[-1] + 1, snap_every)) if snap_every else []
for s in steps:
    print(f"PROGRESS {s} {n_steps} {s * dt:.6g}", flush=True)
    if s == steps[0]:
        time.sleep(float(os.environ.get("FAKE_FOLD_RUN_SLEEP", "0")))
append_results(path, dim, len(p), n_fam, [s * dt for s in steps], snaps, [s * dt for s in snaps],
               np.repeat(a2[None], len(steps), axis=0), np.repeat(x[None], len(snaps), axis=0),
               np.repeat(p[None], len(snaps), axis=0), [2.0] * len(steps),
               status="ok" if code == 0 else f"failed: step {steps[-1]}, t = {steps[-1] * dt:g}: stand-in blow-up")
if code == 1:
    print(f"fold_run: error: step {steps[-1]}: stand-in blow-up", file=sys.stderr)
sys.exit(code)
