"""``pyfold main``: the bundled default job of the README.

Every invocation writes a fresh, timestamped results folder under ``--out``
(``run-YYYYmmdd-HHMMSS``), assembled in a hidden temporary folder and renamed
into place only when complete, so an earlier result is never overwritten and
an interrupted job leaves no half-written folder. ``<out>/latest`` points to
the newest complete result.
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path


from pyfold.errors import InputError
from pyfold.pipeline import DEFAULT_CLOSURES

def _bundled_scenes() -> Path:
    """data/scenes of the source tree (editable install), or pyfold/scenes of a wheel."""
    installed = Path(__file__).resolve().parents[1] / "scenes"
    return installed if installed.is_dir() else Path(__file__).resolve().parents[2] / "data" / "scenes"


#: Scenes bundled with pyfold.
SCENES = _bundled_scenes()
DEFAULT_SCENE = SCENES / "default.toml"
STOKES_SCENE = SCENES / "stokes_small.toml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out/main", help="parent folder of the results (default: out/main)")
    parser.add_argument("--scene", default=None,
                        help=f"scene to simulate (default: the bundled {DEFAULT_SCENE.name})")
    parser.add_argument("--np", type=int, default=1, metavar="N", help="MPI ranks of the simulation (default 1)")
    parser.add_argument("--closures", default=None,
                        help="comma-separated closures to fit C_I with and to judge: 'exact' or names of "
                             f"pyfold.closures.available(dim) (default: {','.join(DEFAULT_CLOSURES)}, "
                             "those defined in the scene's dimension)")


def _scene_dim(scene: Path) -> int:
    """The scene's dimension (2 or 3), from the complete validation (a bad scene stops here)."""
    from pyfold.scene import load_scene

    return load_scene(scene).dim


def run(args: argparse.Namespace) -> int:
    scene = Path(args.scene) if args.scene else DEFAULT_SCENE
    if not scene.is_file():
        raise InputError(f"--scene: no such scene file: {scene}")
    from pyfold.commands.run import check_ranks

    check_ranks(args.np)
    dim = _scene_dim(scene)
    if args.closures is None:
        from pyfold.closures import available

        closures = tuple(c for c in DEFAULT_CLOSURES if c == "exact" or c in available(dim))
    else:
        from pyfold.pipeline import check_closures

        closures = check_closures(args.closures, dim)
    parent = Path(args.out)
    if parent.exists() and not parent.is_dir():
        raise InputError(f"--out: must be a folder (or not exist yet), got the file {parent}")
    parent.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("run-%Y%m%d-%H%M%S")
    final = parent / stamp
    suffix = 1
    while final.exists():
        suffix += 1
        final = parent / f"{stamp}-{suffix}"
    work = Path(tempfile.mkdtemp(prefix=".partial-", dir=parent))
    try:
        _job(work, scene, args.np, closures)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    work.rename(final)
    latest = parent / "latest"
    if latest.is_symlink() or not latest.exists():
        tmp_link = parent / f".latest-{os.getpid()}"
        tmp_link.unlink(missing_ok=True)
        tmp_link.symlink_to(final.name)
        tmp_link.replace(latest)
    print(f"pyfold main: results in {final}")
    return 0


def _job(outdir: Path, scene: Path, ranks: int, closures: tuple[str, ...]) -> None:
    """Simulate the scene, fit C_I per closure, judge closures, write figures and data."""
    from pyfold import pipeline

    print(f"pyfold main: 1/3 direct simulation of {scene}")
    run_path = pipeline.run_scene(scene, outdir / "run.h5", ranks=ranks)
    print("pyfold main: 2/3 fitting C_I of Folgar-Tucker per closure and judging closures against the run's a4")
    chain = pipeline.fit_and_compare(run_path, outdir, closures=closures)
    results = pipeline.results_dataset(chain)
    results.attrs["scene"] = str(scene)
    results.to_netcdf(outdir / "results.nc", engine="h5netcdf")
    summary = [f"scene: {scene}", f"run: {run_path.name}", "", pipeline.summary_table(chain.fits, chain.closure_errors)]
    if STOKES_SCENE.is_file() and scene == DEFAULT_SCENE:
        print(f"pyfold main: 3/3 small Stokes scene {STOKES_SCENE.name} (fibres coupled through the fluid)")
        stokes_path = pipeline.run_scene(STOKES_SCENE, outdir / "stokes_run.h5", ranks=ranks)
        summary += ["", pipeline.stokes_summary(stokes_path)]
    else:
        print("pyfold main: 3/3 skipped (no Stokes scene with a custom --scene)")
    (outdir / "summary.txt").write_text("\n".join(summary) + "\n")
