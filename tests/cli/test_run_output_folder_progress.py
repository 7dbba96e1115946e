"""`pyfold run -o` creates its folder; plain progress lines when stderr is no terminal.

With the stand-in fold_run of conftest (orchestration only, no physics).
"""
from __future__ import annotations

import time

import pytest
from conftest import base_scene, write_scene

from pyfold.cli import main
from pyfold.progress import PlainProgress, check_interval, describe, latest_in_log, parse_line


@pytest.fixture
def scene(tmp_path):
    return write_scene(tmp_path / "scene.toml", base_scene())


def test_output_creates_its_folder_with_parents(scene, tmp_path, fake_fold_run, capsys):
    out = tmp_path / "new" / "deeper" / "run.h5"
    assert main(["run", str(scene), "-o", str(out)]) == 0, capsys.readouterr().err
    assert out.is_file() and out.with_suffix(".xmf").is_file()


def test_a_refused_run_leaves_no_new_folder(tmp_path, fake_fold_run, capsys):
    bad = base_scene()
    bad["numerics"]["dt"] = -1.0
    scene = write_scene(tmp_path / "bad.toml", bad)
    out = tmp_path / "made" / "run.h5"
    assert main(["run", str(scene), "-o", str(out)]) == 2
    assert "numerics.dt" in capsys.readouterr().err
    assert not (tmp_path / "made").exists()


def test_output_through_a_file_is_refused_clearly(scene, tmp_path, fake_fold_run, capsys):
    (tmp_path / "plain").write_text("")
    assert main(["run", str(scene), "-o", str(tmp_path / "plain" / "sub" / "run.h5")]) == 2
    err = capsys.readouterr().err
    assert "not a folder" in err and "Traceback" not in err
    assert not (tmp_path / "plain" / "sub").exists()


def test_progress_lines_without_a_terminal(scene, tmp_path, fake_fold_run, capsys):
    """capsys is no terminal: no bar, plain lines that say step, strain, ETA and load."""
    assert main(["run", str(scene), "-o", str(tmp_path / "run.h5"), "--progress-every", "1"]) == 0
    err = capsys.readouterr().err
    states = [parse_line(line) for line in err.splitlines() if parse_line(line)]
    assert states, err
    last = states[-1]
    assert last.step == last.total == 20 and last.percent == 100.0
    assert last.strain == pytest.approx(0.2, rel=1e-12)  # shear rate 1, t = 0.2
    assert "load " in err and "\x1b[" not in err  # no terminal control sequences in a log


@pytest.mark.parametrize("value", ["0", "-3", "nan", "1e9"])
def test_bad_progress_interval_is_refused(scene, tmp_path, fake_fold_run, capsys, value):
    assert main(["run", str(scene), "-o", str(tmp_path / "run.h5"), "--progress-every", value]) == 2
    err = capsys.readouterr().err
    assert "--progress-every" in err and "[1, 86400]" in err
    assert not (tmp_path / "run.h5").exists()


def test_bad_progress_environment_is_refused(scene, tmp_path, fake_fold_run, capsys, monkeypatch):
    monkeypatch.setenv("PYFOLD_PROGRESS_EVERY", "soon")
    assert main(["run", str(scene), "-o", str(tmp_path / "run.h5")]) == 2
    assert "$PYFOLD_PROGRESS_EVERY" in capsys.readouterr().err


def test_plain_progress_writes_at_a_steady_rate():
    """Lines come from a timer, not from the run's own PROGRESS lines: with no new state
    for 10 intervals there are still about 10 lines."""
    lines: list[str] = []
    interval = 0.05
    with PlainProgress(lines.append, 100, 2.0, interval) as progress:
        progress.update(10, 100, 5.0)
        time.sleep(10 * interval)
    # timer lines in 10 intervals (a loaded machine may delay a few) + the final one
    assert 4 <= len(lines) <= 12
    state = parse_line(lines[-1])
    assert (state.step, state.total, state.t, state.strain) == (10, 100, 5.0, 10.0)


def test_eta_extrapolates_the_steps_of_this_process():
    now = [0.0]
    lines: list[str] = []
    progress = PlainProgress(lines.append, 1000, 1.0, 3600.0, clock=lambda: now[0])
    progress.update(500, 1000, 50.0)  # a resumed run starts at step 500
    now[0] = 10.0
    progress.update(600, 1000, 60.0)  # 100 steps in 10 s: 400 left take 40 s
    progress.write()
    assert parse_line(lines[-1]).eta == pytest.approx(40.0)


def test_main_reads_the_latest_progress_of_each_seed(tmp_path):
    log = tmp_path / "seed_1.log"
    log.write_text("pyfold run: progress step 10/40 (25.0 %), t = 1, strain 1, elapsed 3 s, ETA 9 s, load 1 1 1\n"
                   "a warning line\n"
                   "pyfold run: progress step 20/40 (50.0 %), t = 2, strain 2, elapsed 6 s, ETA 6 s, load 1 1 1\n")
    assert describe("seed 1", latest_in_log(log)) == "seed 1: step 20/40 (50.0 %), strain 2, ETA 6 s"
    assert "starting" in describe("seed 2", latest_in_log(tmp_path / "missing.log"))


def test_check_interval_bounds():
    assert check_interval(1.0) == 1.0
    with pytest.raises(Exception, match="--progress-every"):
        check_interval(0.5)
