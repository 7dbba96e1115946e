"""Every ```python block of README.md runs as written.

The blocks assume a run file ``run.h5`` in the working folder (``pyfold run scene.toml
-o run.h5``); it is made here by the real fold_run from a small dilute scene (8 fibres,
beta = 10, simple shear at rate 1, as ``simple_shear(1.0)`` in the README assumes), in a
temporary folder that is the working folder of the blocks.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from pyfold.cli import main
from pyfold.scene.sheared_fibres import sheared_fibres_toml

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)

#: 8 fibres (beta = 10) in a periodic 4^3 cell, simple shear, to t = 1.
SCENE = sheared_fibres_toml(title="README run", side=4.0, count=8, radius=0.05, dt=0.01, t_end=1.0, seed=3,
                            interval=0.05, snapshot_interval=0.5, alpha=0.005)


def python_blocks() -> list[str]:
    return BLOCK.findall(README.read_text(encoding="utf-8"))


def test_readme_has_python_blocks():
    assert python_blocks(), "README.md has no ```python block to check"


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("readme")
    scene = folder / "scene.toml"
    scene.write_text(SCENE, encoding="utf-8")
    os.environ.pop("PYFOLD_FOLD_RUN", None)
    assert main(["run", str(scene), "-o", str(folder / "run.h5")]) == 0
    return folder


@pytest.mark.parametrize("index", range(len(python_blocks())))
def test_readme_python_block_runs_as_written(index, run_folder, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")  # the blocks plot; no display here
    monkeypatch.chdir(run_folder)
    code = python_blocks()[index]
    namespace: dict = {"__name__": f"readme_block_{index}"}
    exec(compile(code, f"README.md python block {index + 1}", "exec"), namespace)  # noqa: S102
    if "fit" in namespace and hasattr(namespace["fit"], "success"):
        assert namespace["fit"].success, namespace["fit"].message
