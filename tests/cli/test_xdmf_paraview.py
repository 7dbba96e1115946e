"""The XDMF of a run, loaded by ParaView itself (pvpython, default reader), shows the
particles where the HDF5 file has them, and the documented glyph recipe
(scripts/paraview_fibres.py) draws each fibre along its axis with its length.

ParaView is Debian's ``paraview`` package, installed by scripts/test; reading data
needs no display. The check runs pvpython on a small script that dumps, for every
time step of the file, what ParaView loaded and the glyphs it built; the comparison
with the HDF5 datasets is made here.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import tomli_w

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

DUMP = r'''
import sys
import numpy as np
sys.path.insert(0, sys.argv[3])
from paraview.simple import OpenDataFile
from paraview import servermanager as sm
from vtk.numpy_interface import dataset_adapter as dsa
import paraview_fibres

reader = OpenDataFile(sys.argv[1])
glyph = paraview_fibres.fibre_glyphs(reader)
out = {"reader": np.array(reader.GetXMLName()), "times": np.array(reader.TimestepValues, dtype=float)}
for k, t in enumerate(reader.TimestepValues):
    reader.UpdatePipeline(t)
    glyph.UpdatePipeline(t)
    data = dsa.WrapDataObject(sm.Fetch(reader))
    out[f"points_{k}"] = np.array(data.Points)  # copies: the VTK arrays die with the fetched object
    for name in ("p", "length", "radius"):
        out[f"{name}_{k}"] = np.array(data.PointData[name])
    out[f"glyph_{k}"] = np.array(dsa.WrapDataObject(sm.Fetch(glyph)).Points)
np.savez(sys.argv[2], **out)
'''


def pvpython() -> str:
    exe = shutil.which("pvpython")
    if exe is None:
        pytest.fail("pvpython not found: scripts/test installs Debian's paraview package")
    return exe


def scene(dim: int) -> dict:
    return {
        "title": f"paraview check {dim}-D",
        "cell": {"dim": dim, "size": [4.0] * dim},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": [{"name": "fibres", "shape": "fibre", "length": 1.0, "radius": 0.05, "count": 8},
                      {"name": "short", "shape": "fibre", "length": 0.5, "radius": 0.04, "count": 3}],
        "model": {"alpha": 0.005},
        "numerics": {"dt": 0.01, "t_end": 0.2, "seed": 3},
        "output": {"interval": 0.05, "snapshot_interval": 0.1},
    }


@pytest.fixture(scope="module", params=[3, 2], ids=["3d", "2d"])
def loaded(request, tmp_path_factory):
    """A run (its name holds an XML special character), and what ParaView loaded."""
    from pyfold.cli import main

    tmp = tmp_path_factory.mktemp(f"pv{request.param}")
    toml = tmp / "scene.toml"
    toml.write_text(tomli_w.dumps(scene(request.param)), encoding="utf-8")
    run = tmp / "fibres & co.h5"
    assert main(["run", str(toml), "-o", str(run)]) == 0
    dump = tmp / "paraview.npz"
    script = tmp / "dump.py"
    script.write_text(DUMP, encoding="utf-8")
    proc = subprocess.run([pvpython(), str(script), str(run.with_suffix(".xmf")), str(dump), str(ROOT / "scripts")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Skipping unrecognized" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr
    return run, dict(np.load(dump))


def test_paraview_default_reader_loads_every_snapshot_where_the_run_file_has_it(loaded):
    run, pv = loaded
    assert str(pv["reader"]) == "Xdmf3ReaderS"  # what ParaView picks for .xmf
    with h5py.File(run) as f:
        times, x, p = f["snapshot_time"][()], f["x"][()], f["p"][()]
        length, radius = f["initial/length"][()], f["initial/radius"][()]
    np.testing.assert_allclose(pv["times"], times, rtol=0, atol=0)
    n, dim = x.shape[1:]
    for k in range(len(times)):
        pts = pv[f"points_{k}"]
        assert pts.shape == (n, 3)
        np.testing.assert_array_equal(pts[:, :dim], x[k])  # float64 read back bit for bit
        np.testing.assert_array_equal(pv[f"p_{k}"].reshape(n, -1)[:, :dim], p[k])
        np.testing.assert_array_equal(pv[f"length_{k}"], length)
        np.testing.assert_array_equal(pv[f"radius_{k}"], radius)


def test_documented_glyph_recipe_draws_each_fibre_along_its_axis_with_its_length(loaded):
    import paraview_fibres

    run, pv = loaded
    with h5py.File(run) as f:
        x, p = f["x"][()], f["p"][()]
        length, radius = f["initial/length"][()], f["initial/radius"][()]
    n, dim = x.shape[1:]
    # VTK builds glyphs in float32: coordinates of size |x| + L carry ~1e-7 relative error
    tol = 1e-5 * (np.abs(x).max() + length.max())
    for k in range(x.shape[0]):
        glyphs = pv[f"glyph_{k}"]
        assert glyphs.shape[0] % n == 0
        per = glyphs.shape[0] // n
        assert per >= 4 * paraview_fibres.RESOLUTION
        for i in range(n):
            pts = glyphs[i * per:(i + 1) * per] - np.append(x[k, i], [0.0] * (3 - dim))
            axis = np.append(p[k, i], [0.0] * (3 - dim))
            along = pts @ axis
            across = np.linalg.norm(pts - np.outer(along, axis), axis=1)
            assert abs(along.max() - 0.5 * length[i]) < tol and abs(along.min() + 0.5 * length[i]) < tol
            assert abs(across.max() - radius[i]) < tol
