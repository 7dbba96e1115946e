"""Corruption of a run file never passes silently (pyfold.integrity).

One flipped byte in a record written before the checkpoint, in ``/initial/x``, in
``/setup/resolved/dt`` or in a ``time`` record: ``pyfold run --resume`` (and
``fold_run --resume`` alone, for the records), ``pyfold analyse`` and ``pyfold report``
refuse the file with exit 2 naming the dataset, and leave it as it was;
``--allow-damaged`` reads the intact part (the records before the first damaged chunk,
the other datasets without the damaged one). Random single-byte flips anywhere in a
finished run file either change nothing ``open_run`` returns or are refused naming
what is damaged: never a different value, never a traceback.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from _corrupt import data_offset, data_ranges, flip
from conftest import base_scene, write_scene
from pyfold import report as report_module
from pyfold import run_checks, trajectory_fit
from pyfold.cli import main
from pyfold.errors import DamagedRunWarning, InputError, UnverifiedRunWarning
from pyfold.integrity import CHECKSUM_ATTR, RESULT_NAMES, DamagedRunError, verify_path
from pyfold.run_input import fixed_string
from pyfold.run_results import open_run

ROOT = Path(__file__).resolve().parents[2]
RECORDS = 151  # t_end 1.5, a record every step (dt = 0.01)
ROWS = 64  # entries per chunk of a growing dataset (fortran/io/fold_h5.f90, create_extendible)

#: case -> (dataset, entry flipped, whole records an --allow-damaged reader keeps)
CASES = {
    "a2 record": ("/a2", 100, 100 // ROWS * ROWS),
    "initial x": ("/initial/x", 3, RECORDS),
    "resolved dt": ("/setup/resolved/dt", 0, RECORDS),
    "time record": ("/time", 100, 100 // ROWS * ROWS),
}


class FitStarted(Exception):
    """Raised by the stand-in fit: the checks let the run through."""


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished run of real fold_run: 8 fibres, 150 steps, a record every step."""
    folder = tmp_path_factory.mktemp("damage")
    scene = base_scene()
    scene["numerics"]["t_end"] = 1.5
    scene["output"] = {"interval": 0.01, "snapshot_interval": 0.5}
    path = write_scene(folder / "scene.toml", scene)
    out = folder / "run.h5"
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("PYFOLD_FOLD_RUN", raising=False)
        assert main(["run", str(path), "-o", str(out)]) == 0
    with h5py.File(out) as f:
        assert f["a2"].shape[0] == RECORDS and int(f["checkpoint/step"][()]) <= 150
    assert verify_path(out).summary().startswith("verified:")
    return path, out


def _damaged_copy(finished, tmp_path, case, status=None) -> Path:
    _, src = finished
    path = tmp_path / "run.h5"
    shutil.copy(src, path)
    if status is not None:
        with h5py.File(path, "a") as f:
            f.attrs["status"] = fixed_string(status)
    name, entry, _ = CASES[case]
    flip(path, data_offset(path, name, entry) + 3)
    return path


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def no_fit(monkeypatch):
    """Any fit (pyfold analyse or pyfold report) that starts raises FitStarted, recording
    the records it was given."""
    seen = {}

    def fit(ds, *args, **kwargs):
        seen["time"] = np.asarray(ds["time"].values)
        seen["vars"] = set(ds.variables)
        raise FitStarted()

    monkeypatch.setattr(trajectory_fit, "fit_ci_per_closure", fit)
    monkeypatch.setattr(report_module, "analyse_run", lambda path, ds, *a, **k: fit(ds))
    return seen


@pytest.mark.parametrize("case", CASES)
def test_resume_refuses_a_damaged_file_naming_the_dataset(finished, tmp_path, case, capsys, monkeypatch):
    monkeypatch.delenv("PYFOLD_FOLD_RUN", raising=False)
    scene, _ = finished
    path = _damaged_copy(finished, tmp_path, case, status="failed: step 120, t = 1.2: killed")
    before = _sha(path)
    assert main(["run", str(scene), "-o", str(path), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "pyfold run: error:" in err and f"damaged: {CASES[case][0]}:" in err and "Traceback" not in err
    assert path.is_file() and _sha(path) == before and not path.with_name("run.h5.partial").exists()


@pytest.mark.parametrize("case", ["a2 record", "time record"])
def test_fold_run_resume_alone_refuses_a_damaged_record(finished, tmp_path, case):
    from pyfold.commands.run import find_fold_run

    path = _damaged_copy(finished, tmp_path, case)
    proc = subprocess.run([str(find_fold_run()), str(path), "--resume"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert f"{CASES[case][0]}: damaged" in proc.stderr and "Fletcher32" in proc.stderr


@pytest.mark.parametrize("command", ["analyse", "report"])
@pytest.mark.parametrize("case", CASES)
def test_analyse_and_report_refuse_a_damaged_file(finished, tmp_path, case, command, no_fit, capsys):
    path = _damaged_copy(finished, tmp_path, case)
    assert main([command, str(path), "--closures", "exact", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert f"pyfold {command}: error:" in err and f"damaged: {CASES[case][0]}:" in err and "--allow-damaged" in err
    out = tmp_path / "out"
    assert not no_fit and (not out.exists() or not any(out.iterdir()))  # nothing written


@pytest.mark.parametrize("command", ["analyse", "report"])
@pytest.mark.parametrize("case", CASES)
def test_allow_damaged_reads_the_intact_part(finished, tmp_path, case, command, no_fit, capsys):
    path = _damaged_copy(finished, tmp_path, case)
    with pytest.raises(FitStarted):
        main([command, str(path), "--closures", "exact", "--out", str(tmp_path / "out"), "--allow-damaged",
              "--force"])  # --force: the run is shorter than one Jeffery period
    err = capsys.readouterr().err
    name, _, kept = CASES[case]
    assert f"pyfold {command}: warning:" in err and f"damaged: {name}:" in err
    assert len(no_fit["time"]) == kept
    with h5py.File(finished[1]) as f:
        np.testing.assert_array_equal(no_fit["time"], f["time"][:kept])
    assert ("initial_x" in no_fit["vars"]) == (case != "initial x")


def test_open_run_allow_damaged_leaves_the_damaged_dataset_out(finished, tmp_path):
    path = _damaged_copy(finished, tmp_path, "resolved dt")
    with pytest.raises(DamagedRunError, match="/setup/resolved/dt"):
        open_run(path)
    with pytest.warns(DamagedRunWarning, match="/setup/resolved/dt"):
        ds = open_run(path, allow_damaged=True)
    assert "dt" not in ds.attrs and ds.sizes["time"] == RECORDS and ds.attrs["integrity"].startswith("damaged:")


def test_files_of_the_format_without_checksums_open_unverified(finished, tmp_path):
    path = tmp_path / "old.h5"
    shutil.copy(finished[1], path)
    with h5py.File(path, "a") as f:
        f.attrs["format_version"] = fixed_string("1.0")
        for group in ("setup", "setup/resolved", "initial"):
            for ds in f[group].values():
                if isinstance(ds, h5py.Dataset):
                    del ds.attrs[CHECKSUM_ATTR]
    with pytest.warns(UnverifiedRunWarning, match="no checksums: not verified"):
        ds = open_run(path)
    assert ds.attrs["integrity"] == "no checksums: not verified" and ds.sizes["time"] == RECORDS


def test_a_format_version_flipped_to_the_old_format_is_refused(finished, tmp_path):
    path = tmp_path / "flipped.h5"
    shutil.copy(finished[1], path)
    with h5py.File(path, "a") as f:
        f.attrs["format_version"] = fixed_string("1.0")
    with pytest.raises(DamagedRunError, match="attribute format_version"):
        open_run(path)


def test_a_lowered_record_count_of_a_finished_run_is_refused(finished, tmp_path):
    path = tmp_path / "count.h5"
    shutil.copy(finished[1], path)
    with h5py.File(path, "a") as f:
        f.attrs["records_complete"] = np.int64(RECORDS - 28)
    with pytest.raises(DamagedRunError, match=f"attribute records_complete: = {RECORDS - 28} in a finished run"):
        open_run(path)


def test_result_names_are_the_datasets_fold_output_writes():
    """RESULT_NAMES mirrors fortran/io/fold_output.f90 (its name lists and the tensors)."""
    text = (ROOT / "fortran" / "io" / "fold_output.f90").read_text()
    names = set()
    for block in ("SCALAR_VARS", "STOKES_VARS", "LUBRICATION_VARS", "SNAPSHOT_VARS", "SCALES"):
        match = re.search(block + r"\(\d+\) = \[character\(len=24\) :: (.*?)\]", text, re.S)
        assert match, block
        names |= set(re.findall(r'"([a-z0-9_]+)"', match.group(1)))
    tensors = re.search(r"names = \[character\(len=24\) :: \"time\", SCALAR_VARS, (.*?)\]", text).group(1)
    names |= {"time", "stress"} | set(re.findall(r'"([a-z0-9_]+)"', tensors))
    assert len(names) > 25 and names == set(RESULT_NAMES)


def _snapshot(ds) -> dict:
    """What open_run returns that is covered: every variable's values and the root and
    resolved attributes other than the free texts (pyfold.integrity: not covered)."""
    skip = {"creator", "created", "command", "fortran_creator", "mpi_ranks", "integrity"}
    out = {"var " + k: np.asarray(v.values) for k, v in ds.variables.items()}
    out.update({"attr " + k: v for k, v in ds.attrs.items() if k not in skip})
    return out


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype.kind != b.dtype.kind:
        return False
    return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))


def test_random_flips_change_nothing_read_or_are_refused(finished, tmp_path):
    """30 flips in the data of the datasets and 30 elsewhere (object headers, chunk
    indexes, heaps), seeded: each is refused naming what is damaged, or open_run returns
    exactly what it returns for the intact file (and pyfold analyse's checks pass it)."""
    src = finished[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = _snapshot(open_run(src))
    size = src.stat().st_size
    in_data = np.zeros(size, dtype=bool)
    for ranges in data_ranges(src).values():
        for offset, length in ranges:
            in_data[offset:offset + length] = True
    rng = np.random.default_rng(20261127)
    offsets = np.concatenate([rng.choice(np.flatnonzero(in_data), 30, replace=False),
                              rng.choice(np.flatnonzero(~in_data), 30, replace=False)])
    outcomes = {"same": 0, "refused": 0}
    for offset in offsets:
        path = tmp_path / "flipped.h5"
        shutil.copy(src, path)
        flip(path, int(offset), mask=1 << int(rng.integers(8)))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                got = _snapshot(open_run(path))
        except InputError as exc:
            assert re.search(r"damaged|not a pyfold run file|format_version", str(exc)), (offset, str(exc))
            outcomes["refused"] += 1
            continue
        differ = sorted(k for k in set(reference) | set(got)
                        if k not in reference or k not in got or not _same(reference[k], got[k]))
        assert not differ, f"byte {offset}: {differ[:5]} changed silently"
        with warnings.catch_warnings():  # and pyfold analyse's own checks of the file pass it
            warnings.simplefilter("ignore")
            assert run_checks.open_checked_run(path).sizes["time"] == RECORDS
        outcomes["same"] += 1
    # the flips in the data of what open_run reads are refused: not all outcomes are "same"
    assert outcomes["refused"] >= 10, outcomes


def test_xdmf_of_a_damaged_snapshot_time_is_a_message_and_no_file(finished, tmp_path):
    """write_xdmf reads /snapshot_time: a chunk failing its Fletcher32 checksum is named, no .xmf is left."""
    from pyfold.errors import PyfoldError
    from pyfold.run_results import write_xdmf

    _, src = finished
    path = tmp_path / "run.h5"
    shutil.copy(src, path)
    flip(path, data_offset(path, "/snapshot_time", 0) + 3)
    with pytest.raises(PyfoldError, match="/snapshot_time is damaged"):
        write_xdmf(path, tmp_path / "run.xmf")
    assert not list(tmp_path.glob("*.xmf")) and not list(tmp_path.glob(".pyfold-tmp-*"))


def test_a_result_laid_on_the_wrong_dimension_scale_is_refused(finished, tmp_path):
    """Dimension-scale references are metadata no chunk checksum covers: a2_family's family axis
    re-attached to the scale i (what one flipped bit of its DIMENSION_LIST can do) would read as
    (time, i, i, j), its values broadcast; it is refused naming the dataset and the axis."""
    path = tmp_path / "dims.h5"
    shutil.copy(finished[1], path)
    with h5py.File(path, "a") as f:
        ds = f["a2_family"]
        ds.dims[1].detach_scale(f["family"])
        ds.dims[1].attach_scale(f["i"])
    with pytest.raises(DamagedRunError, match=r"a2_family.*axis 1 has length 1 but its dimension scale /i"):
        open_run(path)


@pytest.mark.skipif(os.environ.get("HDF5_USE_FILE_LOCKING", "").upper() == "FALSE",
                    reason="HDF5 file locking is switched off in this environment: a reader never meets the lock")
def test_a_run_file_open_for_writing_elsewhere_is_named_as_such_not_as_damaged(finished, tmp_path, capsys):
    """A run file a live process holds open for writing (HDF5's exclusive file lock: a
    simulation still running) is refused with that process named, not reported as damaged."""
    import sys

    from pyfold.integrity import DamagedRunError

    path = tmp_path / "live.h5"
    shutil.copyfile(finished[1], path)
    holder = subprocess.Popen([sys.executable, "-c", "import h5py, sys, time\n"
                               f"f = h5py.File({str(path)!r}, 'a')\nprint('open', flush=True)\ntime.sleep(60)"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        with pytest.raises(InputError) as err:
            verify_path(path)
        assert not isinstance(err.value, DamagedRunError)
        assert "open for writing by" in str(err.value) and f"pid {holder.pid}" in str(err.value)
        assert main(["analyse", str(path), "--closures", "exact", "--out", str(tmp_path / "out")]) == 2
        assert "open for writing by" in capsys.readouterr().err
    finally:
        holder.kill()
        holder.wait()
    verify_path(path)  # readable again once the writer has gone
