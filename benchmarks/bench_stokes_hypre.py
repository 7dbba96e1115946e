"""Cost of the staggered-grid hypre Stokes backend: Schur-CG iterations against the
viscosity contrast, time per solve against the FFT backend, and np = 2 against np = 1.

Question: do the outer (Schur-complement CG) iterations of fold_stokes_hypre stay
flat for kappa = 10 ... 1e4 (goal: growth <= 2x), what does a solve cost relative
to the FFT backend on the same periodic scene (zero Lees-Edwards offset), and what
does np = 2 buy?
Command:  python benchmarks/bench_stokes_hypre.py [--build build-wt] [--repeats 3] [--large]
Cost: ~3 min on 2 shared cores (--large: 3-D 32^3 instead of 24^3, ~10 min).
Outputs: printed table (no files). Runs fortran/stokes/tests/bench_stokes_hypre
(a sphere of radius n/8 voxels and one of n/16, simple shear, tol 1e-6, zero guess;
each solve includes the matrix assembly and the BoomerAMG setup). Times are medians
over repeats of the CPU time of the solve (max over ranks) measured back to back;
the machine is shared, so read the ratios together with the load average printed
before each block, not the absolute seconds.
"""
from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1")


def _solve(exe: Path, dim: int, n: int, kappa: float, repeats: int, backend: str, walls: bool,
           ranks: int = 1) -> dict:
    cmd = [str(exe), str(dim), str(n), repr(kappa), str(repeats), backend, "1" if walls else "0"]
    if ranks > 1:
        cmd = ["mpirun", "-np", str(ranks), "--oversubscribe", *cmd]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=ENV).stdout
    rows = [dict(re.findall(r"(\w+)=\s*(\S+)", line)) for line in out.splitlines() if line.startswith("SOLVE")]
    return {"iterations": int(rows[-1]["iterations"]), "inner": int(rows[-1]["inner"]),
            "t_cpu": statistics.median(float(r["t_cpu"]) for r in rows),
            "t_wall": statistics.median(float(r["t_wall"]) for r in rows)}


def _load() -> str:
    return "load average %.2f %.2f %.2f" % os.getloadavg()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=str(ROOT / "build-wt"), help="meson build directory")
    ap.add_argument("--repeats", type=int, default=3, help="solves per configuration (median)")
    ap.add_argument("--large", action="store_true", help="3-D grid 32^3 instead of 24^3")
    args = ap.parse_args()
    exe = Path(args.build) / "fortran/stokes/tests/bench_stokes_hypre"
    if not exe.exists():
        raise SystemExit(f"bench_stokes_hypre not built: {exe} (ninja -C {args.build})")
    n3 = 32 if args.large else 24

    print("# Schur-CG iterations against kappa (walls, hypre);", _load())
    for dim, n in ((2, 64), (3, n3)):
        its = {}
        for kappa in (10.0, 1e2, 1e3, 1e4):
            r = _solve(exe, dim, n, kappa, 1, "hypre", True)
            its[kappa] = r["iterations"]
            print(f"dim {dim} n {n} kappa {kappa:8.0e}: outer {r['iterations']:3d}, inner PCG {r['inner']:5d}, "
                  f"cpu {r['t_cpu']:.3f} s")
        print(f"dim {dim}: outer iterations kappa 1e4 / kappa 10 = {its[1e4] / its[10.0]:.2f}")

    print("# time per solve, hypre / fft, periodic scene (zero offset);", _load())
    for dim, n in ((2, 128), (3, n3)):
        for kappa in (10.0, 1e3):
            h = _solve(exe, dim, n, kappa, args.repeats, "hypre", False)
            f = _solve(exe, dim, n, kappa, args.repeats, "fft", False)
            print(f"dim {dim} n {n} kappa {kappa:7.0e}: hypre {h['t_cpu']:.3f} s ({h['iterations']} outer, "
                  f"{h['inner']} inner), fft {f['t_cpu']:.4f} s ({f['iterations']} CG), "
                  f"cpu ratio hypre/fft {h['t_cpu'] / f['t_cpu']:.0f}")

    print("# np = 2 against np = 1 (hypre, walls);", _load())
    for dim, n in ((2, 128), (3, n3)):
        one = _solve(exe, dim, n, 1e3, args.repeats, "hypre", True, 1)
        two = _solve(exe, dim, n, 1e3, args.repeats, "hypre", True, 2)
        print(f"dim {dim} n {n}: wall np=1 {one['t_wall']:.3f} s, np=2 {two['t_wall']:.3f} s, "
              f"speed-up {one['t_wall'] / two['t_wall']:.2f} (outer {one['iterations']} vs {two['iterations']})")
    print("#", _load())


if __name__ == "__main__":
    main()
