"""Scene paths and scene bytes that are not a scene: `pyfold validate` (and `pyfold run`,
`analyse`, `report` for their file arguments) answers at once with exit 2 and a message
naming the path and the cause, never a hang or a traceback.

A FIFO is refused without being opened (opening it for reading blocks until a writer
comes); a folder or a device (``/dev/zero`` never ends) likewise; a scene file larger
than :data:`pyfold.scene.MAX_SCENE_BYTES` is refused stating the limit. Arrays nested
deeper than the TOML parser recurses are refused. A UTF-8 byte-order mark is accepted;
bytes that are not UTF-8 are refused naming the byte offset. Each call runs under
a time limit, so a hang fails the test instead of hanging CI.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import tomli_w

from conftest import base_scene, write_scene
from pyfold.cli import main
from pyfold.scene import MAX_SCENE_BYTES, load_scene
from test_extreme_inputs import time_limit

BOM = b"\xef\xbb\xbf"


def _cli(argv, capsys) -> tuple[int, str]:
    with time_limit():
        status = main(argv)
    out = capsys.readouterr()
    assert "Traceback" not in out.err, out.err
    return status, out.err


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def test_fifo_as_scene_is_refused_without_blocking(tmp_path, capsys):
    status, err = _cli(["validate", str(_fifo(tmp_path / "f.toml"))], capsys)
    assert status == 2, err
    assert "SCENE" in err and "f.toml" in err and "FIFO" in err and "not a regular file" in err, err


def test_folder_as_scene_is_refused(tmp_path, capsys):
    (tmp_path / "d.toml").mkdir()
    status, err = _cli(["validate", str(tmp_path / "d.toml")], capsys)
    assert status == 2 and "d.toml is a folder, not a regular file" in err, err


def test_endless_device_as_scene_is_refused_without_reading_it(capsys):
    status, err = _cli(["validate", "/dev/zero"], capsys)
    assert status == 2 and "/dev/zero is a character device, not a regular file" in err, err


def test_missing_scene_is_refused(tmp_path, capsys):
    status, err = _cli(["validate", str(tmp_path / "none.toml")], capsys)
    assert status == 2 and "SCENE: no such file" in err, err


def test_scene_file_over_the_size_limit_is_refused_stating_the_limit(tmp_path, capsys):
    big = tmp_path / "big.toml"
    with open(big, "wb") as f:  # sparse: no disk space used
        f.truncate(MAX_SCENE_BYTES + 1)
    status, err = _cli(["validate", str(big)], capsys)
    assert status == 2, err
    assert f"{MAX_SCENE_BYTES + 1} bytes" in err and f"at most {MAX_SCENE_BYTES} bytes" in err, err


def test_fifo_as_scene_of_run_is_refused_before_any_work(tmp_path, capsys):
    status, err = _cli(["run", str(_fifo(tmp_path / "f.toml")), "-o", str(tmp_path / "out.h5")], capsys)
    assert status == 2 and "FIFO" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.toml"]  # nothing written


@pytest.mark.parametrize("depth", [2000, 100_000])
def test_deeply_nested_array_is_refused(tmp_path, capsys, depth):
    text = tomli_w.dumps(base_scene())
    scene = tmp_path / "deep.toml"
    scene.write_text("deep = " + "[" * depth + "]" * depth + "\n" + text, encoding="utf-8")
    status, err = _cli(["validate", str(scene)], capsys)
    assert status == 2, err
    assert "deep.toml" in err and "nested too deeply" in err, err


def test_byte_order_mark_is_accepted_and_not_kept(tmp_path, capsys):
    scene = write_scene(tmp_path / "bom.toml", base_scene())
    plain = load_scene(scene)
    scene.write_bytes(BOM + scene.read_bytes())
    status, err = _cli(["validate", str(scene)], capsys)
    assert status == 0, err
    resolved = load_scene(scene)
    assert resolved.toml == plain.toml and not resolved.toml.startswith("\ufeff")


@pytest.mark.parametrize("bom", [False, True], ids=["plain", "after a byte-order mark"])
def test_bytes_that_are_not_utf8_are_refused_naming_the_byte_offset(tmp_path, capsys, bom):
    data = (BOM if bom else b"") + tomli_w.dumps(base_scene()).encode()
    offset = data.index(b"test scene")  # the title: a Latin-1 e-acute there is not UTF-8
    scene = tmp_path / "latin1.toml"
    scene.write_bytes(data[:offset] + b"\xe9" + data[offset:])
    status, err = _cli(["validate", str(scene)], capsys)
    assert status == 2, err
    assert "latin1.toml" in err and "not valid UTF-8" in err and f"byte offset {offset}" in err, err


@pytest.mark.parametrize("kind", ["fifo", "folder"])
def test_orientations_file_that_is_not_a_regular_file_is_refused_naming_the_key(tmp_path, capsys, kind):
    data = tmp_path / "axes.csv"
    _fifo(data) if kind == "fifo" else data.mkdir()
    scene = base_scene()
    scene["particles"][0].update(orientation="given", orientations="axes.csv")
    status, err = _cli(["validate", str(write_scene(tmp_path / "s.toml", scene))], capsys)
    assert status == 2, err
    assert "particles[0].orientations" in err and "not a regular file" in err, err


@pytest.mark.parametrize("command", ["analyse", "report"])
@pytest.mark.parametrize("kind", ["fifo", "folder"])
def test_run_file_argument_that_is_not_a_regular_file_is_refused(tmp_path, capsys, command, kind):
    run = tmp_path / "run.h5"
    _fifo(run) if kind == "fifo" else run.mkdir()
    status, err = _cli([command, str(run), "--out", str(tmp_path / "out")], capsys)
    assert status == 2, err
    assert "RUN.h5" in err and "run.h5 is" in err and "not a regular file" in err, err


def test_fifo_scene_in_a_subprocess_exits_within_seconds(tmp_path):
    """The installed entry point, not only main(): nothing blocks on the FIFO."""
    fifo = _fifo(tmp_path / "f.toml")
    proc = subprocess.run([sys.executable, "-m", "pyfold.cli", "validate", str(fifo)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "FIFO" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
