"""Helpers of the sweep tests: the pyfold command, the bundled sweep, sweep files, polling,
and the fixtures (imported by the test modules: a conftest.py here would shadow
tests/cli's, which its modules import by name) of a stand-in fold_run and a
single-node Slurm started by scripts/slurm_local."""
from __future__ import annotations

import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "sweeps" / "example.toml"
EXAMPLE_SCENE = ROOT / "data" / "sweeps" / "example_scene.toml"
SLURM_LOCAL = ROOT / "scripts" / "slurm_local"
CLI_TESTS = ROOT / "tests" / "cli"
#: Exit status of scripts/slurm_local when the packages cannot be installed here.
SLURM_UNAVAILABLE = 3


def pyfold(*args: str, env: dict | None = None, timeout: float = 900, cwd: Path | None = None
           ) -> subprocess.CompletedProcess:
    """``pyfold ARGS`` in a fresh interpreter (exit status, stdout, stderr)."""
    return subprocess.run([sys.executable, "-m", "pyfold.cli", *args], capture_output=True, text=True,
                          timeout=timeout, env=env or dict(os.environ), cwd=cwd)


def no_traceback(proc: subprocess.CompletedProcess) -> None:
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr


def write_sweep(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def example_sweep(folder: Path, t_end: float = 20.0, counts: tuple[int, ...] = (24, 48),
                  seeds: tuple[int, ...] = (1, 2), extra: str = "") -> Path:
    """A sweep over the bundled example scene (its file in ``folder``), with its own strain."""
    return write_sweep(folder / "sweep.toml", f'''[sweep]
name = "test"
scene = "{EXAMPLE_SCENE}"
seeds = {list(seeds)}

[arguments]
"numerics.t_end" = {t_end!r}
"output.checkpoint_interval" = {t_end / 10!r}
"output.snapshot_interval" = {t_end!r}

[axes]
"particles[0].count" = {list(counts)}
{extra}''')


def wait_for(predicate, timeout: float, what: str, step: float = 0.2):
    """Poll ``predicate`` until it returns something true; fail naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


@pytest.fixture
def fake_fold_run(tmp_path, monkeypatch):
    """PYFOLD_FOLD_RUN -> tests/cli/_fake_fold_run.py (exit status from $FAKE_FOLD_RUN_EXIT)."""
    script = tmp_path / "fake_bin" / "fold_run"
    script.parent.mkdir()
    script.write_text(f"#!/bin/sh\nexec {sys.executable} {CLI_TESTS / '_fake_fold_run.py'} \"$@\"\n")
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PYFOLD_FOLD_RUN", str(script))
    monkeypatch.setenv("PYTHONPATH", str(CLI_TESTS) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return script


@pytest.fixture(scope="session")
def slurm():
    """A running single-node Slurm (scripts/slurm_local start); the environment for its commands.
    Skipped, saying why, only where its packages cannot be installed."""
    was_running = subprocess.run(["bash", str(SLURM_LOCAL), "status"], capture_output=True, text=True,
                                 timeout=60).returncode == 0
    proc = subprocess.run(["bash", str(SLURM_LOCAL), "start"], capture_output=True, text=True, timeout=900)
    if proc.returncode == SLURM_UNAVAILABLE:
        pytest.skip(f"Slurm cannot be installed on this machine: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stderr
    conf = proc.stdout.strip().split("=", 1)[1]
    env = dict(os.environ, SLURM_CONF=conf)
    yield env
    if not was_running:  # leave the machine as found
        subprocess.run(["bash", str(SLURM_LOCAL), "stop"], capture_output=True, text=True, timeout=120)
