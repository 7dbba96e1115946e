"""The job files that study scripts generate for a batch scheduler run pyfold and
nothing else, with exactly the paths they were given.

Each generator (studies/closures_vs_dns/closure_verdict.py --write-scenes,
studies/interaction_coefficient/ci_concentration.py --emit-scenes,
studies/interaction_coefficient/ci_hydrodynamics.py --write-scenes) is run in its
cheapest form (write scenes and commands, simulate nothing) on folder names holding
spaces, single and double quotes, ``;``, ``$(...)``, backticks and a leading ``-``,
from an interpreter whose own folder is just as hostile (the lines call the pyfold
beside the interpreter). The job file is then run by ``sh`` in a sandbox, whole and
line by line as a scheduler's array task would, with stand-ins first on PATH that
record their argv. Checked: no injected ``touch`` created its file, nothing but the
stand-in pyfold ran, and each recorded argv is the intended argument list byte for
byte (a relative path starting with ``-`` with ``./`` in front: the same file, and no
option to pyfold's parser). A line break in a path is refused with exit 2 before
anything is written (a job file holds one command per line).
"""
from __future__ import annotations

import os
import shlex
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from pyfold.cli import build_parser
from pyfold.command_line import command_line, job_line, path_argument
from pyfold.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
STUDIES = ROOT / "studies"

#: Every injection names its own side-effect file "pwned-*", created in the sandbox
#: (the working directory of sh) if the shell ever runs it.
INJECTIONS = ("semi;touch pwned-semicolon;#", "$(touch pwned-substitution)", "`touch pwned-backtick`",
              "amp&&touch pwned-and|x")
HOSTILE_PARTS = ("-lead dash", "two  spaces", *INJECTIONS, "it's \"quoted\"")
#: One relative folder holding every hostile component (the leading '-' first).
HOSTILE = os.path.join(*HOSTILE_PARTS)
#: Folder of the interpreter that runs the generator (its bin/pyfold is what the lines call).
HOSTILE_VENV = "venv 'v' \"q\" $(touch pwned-venv) `touch pwned-venv-tick`;touch pwned-venv-semi"

#: Run a study script as `python SCRIPT ARGS` would, with sys.executable set to argv[1].
_RUN_AS = ("import runpy, sys; sys.executable = sys.argv[1]; sys.argv = sys.argv[2:]; "
           "sys.path.insert(0, sys.argv[0].rpartition('/')[0]); runpy.run_path(sys.argv[0], run_name='__main__')")

#: Records "$0", "$#" and every argument, NUL-separated (byte exact, line breaks included).
_RECORDER = "#!/bin/sh\n{ printf '%s\\0' \"$0\" \"$#\"; printf '%s\\0' \"$@\"; } >> \"$RECORD\"\n"


def _recorder(path: Path, record: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(_RECORDER.replace("$RECORD", shlex.quote(str(record))), encoding="utf-8")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def _calls(record: Path) -> list[tuple[str, list[str]]]:
    """(program, argv) of every call a recorder logged, in order."""
    if not record.exists():
        return []
    items = record.read_bytes().split(b"\0")
    assert items[-1] == b""
    items, calls = [i.decode() for i in items[:-1]], []
    while items:
        prog, n = items[0], int(items[1])
        calls.append((prog, items[2:2 + n]))
        items = items[2 + n:]
    return calls


class Sandbox:
    """A working directory with a hostile venv folder holding the recording pyfold, and
    stand-ins for pyfold, mpirun, python, python3 and fold_run first on PATH that log
    to a separate record (any call to them is a stray)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.cwd = root / "work"
        self.cwd.mkdir()
        self.pyfold_record = root / "pyfold.argv"
        self.stray_record = root / "stray.argv"
        self.python = self.cwd / HOSTILE_VENV / "bin" / "python"
        self.pyfold = _recorder(self.python.parent / "pyfold", self.pyfold_record)
        self.fake_bin = root / "fake bin"
        for name in ("pyfold", "mpirun", "python", "python3", "fold_run"):
            _recorder(self.fake_bin / name, self.stray_record)
        self.env = dict(os.environ, PATH=f"{self.fake_bin}{os.pathsep}/usr/bin{os.pathsep}/bin")

    def generate(self, script: str, *args: str) -> subprocess.CompletedProcess:
        """Run a study script with the sandbox as working directory and its venv's python."""
        return subprocess.run([sys.executable, "-c", _RUN_AS, str(self.python), str(STUDIES / script), *args],
                              cwd=self.cwd, capture_output=True, text=True, timeout=300)

    def sh(self, *, file: Path | None = None, line: str | None = None, check: bool = True) -> None:
        """`sh FILE`, or one line on sh's stdin (`sed -n Np FILE | sh`)."""
        proc = subprocess.run(["sh"] + ([str(file)] if file else []), input=line, cwd=self.cwd, env=self.env,
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0 or not check, proc.stderr

    def pwned(self) -> list[Path]:
        return sorted(p for p in self.root.rglob("*") if p.name.startswith("pwned"))

    def reset(self) -> None:
        self.pyfold_record.unlink(missing_ok=True)


def _expected(scene_folder: str, out_folder: str, names: list[str], ranks: int) -> list[list[str]]:
    """The intended argv of each run, the relative folders given with './' before a leading '-'."""
    def arg(folder: str, file: str) -> str:
        text = os.path.join(folder, file)
        return "./" + text if text.startswith("-") else text

    return [["run", arg(scene_folder, f"{n}.toml"), "-o", arg(out_folder, f"{n}.h5"), "--np", str(ranks)]
            for n in names]


def _check_runs(box: Sandbox, lines_source: Path | str, scene_folder: str, out_folder: str, ranks: int) -> None:
    scenes = sorted(p.stem for p in (box.cwd / scene_folder).glob("*.toml"))
    assert scenes, f"no scenes written to {scene_folder!r}"
    expected = sorted(_expected(scene_folder, out_folder, scenes, ranks))
    text = lines_source.read_text(encoding="utf-8") if isinstance(lines_source, Path) else lines_source
    lines = text.splitlines()
    assert len(lines) == len(scenes), "one command per line and run"

    # the whole file, as `sh commands.txt`
    job_file = lines_source if isinstance(lines_source, Path) else box.root / "printed.txt"
    job_file.write_text(text, encoding="utf-8")
    box.sh(file=job_file)
    calls = _calls(box.pyfold_record)
    assert box.pwned() == [], "an injected command ran"
    assert _calls(box.stray_record) == [], "a program other than the venv's pyfold ran"
    assert [prog for prog, _ in calls] == [str(box.pyfold)] * len(scenes)
    assert sorted(argv for _, argv in calls) == expected

    # line by line, as an array task: each line alone runs exactly one pyfold
    for line in lines:
        box.reset()
        box.sh(line=line + "\n")
        assert len(_calls(box.pyfold_record)) == 1
    assert box.pwned() == [] and _calls(box.stray_record) == []

    # pyfold's own parser reads each recorded argv as that scene and output (no path is an option)
    for argv in expected:
        args = build_parser().parse_args(argv)
        assert (box.cwd / args.scene).is_file()
        assert args.output == argv[3] and args.np == ranks


@pytest.fixture
def box(tmp_path) -> Sandbox:
    return Sandbox(tmp_path)


@pytest.mark.parametrize("part", INJECTIONS)
def test_sandbox_detects_each_injection_of_an_unquoted_line(box, part):
    """The checks can fail: each injection, written unquoted as the generators once did,
    creates its file, and pyfold does not get the path."""
    box.sh(line=f"{shlex.quote(str(box.pyfold))} run {part}/x.toml\n", check=False)
    assert len(box.pwned()) == 1
    assert [argv for _, argv in _calls(box.pyfold_record)] != [["run", f"{part}/x.toml"]]


def test_closure_verdict_commands_run_only_pyfold_on_the_given_paths(box):
    proc = box.generate("closures_vs_dns/closure_verdict.py", "--write-scenes", "--seeds", "1", "2",
                        "--np", "2", f"--run-folder={HOSTILE}", "--out", "verdict out")
    assert proc.returncode == 0, proc.stderr
    _check_runs(box, box.cwd / HOSTILE / "commands.txt", HOSTILE, HOSTILE, ranks=2)


def test_ci_concentration_jobs_run_only_pyfold_on_the_given_paths(box):
    scenes, out = os.path.join(HOSTILE, "scenes"), os.path.join(HOSTILE, "out dir")
    proc = box.generate("interaction_coefficient/ci_concentration.py", f"--emit-scenes={scenes}", f"--out={out}",
                        "--seeds", "1", "--np", "3")
    assert proc.returncode == 0, proc.stderr
    _check_runs(box, box.cwd / scenes / "jobs.txt", scenes, os.path.join(out, "runs"), ranks=3)


def test_ci_hydrodynamics_printed_commands_run_only_pyfold_on_the_given_paths(box):
    proc = box.generate("interaction_coefficient/ci_hydrodynamics.py", "--write-scenes", f"--out={HOSTILE}",
                        "--seeds", "1", "2", "--np", "2")
    assert proc.returncode == 0, proc.stderr
    runs = os.path.join(HOSTILE, "runs")
    _check_runs(box, proc.stdout, runs, runs, ranks=2)


@pytest.mark.parametrize("script, args, option", [
    ("closures_vs_dns/closure_verdict.py", ["--write-scenes", "--run-folder=a\nb"], "--run-folder"),
    ("interaction_coefficient/ci_concentration.py", ["--emit-scenes=a\nb"], "--emit-scenes"),
    ("interaction_coefficient/ci_concentration.py", ["--emit-scenes=jobs", "--out=a\rb"], "--out"),
    ("interaction_coefficient/ci_hydrodynamics.py", ["--write-scenes", "--out=a\nb"], "--out"),
])
def test_generator_refuses_a_line_break_in_a_job_path_and_writes_nothing(box, script, args, option):
    before = sorted(box.cwd.rglob("*"))
    proc = box.generate(script, *args)
    assert proc.returncode == 2, proc.stderr
    assert f"error: {option}: " in proc.stderr and "line break" in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    assert sorted(box.cwd.rglob("*")) == before


# The helper itself


@pytest.mark.parametrize("part", HOSTILE_PARTS + ("new\nline", "tab\there", "", "ünï cødé"))
def test_command_line_round_trips_every_argument_through_sh(tmp_path, part):
    record = tmp_path / "argv"
    prog = _recorder(tmp_path / "p r'o\"g" / "pyfold", record)
    argv = [prog, "run", part, Path(part or "."), "--np", "1"]
    proc = subprocess.run(["sh", "-c", command_line(argv)], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert list(tmp_path.glob("pwned*")) == []
    assert _calls(record) == [(str(prog), ["run", part, path_argument(Path(part or ".")), "--np", "1"])]


def test_path_argument_guards_only_a_leading_dash():
    assert path_argument(Path("-x/y.toml")) == "./-x/y.toml"
    assert path_argument(Path("/abs/-x")) == "/abs/-x"
    assert path_argument("a -b") == "a -b"
    assert command_line(["-s", Path("-p")]) == "-s ./-p"  # strings (options) are kept as given


def test_job_line_calls_the_venv_pyfold_or_pyfold_on_path(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "executable", str(tmp_path / "a b" / "python"))
    assert job_line(["run", "x"]) == "pyfold run x"  # no launcher beside the interpreter
    launcher = _recorder(tmp_path / "a b" / "pyfold", tmp_path / "argv")
    assert job_line(["run", "x"]) == f"{shlex.quote(str(launcher))} run x"


def test_job_line_refuses_a_line_break():
    with pytest.raises(InputError, match="line break"):
        job_line(["run", Path("a\nb.toml")])
