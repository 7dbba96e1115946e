"""scripts/ninja-serial, the build command of the editable install: concurrent calls run one
at a time (two ninjas in one build folder corrupt its logs and fail the import that started
them), arguments and exit status pass through, and scripts/bootstrap installs pyfold with it."""
from __future__ import annotations

import glob
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
WRAPPER = ROOT / "scripts" / "ninja-serial"


def _fake_ninja(tmp_path: Path) -> Path:
    """A stand-in for ninja that records when it ran and with what, holds for 0.4 s, and exits
    with the status named by its first argument."""
    fake = tmp_path / "fake-ninja"
    fake.write_text("#!/usr/bin/env bash\n"
                    f"echo \"start $(date +%s.%N) $*\" >> {tmp_path / 'calls'}\n"
                    "sleep 0.4\n"
                    f"echo \"end $(date +%s.%N)\" >> {tmp_path / 'calls'}\n"
                    "exit \"$1\"\n")
    fake.chmod(0o755)
    return fake


def test_concurrent_calls_do_not_overlap_and_pass_arguments_and_status(tmp_path):
    env = {**os.environ, "PYFOLD_REAL_NINJA": str(_fake_ninja(tmp_path)),
           "PYFOLD_NINJA_LOCK": str(tmp_path / "lock")}
    t0 = time.monotonic()
    procs = [subprocess.Popen([str(WRAPPER), str(k), "-C", "somewhere"], env=env) for k in range(3)]
    codes = [p.wait(timeout=60) for p in procs]
    assert codes == [0, 1, 2]
    lines = (tmp_path / "calls").read_text().split("\n")[:-1]
    # each start is followed by its own end before the next start: no two ran at once
    kinds = [line.split()[0] for line in lines]
    assert kinds == ["start", "end"] * 3
    assert sorted(line.split(maxsplit=2)[2] for line in lines if line.startswith("start")) == [
        f"{k} -C somewhere" for k in range(3)]
    # and they took at least three holds in a row (0.4 s each), not one
    assert time.monotonic() - t0 >= 1.2


def test_no_ninja_is_a_clear_error(tmp_path):
    env = {**os.environ, "PYFOLD_REAL_NINJA": str(tmp_path / "missing"), "PYFOLD_NINJA_LOCK": str(tmp_path / "lock")}
    res = subprocess.run([str(WRAPPER), "--version"], env=env, capture_output=True, text=True)
    assert res.returncode == 127 and "no ninja found" in res.stderr


def test_the_editable_install_rebuilds_through_it():
    """scripts/bootstrap installs with NINJA = scripts/ninja-serial, which meson-python writes
    into the import hook as the rebuild command."""
    site = Path(sys.prefix) / "lib"
    loaders = glob.glob(str(site / "python3*" / "site-packages" / "_pyfold_editable_loader.py"))
    if not loaders:
        pytest.skip("pyfold is not installed editable here (no meson-python import hook to check)")
    text = Path(loaders[0]).read_text()
    assert str(WRAPPER) in text
