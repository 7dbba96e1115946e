"""Secondary writers on a full disk: the XDMF beside a run file, the figures and
results.nc of `pyfold analyse --out`, the report files of `pyfold report --out`.

Each exits 1 naming the file and the cause (``No space left on device (ENOSPC)``),
with no traceback, and leaves nothing half-written: no 0-byte ``.xmf``, no truncated
PNG, no temporary (every writer goes through :func:`pyfold.files.atomic_output`:
temporary in the same folder, fsync, rename). `pyfold run` keeps the complete run
file when only its XDMF fails, and exits 1.

The full disk is real: a small tmpfs mounted for each test (we run as root) and
filled to the last page. Where mount is not permitted the tests are skipped, saying so.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import base_scene, write_scene
from pyfold import plotting
from pyfold.cli import main
from pyfold.commands import run as run_command
from pyfold.errors import PyfoldError
from pyfold.files import atomic_output
from pyfold.run_input import write_run_file
from pyfold.run_results import write_xdmf
from pyfold.scene import load_scene
from pyfold.scene.initial import initial_state

#: Size of the tmpfs [bytes]: room for the small run files of these tests
DISK = 1 << 20
FILLER = "filler"
ENOSPC = "No space left on device (ENOSPC)"


@pytest.fixture
def disk(tmp_path):
    """A fresh tmpfs of DISK bytes at tmp_path/disk (unmounted afterwards)."""
    folder = tmp_path / "disk"
    folder.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK}", "tmpfs", str(folder)], capture_output=True,
                          text=True)
    if proc.returncode != 0:
        pytest.skip(f"a full disk needs a tmpfs, and mount is not permitted here: {proc.stderr.strip()}")
    try:
        yield folder
    finally:
        if subprocess.run(["umount", str(folder)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def fill(folder: Path) -> None:
    """Write FILLER until the file system refuses another byte (ENOSPC)."""
    with open(folder / FILLER, "ab", buffering=0) as f:
        with pytest.raises(OSError) as caught:
            for _ in range(2 * DISK // 4096 + 16):
                f.write(b"\0" * 4096)
        assert caught.value.errno == 28, caught.value
        with pytest.raises(OSError):
            f.write(b"\0")  # not even one byte: the last page is taken too


def contents(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")} - {FILLER}


def test_atomic_output_on_a_full_disk_keeps_the_earlier_file_and_no_temporary(disk):
    target = disk / "summary.txt"
    target.write_text("earlier\n", encoding="utf-8")
    fill(disk)
    with pytest.raises(PyfoldError, match=r"cannot write .*summary\.txt: No space left on device \(ENOSPC\)"):
        with atomic_output(target) as tmp:
            tmp.write_text("new " * 10_000, encoding="utf-8")
    assert target.read_text(encoding="utf-8") == "earlier\n"
    assert contents(disk) == {"summary.txt"}


def test_netcdf_on_a_full_disk_raises_naming_enospc_and_leaves_nothing(disk):
    """results.nc goes through h5netcdf / HDF5, which reports the failed write in its own words."""
    import xarray as xr

    fill(disk)
    ds = xr.Dataset({"ci": (("closure",), np.linspace(0.0, 1.0, 50_000))})
    with pytest.raises(PyfoldError) as caught:
        with atomic_output(disk / "results.nc") as tmp:
            ds.to_netcdf(tmp, engine="h5netcdf")
    assert str(caught.value) == f"cannot write {disk / 'results.nc'}: {ENOSPC}"
    assert contents(disk) == set()


@pytest.fixture(scope="module")
def setup_run(tmp_path_factory) -> Path:
    """A run file as `pyfold run` writes it before fold_run (/setup, /initial)."""
    folder = tmp_path_factory.mktemp("setup_run")
    resolved = load_scene(write_scene(folder / "scene.toml", base_scene()))
    path = folder / "run.h5"
    write_run_file(path, resolved, initial_state(resolved), "pyfold run scene.toml")
    return path


def test_xdmf_on_a_full_disk_raises_naming_enospc_and_leaves_no_xmf(disk, setup_run):
    fill(disk)
    with pytest.raises(PyfoldError) as caught:
        write_xdmf(setup_run, disk / "run.xmf")
    assert "run.xmf" in str(caught.value) and ENOSPC in str(caught.value)
    assert contents(disk) == set()


def test_figure_on_a_full_disk_leaves_no_truncated_png(disk):
    fill(disk)
    t = np.linspace(0.0, 1.0, 5)
    a2 = np.repeat(np.eye(3)[None] / 3.0, len(t), axis=0)
    with pytest.raises(PyfoldError, match=r"histories\.png: No space left on device \(ENOSPC\)"):
        plotting.plot_a2_histories(t, {"isotropic": a2}, disk / "histories.png")
    assert contents(disk) == set()


def test_run_whose_xdmf_meets_a_full_disk_keeps_the_run_file_and_exits_1(disk, fake_fold_run, monkeypatch, capsys,
                                                                         tmp_path):
    execute = run_command._execute

    def execute_then_fill(*args, **kwargs):  # the disk fills up while fold_run runs
        result = execute(*args, **kwargs)
        fill(disk)
        return result

    monkeypatch.setattr(run_command, "_execute", execute_then_fill)
    out = disk / "out.h5"
    assert main(["run", str(write_scene(tmp_path / "s.toml", base_scene())), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"pyfold run: failed: the run is complete in {out}, but its XDMF {disk / 'out.xmf'} was not written" in err
    assert ENOSPC in err, err
    assert contents(disk) == {"out.h5"}  # no .xmf, no temporary, no .partial
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] in ("ok", b"ok") and "a2" in f


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A short real run (8 fibres, 200 steps) to analyse and report on."""
    folder = tmp_path_factory.mktemp("finished_run")
    scene = base_scene()
    scene["numerics"]["t_end"] = 2.0
    out = folder / "run.h5"
    assert main(["run", str(write_scene(folder / "s.toml", scene)), "-o", str(out)]) == 0
    return out


@pytest.mark.parametrize("command", ["analyse", "report"])
def test_analysis_outputs_on_a_full_disk_exit_1_naming_enospc_and_leave_nothing(disk, finished_run, capsys, command):
    fill(disk)
    out = disk / "out"
    # --force: the run (strain 2) is shorter than the Jeffery period a C_I estimate needs
    assert main([command, str(finished_run), "--closures", "exact,ibof", "--out", str(out), "--force"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    failed = [line for line in err.splitlines() if line.startswith(f"pyfold {command}: failed: ")]
    assert len(failed) == 1, err
    assert f"cannot write {out}/" in failed[0] and ENOSPC in failed[0] and "/.report-" not in failed[0], failed[0]
    assert contents(disk) == {"out"}  # the folder, empty: no truncated PNG, no results.nc, no temporary
