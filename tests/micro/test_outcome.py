"""pyfold.outcome reads how a run ended from the outcome attributes fold_run writes
beside the human-readable status, and from the status text of older files."""
from __future__ import annotations

import math
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from pyfold.outcome import OUTCOMES, UNKNOWN_FAILURE, outcome_of, read_outcome, write_status_outcome
from pyfold.run_input import fixed_string
from pyfold.sweep import store

ROOT = Path(__file__).resolve().parents[2]


def test_outcome_names_are_those_of_the_fortran_writer():
    """One enumeration: the Python tuple lists fold_outcome's OUTCOME_NAMES in order."""
    source = (ROOT / "fortran/io/fold_outcome.f90").read_text()
    block = re.search(r"OUTCOME_NAMES\(0:\d+\) = \[character\(len=\d+\) :: &(.*?)\]", source, re.DOTALL)
    assert block is not None
    assert tuple(re.findall(r'"([a-z_]+)"', block.group(1))) == OUTCOMES


def _write(path: Path, status: str, **outcome) -> Path:
    with h5py.File(path, "w") as f:
        f.attrs["status"] = fixed_string(status)
        for name, value in outcome.items():
            f.attrs[name] = fixed_string(value) if isinstance(value, str) else value
    return path


def test_structured_attributes_are_read_as_written(tmp_path):
    path = _write(tmp_path / "r.h5", "failed: step 7, t = 7.0E-01: Stokes solver: not converged",
                  outcome="not_converged", outcome_step=np.int64(7), outcome_time=0.7,
                  outcome_cause="Stokes solver: not converged", outcome_residual=3e-4)
    o = read_outcome(path)
    assert (o.code, o.step, o.time, o.cause, o.residual) == ("not_converged", 7, 0.7,
                                                             "Stokes solver: not converged", 3e-4)
    assert not o.completed and not o.interrupted


def test_nan_residual_reads_none(tmp_path):
    path = _write(tmp_path / "r.h5", "ok", outcome="completed", outcome_step=np.int64(10), outcome_time=1.0,
                  outcome_cause="", outcome_residual=math.nan)
    o = read_outcome(path)
    assert o.completed and o.residual is None and o.step == 10


@pytest.mark.parametrize("status, code, step", [
    ("ok", "completed", None),
    ("running", "running", None),
    ("failed: step 3, t = 3.0000000000000000E-01: particle 2 would move 4.0 in one step", UNKNOWN_FAILURE, 3),
    ("failed: step 5, t = 5.0E-01: I/O: writing the outputs of step 5 failed: disk full", "io_error", 5),
    ("failed: fold_run exited with status 137 without recording a cause", "interrupted", None),
])
def test_files_without_outcome_attributes_are_read_from_the_status_text(tmp_path, status, code, step):
    o = read_outcome(_write(tmp_path / "old.h5", status))
    assert (o.code, o.step, o.status) == (code, step, status)


def test_outcome_running_beside_an_ended_status_goes_by_the_status(tmp_path):
    """A status recorded after the outcome (the outcome's flush refused) wins."""
    path = _write(tmp_path / "r.h5", "failed: step 2, t = 2.0E-01: I/O: writing failed", outcome="running",
                  outcome_step=np.int64(0), outcome_time=0.0, outcome_cause="", outcome_residual=math.nan)
    assert read_outcome(path).code == "io_error"


def test_status_rewritten_after_a_completed_outcome_goes_by_the_status(tmp_path):
    path = _write(tmp_path / "r.h5", "failed: step 8, t = 8.0E-01: NaN in the particle velocities",
                  outcome="completed", outcome_step=np.int64(10), outcome_time=1.0, outcome_cause="",
                  outcome_residual=math.nan)
    o = read_outcome(path)
    assert (o.code, o.step) == (UNKNOWN_FAILURE, 8) and not o.completed


def test_no_status_and_unreadable_file_read_none(tmp_path):
    with h5py.File(tmp_path / "empty.h5", "w"):
        pass
    assert read_outcome(tmp_path / "empty.h5") is None
    (tmp_path / "junk.h5").write_text("not hdf5")
    assert read_outcome(tmp_path / "junk.h5") is None
    assert outcome_of({}) is None


def test_status_written_for_a_killed_run_sets_its_outcome(tmp_path):
    path = _write(tmp_path / "r.h5", "running", outcome="running", outcome_step=np.int64(0), outcome_time=0.0,
                  outcome_cause="", outcome_residual=math.nan)
    text = "failed: fold_run exited with status 137 without recording a cause"
    with h5py.File(path, "a") as f:
        f.attrs["status"] = fixed_string(text)
        write_status_outcome(f.attrs, text)
    o = read_outcome(path)
    assert o.interrupted and o.status == text
    with h5py.File(path, "a") as f:  # a failure of unknown kind: no code of its own, the status says it
        f.attrs["status"] = fixed_string("failed: step 4, t = 4.0E-01: killed")
        write_status_outcome(f.attrs, "failed: step 4, t = 4.0E-01: killed")
        assert "outcome" not in f.attrs
    assert read_outcome(path).code == UNKNOWN_FAILURE


@pytest.mark.parametrize("outcome, state", [("completed", "done"), ("interrupted", "interrupted"),
                                            ("contact_cap", "failed"), ("blow_up", "failed")])
def test_sweep_run_state_follows_the_outcome(tmp_path, outcome, state):
    """The sweep's state of a run is read from the outcome code, not from the text."""
    folder = tmp_path / "runs" / "abc"
    folder.mkdir(parents=True)
    status = {"completed": "ok"}.get(outcome, "failed: some cause")
    _write(folder / store.RUN_FILE, status, outcome=outcome, outcome_step=np.int64(3),
           outcome_time=0.3, outcome_cause="cause", outcome_residual=math.nan)
    got = store.run_state(folder)
    assert (got.state, got.outcome) == (state, outcome)
    assert got.detail == ("" if state == "done" else status)
