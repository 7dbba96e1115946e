"""Shared helpers of the CLI tests: a small valid scene and a stand-in for fold_run."""
from __future__ import annotations

import copy
import os
import stat
import sys
from pathlib import Path

import pytest
import tomli_w

HERE = Path(__file__).resolve().parent

#: A small valid 3-D scene: 8 fibres (beta = 10) in a periodic cell, simple shear.
BASE_SCENE = {
    "title": "test scene",
    "cell": {"dim": 3, "size": [4.0, 4.0, 4.0]},
    "flow": {"type": "simple_shear", "rate": 1.0},
    "particles": [{"name": "fibres", "shape": "fibre", "length": 1.0, "radius": 0.05, "count": 8}],
    "model": {"alpha": 0.005},
    "numerics": {"dt": 0.01, "t_end": 0.2, "seed": 3},
    "output": {"interval": 0.05, "snapshot_interval": 0.1},
}


def base_scene() -> dict:
    return copy.deepcopy(BASE_SCENE)


def write_scene(path: Path, scene: dict) -> Path:
    path.write_text(tomli_w.dumps(scene), encoding="utf-8")
    return path


@pytest.fixture
def fake_fold_run(tmp_path, monkeypatch):
    """Point PYFOLD_FOLD_RUN at a stand-in that reads the run file, appends results in
    fold_run's layout (a2 from the initial axes, snapshots = initial state),
    prints PROGRESS lines and exits with $FAKE_FOLD_RUN_EXIT (default 0). It tests
    the orchestration of `pyfold run`, not the physics of fold_run."""
    script = tmp_path / "fold_run"
    script.write_text(f"#!/bin/sh\nexec {sys.executable} {HERE / '_fake_fold_run.py'} \"$@\"\n")
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PYFOLD_FOLD_RUN", str(script))
    monkeypatch.setenv("PYTHONPATH", str(HERE) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return script
