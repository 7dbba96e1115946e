"""meson test: fold_run on 1 and 2 MPI ranks, exit codes of bad and blowing-up runs.

Usage: check_fold_run.py FOLD_RUN MPIEXEC. Writes its run files into a temporary
directory (h5py), in the layout pyfold/run_input.py writes. Scene: the seed's 2-D
Couette disks (cell 1.5 x 1, R = 0.075, 42 disks = 49 % area, gamma_dot = 1,
dt = 0.05, alpha = 0.005), 40 steps with the collision strategy: contact-heavy.
"""
import os
import subprocess
import sys
import tempfile

import h5py
import numpy as np


def place_disks(n, R, Lx, Ly, rng):
    """Random sequential addition of n disks (periodic in x, walls at y = 0, Ly)."""
    pts = np.empty((0, 2))
    while len(pts) < n:
        for c in np.column_stack([rng.uniform(0, Lx, 4096), rng.uniform(R, Ly - R, 4096)]):
            dx = pts[:, 0] - c[0]
            dx -= Lx * np.round(dx / Lx)
            if len(pts) and np.min(dx**2 + (pts[:, 1] - c[1]) ** 2) < (2 * R) ** 2:
                continue
            pts = np.vstack([pts, c])
            if len(pts) == n:
                break
    return pts


def write(path, **change):
    R, n = 0.075, 42
    rng = np.random.default_rng(0)  # this seed places the 42 disks in ~2e4 trials
    x = place_disks(n, R, 1.5, 1.0, rng)
    theta = rng.uniform(0, 2 * np.pi, n)
    G = np.zeros((3, 3))
    G[0, 1] = 1.0
    res = dict(dim=2, cell_lengths=np.array([1.5, 1.0, 1.0]), walls=1, wall_speed=0.5, velocity_gradient=G,
               shear_rate=1.0, viscosity=1.0, dt=0.05, t_end=2.0, seed=1, hydrodynamics=0, collisions=2,
               alpha=0.005, contact_max_iter=200, on_contact_cap=1, lubrication=0, output_every=1,
               snapshot_every=10, checkpoint_every=0)
    res.update(change)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "pyfold.run"
        f.attrs["format_version"] = "1.0"
        r = f.create_group("setup/resolved")
        for k, v in res.items():
            r[k] = v
        r.create_dataset("family_names", data=np.array(["disks"], dtype=object), dtype=h5py.string_dtype())
        i = f.create_group("initial")
        i["x"] = x
        i["p"] = np.column_stack([np.cos(theta), np.sin(theta)])
        i["shape"] = np.full(n, 2)
        i["family"] = np.zeros(n, dtype=int)
        i["radius"] = np.full(n, R)
        i["length"] = np.full(n, 2 * R)
        i["xi"] = np.zeros(n)


def run(exe, mpiexec, path, np_ranks):
    cmd = [exe, path] if np_ranks == 1 else [mpiexec, "-np", str(np_ranks), "--oversubscribe", exe, path]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=100)


def main():
    exe, mpiexec = sys.argv[1], sys.argv[2]
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        out = {}
        for np_ranks in (1, 2):
            path = os.path.join(tmp, f"np{np_ranks}.h5")
            write(path)
            proc = run(exe, mpiexec, path, np_ranks)
            if proc.returncode != 0:
                failures.append(f"np={np_ranks}: exit {proc.returncode}: {proc.stderr[-2000:]}")
                continue
            with h5py.File(path) as f:
                out[np_ranks] = {k: f[k][()] for k in ("a2", "min_gap", "n_corrections", "x", "p")}
                out[np_ranks]["mpi_ranks"] = int(f.attrs["mpi_ranks"])
        if len(out) == 2:
            if out[2]["mpi_ranks"] != 2:
                failures.append("np=2 run did not record mpi_ranks = 2")
            if out[1]["n_corrections"].sum() == 0:
                failures.append("scene is not contact-heavy: no corrections")
            for k in ("a2", "min_gap", "x", "p"):
                diff = np.max(np.abs(out[1][k] - out[2][k]))
                print(f"np1 vs np2: max |diff| of {k} = {diff:.3e}")
                if not diff <= 1e-12:
                    failures.append(f"{k} differs between np=1 and np=2 by {diff:.3e}")
            if not np.array_equal(out[1]["n_corrections"], out[2]["n_corrections"]):
                failures.append("n_corrections differ between np=1 and np=2")
            if out[1]["min_gap"].min() < 0:
                failures.append(f"overlap with the strategy: min gap {out[1]['min_gap'].min():.3e}")
        bad = os.path.join(tmp, "bad.h5")
        write(bad, dt=-1.0)
        proc = run(exe, mpiexec, bad, 2)
        if proc.returncode != 2 or "/setup/resolved/dt" not in proc.stderr:
            failures.append(f"bad dt: exit {proc.returncode}, stderr {proc.stderr[-500:]!r}")
        nan = os.path.join(tmp, "nan.h5")
        write(nan, dt=1e300, t_end=1e301)
        proc = run(exe, mpiexec, nan, 2)
        if proc.returncode != 1 or "step 1" not in proc.stderr:
            failures.append(f"absurd dt: exit {proc.returncode}, stderr {proc.stderr[-500:]!r}")
    for f in failures:
        print("FAIL:", f)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
