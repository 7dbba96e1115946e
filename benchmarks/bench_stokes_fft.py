"""Cost of one CG iteration of the Stokes solver in units of one real 3-D FFT.

Question: how close is an iteration to its floor of 12 FFTs (6 c2r + 6 r2c), at
64^3 and 128^3, and what does np = 2 buy on 128^3?
Command:  python benchmarks/bench_stokes_fft.py [--build build/editable] [--repeats 5]
Cost: ~1 min. Runs the Fortran program fortran/stokes/tests/bench_stokes_fft
(FFTW_MEASURE plans, a sphere of radius n/8, kappa 1e3, 20 iterations) and
prints medians over repeats (the machine is shared: read ratios, not times).
"""
from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(exe: Path, n: int, ranks: int, repeats: int) -> list[dict]:
    cmd = [str(exe), str(n), "1000", str(repeats)]
    if ranks > 1:
        cmd = ["mpirun", "-np", str(ranks), "--oversubscribe"] + cmd
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env).stdout
    rows = []
    for line in out.splitlines():
        m = re.search(r"t_fft=\s*(\S+) t_iter=\s*(\S+) ratio=\s*(\S+)", line)
        if m:
            rows.append(dict(t_fft=float(m[1]), t_iter=float(m[2]), ratio=float(m[3])))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=str(ROOT / "build" / "editable"))
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    exe = Path(args.build) / "fortran" / "stokes" / "tests" / "bench_stokes_fft"
    print(f"{'grid':>6} {'ranks':>5} {'median t_iter [s]':>18} {'median iter/FFT':>16}")
    per_rank = {}
    for n, ranks in ((64, 1), (128, 1), (128, 2)):
        rows = run(exe, n, ranks, args.repeats)
        t_it = statistics.median(r["t_iter"] for r in rows)
        ratio = statistics.median(r["ratio"] for r in rows)
        per_rank[(n, ranks)] = t_it
        print(f"{n:>5}^3 {ranks:>5} {t_it:>18.3e} {ratio:>16.1f}")
    print(f"speed-up np=2 vs np=1 at 128^3: {per_rank[(128, 1)] / per_rank[(128, 2)]:.2f}")


if __name__ == "__main__":
    main()
