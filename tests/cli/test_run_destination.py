"""The destination of `pyfold run -o OUT.h5` (and `report --out` / `main --out`) is
written by one process at a time and nothing else is lost there: a second writer
(a second run, a concurrent --resume) is refused with exit 2 naming the holder's pid
and host while the first completes with a correct file; the lock dies with its
holder (SIGKILL) but lives as long as an orphaned fold_run; links at output names
are replaced, never written through; the scene is never an output; an interruption
after the final rename does not report failure; -o "" and names beyond NAME_MAX are
refused; a run file held open by a reader is named as such for --resume."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import base_scene, write_scene
from pyfold.cli import main

HOST = socket.gethostname()
#: Results of the stand-in fold_run compared bit for bit with an undisturbed run.
COMPARED = ("time", "a2", "x", "p")


@pytest.fixture
def scene(tmp_path):
    return write_scene(tmp_path / "fibres.toml", base_scene())


def _pyfold(*args: str, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pyfold.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, **(env or {})))


def _wait_for(predicate, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"{what} did not happen within {timeout} s"
        time.sleep(0.05)


def _lock_recorded(out: Path, pid: int) -> bool:
    lock = out.with_name(out.name + ".lock")
    try:
        return f'"pid": {pid}' in lock.read_text()
    except OSError:
        return False


def _same_results(a: Path, b: Path) -> None:
    with h5py.File(a) as fa, h5py.File(b) as fb:
        assert fb.attrs["status"] == "ok"
        for name in COMPARED:
            np.testing.assert_array_equal(fa[name][()], fb[name][()], err_msg=name)


def _holder(target: Path) -> subprocess.Popen:
    """Another process holding the destination lock of ``target`` (as a pyfold command would)."""
    code = ("import sys, time; from pathlib import Path; from pyfold.destination import acquire; "
            f"lock = acquire(Path({str(target)!r}), '-o', command='stand-in holder'); "
            "print('locked', flush=True); time.sleep(600)")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.wait()


# one writer per destination ----------------------------------------------------------

def test_two_concurrent_runs_one_completes_the_other_refused_naming_it(scene, tmp_path, fake_fold_run):
    """`pyfold run k.toml -o two.h5 &` twice: one run completes with the right results,
    the other exits 2 at once naming the winner's pid and host, never touching its files."""
    out, ref = tmp_path / "two.h5", tmp_path / "ref.h5"
    procs = [_pyfold("run", str(scene), "-o", str(out), env={"FAKE_FOLD_RUN_SLEEP": "3"}) for _ in range(2)]
    results = [(p.pid, *p.communicate(timeout=120), p.returncode) for p in procs]
    codes = sorted(r[3] for r in results)
    assert codes == [0, 2], results
    winner = next(r for r in results if r[3] == 0)
    loser = next(r for r in results if r[3] == 2)
    assert f"pid {winner[0]} on host {HOST}" in loser[2] and "-o" in loser[2], loser[2]
    assert "Traceback" not in loser[2] and "kept for inspection" not in loser[2]
    assert main(["run", str(scene), "-o", str(ref)]) == 0
    _same_results(ref, out)
    assert sorted(p.name for p in tmp_path.glob("two*")) == ["two.h5", "two.xmf", "two.xmf.h5"]  # lock removed by its holder


def test_concurrent_resume_refused_while_the_first_completes(scene, tmp_path, fake_fold_run):
    from pyfold.run_input import write_run_file
    from pyfold.scene import load_scene
    from pyfold.scene.initial import initial_state

    out, partial, ref = tmp_path / "r.h5", tmp_path / "r.h5.partial", tmp_path / "ref.h5"
    resolved = load_scene(scene)
    write_run_file(partial, resolved, initial_state(resolved), "pyfold run (interrupted)")
    first = _pyfold("run", str(scene), "-o", str(out), "--resume", env={"FAKE_FOLD_RUN_SLEEP": "3"})
    try:
        _wait_for(lambda: _lock_recorded(out, first.pid) or first.poll() is not None, "the first --resume's lock")
        assert main(["run", str(scene), "-o", str(out), "--resume"]) == 2
    finally:
        _, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    assert main(["run", str(scene), "-o", str(ref)]) == 0
    _same_results(ref, out)
    assert not partial.exists()


def test_run_refused_while_another_process_holds_the_lock(scene, tmp_path, fake_fold_run, capsys):
    out = tmp_path / "held.h5"
    holder = _holder(out)
    try:
        assert main(["run", str(scene), "-o", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"pid {holder.pid} on host {HOST}" in err and "stand-in holder" in err and "-o" in err
        assert not out.exists() and not (tmp_path / "held.h5.partial").exists()
        assert main(["run", str(scene), "-o", str(out), "--force"]) == 2  # --force does not break a lock
    finally:
        _kill(holder)
    # SIGKILLed holder: the kernel dropped its lock; its lock file is left behind, harmlessly
    assert (tmp_path / "held.h5.lock").exists()
    assert main(["run", str(scene), "-o", str(out)]) == 0
    assert out.is_file() and not (tmp_path / "held.h5.lock").exists()


def _processes_mentioning(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if text in cmdline and state != "Z" and int(entry.name) != os.getpid():
                found.append(int(entry.name))
    return found


@pytest.mark.skipif(sys.platform != "linux", reason="/proc scan")
def test_orphaned_fold_run_of_a_killed_pyfold_keeps_the_destination_locked(scene, tmp_path, fake_fold_run, capsys):
    out = tmp_path / "orphan.h5"
    partial = str(out) + ".partial"
    pyfold = _pyfold("run", str(scene), "-o", str(out), env={"FAKE_FOLD_RUN_SLEEP": "60"})
    try:
        _wait_for(lambda: any("_fake_fold_run" in Path(f"/proc/{p}/cmdline").read_text(errors="replace")
                              for p in _processes_mentioning(partial)), "the stand-in fold_run")
        pyfold.send_signal(signal.SIGKILL)  # pyfold alone: its fold_run (own session) lives on
        pyfold.wait()
        assert _processes_mentioning(partial)
        assert main(["run", str(scene), "-o", str(out), "--force"]) == 2
        err = capsys.readouterr().err
        assert f"pid {pyfold.pid} on host {HOST}" in err and "has ended" in err and "fold_run" in err
    finally:
        _kill(pyfold)
        for pid in _processes_mentioning(partial):
            os.kill(pid, signal.SIGKILL)
    _wait_for(lambda: not _processes_mentioning(partial), "the end of the orphan", timeout=10)
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 0  # its writer gone: the lock with it


def test_report_and_main_folders_locked(tmp_path, monkeypatch, capsys):
    """A second `pyfold report --out DIR` / `pyfold main --out DIR` is refused naming the
    holder before it reads or writes anything; once the holder is killed it goes ahead."""
    import pyfold.commands.main_job as main_job
    import pyfold.report as report

    calls = []

    def fake_report(paths, out, closures, **kwargs):
        out.mkdir(parents=True, exist_ok=True)
        (out / "summary.txt").write_text("stand-in report\n")
        calls.append(out)
        return None, []

    def fake_job(work, scene, processes, n_seeds, closures, fluid=False):
        (work / "summary.txt").write_text("stand-in job\n")
        calls.append(work)

    monkeypatch.setattr(report, "report", fake_report)
    monkeypatch.setattr(report, "summary_lines", lambda rep: [])
    monkeypatch.setattr(main_job, "_job", fake_job)
    rep_out, main_out = tmp_path / "new" / "rep", tmp_path / "main"  # a new parent folder is made, as before
    for argv, target in ((["report", str(tmp_path / "run.h5"), "--out", str(rep_out)], rep_out),
                         (["main", "--out", str(main_out), "--seeds", "1", "--np", "1"], main_out)):
        assert main(argv) == 0, capsys.readouterr().err  # nobody holds it (the folders are made)
        holder = _holder(target)
        try:
            assert main(argv) == 2
            err = capsys.readouterr().err
            assert f"pid {holder.pid} on host {HOST}" in err and "--out" in err, err
            assert len(calls) == 1  # refused before the report / job
        finally:
            _kill(holder)
        assert main(argv) == 0, capsys.readouterr().err
        assert len(calls) == 2 and not target.with_name(target.name + ".lock").exists()
        calls.clear()
    assert (rep_out / "summary.txt").read_text() == "stand-in report\n"
    assert (main_out / "latest" / "summary.txt").read_text() == "stand-in job\n"


# links, and the scene as an output -------------------------------------------------

@pytest.mark.parametrize("name", ["x.h5.partial", "x.xmf", "x.h5"])
def test_a_link_at_an_output_name_is_replaced_never_written_through(scene, tmp_path, fake_fold_run, capsys, name):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    link = tmp_path / name
    link.symlink_to(victim.name)
    out = tmp_path / "x.h5"
    assert main(["run", str(scene), "-o", str(out)]) == 2  # like an existing file: refused without --force
    err = capsys.readouterr().err
    assert name in err and "symbolic link" in err and "--force" in err
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 0
    assert victim.read_text() == "precious"
    for path in (out, tmp_path / "x.xmf"):
        assert path.is_file() and not path.is_symlink()
    assert not os.path.lexists(tmp_path / "x.h5.partial")


def test_resume_of_a_link_refused(scene, tmp_path, fake_fold_run, capsys):
    real = tmp_path / "elsewhere.h5.partial"
    real.write_bytes(b"not ours to write through")
    (tmp_path / "x.h5.partial").symlink_to(real.name)
    assert main(["run", str(scene), "-o", str(tmp_path / "x.h5"), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and "symbolic link" in err and str(real) in err
    assert real.read_bytes() == b"not ours to write through"


@pytest.mark.parametrize("how", ["same", "hard link", "symbolic link", "partial"])
def test_the_scene_is_never_an_output(tmp_path, fake_fold_run, capsys, how):
    scene = write_scene(tmp_path / "scene.h5", base_scene())  # a scene file with a run-file suffix
    text = scene.read_text()
    out = {"same": scene, "hard link": tmp_path / "hard.h5", "symbolic link": tmp_path / "soft.h5",
           "partial": tmp_path / "p.h5"}[how]
    if how == "hard link":
        os.link(scene, out)
    elif how == "symbolic link":
        out.symlink_to(scene.name)
    elif how == "partial":
        os.link(scene, tmp_path / "p.h5.partial")
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 2
    err = capsys.readouterr().err
    assert "-o" in err and str(scene) in err and "scene file" in err
    assert scene.read_text() == text


# small ones ------------------------------------------------------------------------

def test_sigterm_after_the_final_rename_is_not_a_failure(scene, tmp_path, fake_fold_run, monkeypatch, capsys):
    """SIGTERM arriving once OUT.h5 is complete and in place (here: while its XDMF is
    written): exit 0 with the XDMF and summary finished, not 143."""
    import pyfold.run_results

    original = pyfold.run_results.write_xdmf
    sent = []

    def write_xdmf_signalled(path, xmf=None):
        if not sent:
            sent.append(True)
            os.kill(os.getpid(), signal.SIGTERM)  # pyfold.cli's handler raises Interrupted here
            time.sleep(1.0)
        return original(path, xmf)

    monkeypatch.setattr(pyfold.run_results, "write_xdmf", write_xdmf_signalled)
    out = tmp_path / "late.h5"
    assert main(["run", str(scene), "-o", str(out)]) == 0
    assert sent
    err = capsys.readouterr().err
    assert "interrupted after" in err
    with h5py.File(out) as f:
        assert f.attrs["status"] == "ok"
    assert "<Xdmf" in (tmp_path / "late.xmf").read_text()
    assert not (tmp_path / "late.h5.partial").exists()


def test_empty_output_refused(scene, tmp_path, fake_fold_run, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "-o", ""]) == 2
    assert "-o: empty path" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fibres.toml", "fold_run"]


def test_output_name_beyond_name_max_refused(scene, tmp_path, fake_fold_run, capsys):
    """The name with the ".partial" the run adds must fit NAME_MAX of the folder: a name
    3 bytes short of it is refused naming -o and the limit; the longest that fits runs."""
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    too_long = tmp_path / ("a" * (limit - 3 - len(".h5")) + ".h5")
    assert main(["run", str(scene), "-o", str(too_long)]) == 2
    err = capsys.readouterr().err
    assert "-o" in err and str(limit) in err and "NAME_MAX" in err and "Traceback" not in err
    longest = tmp_path / ("b" * (limit - len(".partial") - len(".h5")) + ".h5")
    assert main(["run", str(scene), "-o", str(longest)]) == 0, capsys.readouterr().err
    assert longest.is_file()


def test_resume_of_a_file_open_in_a_reader_names_the_reader(scene, tmp_path, fake_fold_run, capsys):
    """A run file held open by a reader (an xarray dataset from pyfold.open_run not yet
    closed) is locked, not damaged: --resume says so, names the remedy, leaves it as it is."""
    from pyfold.run_input import fixed_string, write_run_file
    from pyfold.scene import load_scene
    from pyfold.scene.initial import initial_state

    out = tmp_path / "open.h5"
    resolved = load_scene(scene)
    write_run_file(out, resolved, initial_state(resolved), "pyfold run (failed)")
    with h5py.File(out, "a") as f:
        f.attrs["status"] = fixed_string("failed: step 0: stand-in")
    before = out.read_bytes()
    reader = subprocess.Popen([sys.executable, "-c", f"import h5py, time; f = h5py.File({str(out)!r}, 'r'); "
                               "print('open', flush=True); time.sleep(600)"], stdout=subprocess.PIPE, text=True)
    try:
        assert reader.stdout.readline().strip() == "open"
        assert main(["run", str(scene), "-o", str(out), "--resume"]) == 2
        err = capsys.readouterr().err
        assert "--resume" in err and "not damaged" in err and "ds.close()" in err and f"pid {reader.pid}" in err
        assert "damaged?" not in err
        assert out.read_bytes() == before and not (tmp_path / "open.h5.partial").exists()
    finally:
        _kill(reader)
    assert main(["run", str(scene), "-o", str(out), "--resume"]) == 0  # closed: it resumes


def test_a_link_at_the_lock_file_is_refused_its_target_untouched(scene, tmp_path, fake_fold_run, capsys):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "x.h5.lock").symlink_to(victim.name)
    assert main(["run", str(scene), "-o", str(tmp_path / "x.h5"), "--force"]) == 2
    err = capsys.readouterr().err
    assert "-o" in err and "x.h5.lock" in err and "symbolic link" in err
    assert victim.read_text() == "precious" and not (tmp_path / "x.h5").exists()


def test_a_reader_opening_the_partial_file_under_fold_run_is_named_not_damaged(scene, tmp_path, monkeypatch, capsys):
    """A reader that opens OUT.h5.partial between pyfold's check and fold_run's open makes
    fold_run fail to lock it ("Resource temporarily unavailable"): named as a reader, exit 2."""
    readers = tmp_path / "reader.pid"
    script = tmp_path / "fold_run"
    script.write_text(
        f"#!{sys.executable}\n"
        "import subprocess, sys, time\n"
        "reader = subprocess.Popen([sys.executable, '-c', 'import h5py, sys, time; f = h5py.File(sys.argv[1], \"r\"); "
        "print(1, flush=True); time.sleep(600)', sys.argv[1]], stdout=subprocess.PIPE, start_new_session=True)\n"
        "reader.stdout.readline()\n"
        f"open({str(readers)!r}, 'w').write(str(reader.pid))\n"
        "print(f'fold_run: bad run file {sys.argv[1]}: cannot open {sys.argv[1]} as an HDF5 file '\n"
        "      '(Resource temporarily unavailable) (damaged?)', file=sys.stderr)\n"
        "sys.exit(2)\n")
    script.chmod(0o755)
    monkeypatch.setenv("PYFOLD_FOLD_RUN", str(script))
    out = tmp_path / "x.h5"
    try:
        assert main(["run", str(scene), "-o", str(out)]) == 2
        err = capsys.readouterr().err
        pid = int(readers.read_text())
        assert f"pid {pid}" in err and "not damaged" in err and "--resume" in err, err
    finally:
        if readers.exists():
            os.kill(int(readers.read_text()), signal.SIGKILL)
    assert (tmp_path / "x.h5.partial").is_file()  # kept for --resume
