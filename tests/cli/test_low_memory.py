"""Too little memory to load pyfold's libraries (a low ``ulimit -v``: the dynamic loader
cannot map numpy's, JAX's or OpenBLAS's shared objects, or Python raises MemoryError
mid-import): `pyfold run` and `pyfold validate` exit 1 with one line naming the cause
and the remedy (``not enough memory to load ...: raise the memory limit (ulimit -v)``),
never a traceback.
"""
from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import base_scene, write_scene
from pyfold import cli
from pyfold.cli import main
from pyfold.commands import validate
from pyfold.memory import describe_load_failure

#: Address-space limits [kB] (``ulimit -v``): the interpreter starts, the libraries do not all load
LIMITS_KB = (150_000, 250_000, 400_000)


@pytest.mark.parametrize("command", ["validate", "run"])
@pytest.mark.parametrize("kb", LIMITS_KB)
def test_low_address_space_limit_is_one_line_naming_ulimit(tmp_path, command, kb):
    scene = write_scene(tmp_path / "s.toml", base_scene())
    argv = [sys.executable, "-m", "pyfold.cli", command, str(scene)] + (
        ["-o", str(tmp_path / "out.h5")] if command == "run" else [])
    # the shell sets the limit (as a user would): no preexec_fn forking a process that may run JAX's threads
    proc = subprocess.run(["sh", "-c", f'ulimit -v {kb} && exec "$@"', "sh", *argv], capture_output=True, text=True,
                          timeout=300, stdin=subprocess.DEVNULL)
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.returncode >= 0, f"killed by signal {-proc.returncode} (a native crash):\n{proc.stderr[-3000:]}"
    if kb == LIMITS_KB[0] or proc.returncode != 0:  # the lowest limit cannot load numpy and JAX
        assert proc.returncode == 1, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1, proc.stderr
        assert lines[0].startswith(f"pyfold {command}: failed: not enough memory"), lines[0]
        assert f"raise the memory limit (ulimit -v; now {kb} kB)" in lines[0], lines[0]


def test_a_library_that_cannot_be_mapped_is_named():
    exc = ImportError("/venv/lib/libjax_common.so: failed to map segment from shared object", name="_jax")
    assert describe_load_failure(exc).startswith("not enough memory to load _jax (libjax_common.so): raise the "
                                                 "memory limit (ulimit -v")


def test_a_missing_package_is_not_called_a_memory_problem():
    text = describe_load_failure(ImportError("No module named 'h5py'", name="h5py"))
    assert text.startswith("cannot load h5py: No module named 'h5py'") and "memory" not in text


@pytest.mark.parametrize("error", [MemoryError(), ImportError("libopenblas.so: cannot allocate memory"),
                                   OSError(12, "Cannot allocate memory", "site-packages/pandas/_libs/tslibs")],
                         ids=["MemoryError", "ENOMEM while loading", "ENOMEM while listing a package"])
def test_memory_failure_inside_a_command_exits_1_with_one_line(monkeypatch, capsys, error):
    def fail(args):
        raise error

    monkeypatch.setattr(validate, "run", fail)  # main() builds its parser, binding the command's run, per call
    assert main(["validate", "scene.toml"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("pyfold validate: failed: not enough memory") and "ulimit -v" in err, err
    assert len(err.strip().splitlines()) == 1, err


def test_only_an_os_error_for_want_of_memory_counts_as_a_load_failure():
    assert cli._load_failure(OSError(12, "Cannot allocate memory"))
    assert not cli._load_failure(OSError(28, "No space left on device"))
    assert cli._load_failure(MemoryError()) and cli._load_failure(ImportError("x"))


def test_memory_failure_while_loading_the_commands_exits_1(monkeypatch, capsys):
    def fail():
        raise ImportError("numpy/_core/_multiarray_umath.so: failed to map segment from shared object",
                          name="numpy._core._multiarray_umath")

    monkeypatch.setattr(cli, "build_parser", fail)
    assert main(["run", "scene.toml"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("pyfold run: failed: not enough memory to load numpy._core._multiarray_umath "
                          "(_multiarray_umath.so)"), err
