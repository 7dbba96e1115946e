"""The XDMF of a run, loaded by ParaView itself (pvpython, default reader under Xvfb),
shows every particle where the HDF5 run file has it, as a vertex cell, with its axis;
ParaView's legacy XDMF reader shows the same; the documented glyph recipe
(scripts/paraview_fibres.py) draws each fibre as a cylinder and each spheroid as an
ellipsoid along its axis with its own size; ``--png`` draws the last frame (or the one
asked for) and refuses unknown arrays and times.

ParaView is Debian's ``paraview`` package and Xvfb Debian's ``xvfb``, both installed
by scripts/test. The checks run pvpython on a small script that dumps, for every time
step of the file, what ParaView loaded and the glyphs it built; the comparison with
the HDF5 datasets is made here. Each pvpython runs on its own Xvfb server, started
with ``-displayfd`` (the server picks a free display and reports it once it accepts
connections, so no two servers race for one display).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import tomli_w

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "paraview_fibres.py"
sys.path.insert(0, str(ROOT / "scripts"))

DUMP = r'''
import sys
import numpy as np
sys.path.insert(0, sys.argv[3])
from paraview.simple import OpenDataFile, XDMFReader
from paraview import servermanager as sm
from vtk.numpy_interface import dataset_adapter as dsa
import paraview_fibres

reader = OpenDataFile(sys.argv[1])
legacy = XDMFReader(FileNames=[sys.argv[1]])
glyphs = paraview_fibres.particle_glyphs(reader)
out = {"reader": np.array(reader.GetXMLName()), "times": np.array(reader.TimestepValues, dtype=float),
       "legacy_times": np.array(legacy.TimestepValues, dtype=float)}
for k, t in enumerate(reader.TimestepValues):
    for name, source in (("default", reader), ("legacy", legacy)):
        source.UpdatePipeline(t)
        data = dsa.WrapDataObject(sm.Fetch(source))
        # copies: the VTK arrays die with the fetched object
        out[f"{name}_points_{k}"] = np.array(data.Points)
        out[f"{name}_cells_{k}"] = np.array(data.GetNumberOfCells())
        cells = []
        for c in range(data.GetNumberOfCells()):
            cell = data.GetCell(c)  # one cell object, refilled by each call: read it at once
            cells.append((cell.GetCellType(), cell.GetNumberOfPoints(), cell.GetPointId(0)))
        cells = np.array(cells, dtype=int).reshape(-1, 3)
        for column, what in enumerate(("types", "sizes", "points")):
            out[f"{name}_cell_{what}_{k}"] = cells[:, column]
        for array in ("p", "glyph_scale", "length", "radius", "shape"):
            out[f"{name}_{array}_{k}"] = np.array(data.PointData[array])
    for kind, glyph in glyphs.items():
        glyph.UpdatePipeline(t)
        points = dsa.WrapDataObject(sm.Fetch(glyph)).Points  # None when no particle has that shape
        out[f"glyph_{kind}_{k}"] = np.zeros((0, 3)) if points is None else np.array(points)
np.savez(sys.argv[2], **out)
'''

#: VTK's cell types of points: VTK_VERTEX, VTK_POLY_VERTEX.
VERTEX_CELLS = {1, 2}


def _installable(package: str) -> bool:
    """Whether apt knows a candidate for the Debian ``package`` (so that scripts/test can install it)."""
    apt = shutil.which("apt-cache")
    if apt is None:
        return False
    proc = subprocess.run([apt, "policy", package], capture_output=True, text=True)
    return proc.returncode == 0 and "Candidate:" in proc.stdout and "Candidate: (none)" not in proc.stdout


def _tool(exe: str, package: str) -> str:
    """The path of ``exe``; a failure where Debian's ``package`` could be installed, a skip where it cannot."""
    path = shutil.which(exe)
    if path is None:
        if _installable(package):
            pytest.fail(f"{exe} not found: install Debian's {package} package (scripts/test does)")
        pytest.skip(f"{exe} not found and Debian's {package} package is not installable here")
    return path


@pytest.fixture(scope="module")
def display():
    """An X display of its own (Xvfb), for ParaView's rendering and for its reader's process."""
    xvfb = _tool("Xvfb", "xvfb")
    # -noreset: without it the server regenerates when its last client leaves, and a client that
    # connects during that reset (one pvpython right after another, on a loaded machine) is refused
    server = subprocess.Popen([xvfb, "-displayfd", "1", "-screen", "0", "1280x1024x24", "-nolisten", "tcp", "-noreset"],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        number = server.stdout.readline().strip()  # written once the server accepts connections
        assert number.isdigit(), f"Xvfb did not report its display (exit status {server.poll()})"
        yield f":{number}"
    finally:
        server.terminate()
        server.wait(timeout=30)


def pvpython(display: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ParaView's Python on ``args`` with the display ``display``."""
    exe = _tool("pvpython", "paraview")
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "DISPLAY": display})


def scene(dim: int) -> dict:
    """Fibres of two lengths; in 3-D also spheroids (ellipsoids) and spheres."""
    particles = [{"name": "fibres", "shape": "fibre", "length": 1.0, "radius": 0.05, "count": 8},
                 {"name": "short", "shape": "fibre", "length": 0.5, "radius": 0.04, "count": 3}]
    if dim == 3:
        particles += [{"name": "spheroids", "shape": "spheroid", "length": 0.6, "radius": 0.1, "count": 3},
                      {"name": "spheres", "shape": "sphere", "radius": 0.15, "count": 2}]
    return {
        "title": f"paraview check {dim}-D",
        "cell": {"dim": dim, "size": [4.0] * dim},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": particles,
        "model": {"alpha": 0.005},
        "numerics": {"dt": 0.01, "t_end": 0.2, "seed": 3},
        "output": {"interval": 0.05, "snapshot_interval": 0.1},
    }


@pytest.fixture(scope="module", params=[3, 2], ids=["3d", "2d"])
def loaded(request, tmp_path_factory, display):
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
    proc = pvpython(display, str(script), str(run.with_suffix(".xmf")), str(dump), str(ROOT / "scripts"))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for complaint in ("Skipping unrecognized", "XDMF Error", "HDF5-DIAG"):
        assert complaint not in proc.stdout + proc.stderr, proc.stdout + proc.stderr
    return run, dict(np.load(dump))


def _run_arrays(run: Path) -> dict[str, np.ndarray]:
    with h5py.File(run) as f:
        return {"times": f["snapshot_time"][()], "x": f["x"][()], "p": f["p"][()],
                "length": f["initial/length"][()], "radius": f["initial/radius"][()],
                "shape": f["initial/shape"][()]}


@pytest.mark.parametrize("reader", ["default", "legacy"])
def test_paraview_readers_show_every_particle_as_a_vertex_cell_where_the_run_file_has_it(loaded, reader):
    run, pv = loaded
    assert str(pv["reader"]) == "Xdmf3ReaderS"  # what ParaView picks for .xmf
    ref = _run_arrays(run)
    np.testing.assert_array_equal(pv["times"], ref["times"])
    np.testing.assert_array_equal(pv["legacy_times"], ref["times"])
    n, dim = ref["x"].shape[1:]
    for k in range(len(ref["times"])):
        assert int(pv[f"{reader}_cells_{k}"]) == n
        # one cell of one point per particle (VTK's vertex or a poly-vertex of one point)
        assert set(pv[f"{reader}_cell_types_{k}"].tolist()) <= VERTEX_CELLS
        np.testing.assert_array_equal(pv[f"{reader}_cell_sizes_{k}"], np.ones(n))
        np.testing.assert_array_equal(pv[f"{reader}_cell_points_{k}"], np.arange(n))
        pts = pv[f"{reader}_points_{k}"]
        assert pts.shape == (n, 3)
        np.testing.assert_array_equal(pts[:, :dim], ref["x"][k])  # float64 read back bit for bit
        np.testing.assert_array_equal(pts[:, dim:], 0.0)
        axis = pv[f"{reader}_p_{k}"]
        assert axis.shape == (n, 3)  # a vector the Glyph filter can orient by, in 2-D too
        np.testing.assert_array_equal(axis[:, :dim], ref["p"][k])
        np.testing.assert_array_equal(axis[:, dim:], 0.0)
        np.testing.assert_array_equal(pv[f"{reader}_glyph_scale_{k}"],
                                      np.column_stack([ref["length"], 2 * ref["radius"], 2 * ref["radius"]]))
        for name in ("length", "radius", "shape"):
            np.testing.assert_array_equal(pv[f"{reader}_{name}_{k}"], ref[name])


def _glyph_blocks(glyphs: np.ndarray, count: int) -> list[np.ndarray]:
    """The glyph points of each of ``count`` particles (the Glyph filter writes them particle by particle)."""
    assert count == 0 or glyphs.shape[0] % count == 0
    per = glyphs.shape[0] // count if count else 0
    return [glyphs[i * per:(i + 1) * per] for i in range(count)]


def test_documented_glyph_recipe_draws_fibres_as_cylinders_and_spheroids_as_ellipsoids_along_p(loaded):
    import paraview_fibres

    run, pv = loaded
    ref = _run_arrays(run)
    n, dim = ref["x"].shape[1:]
    fibres = np.flatnonzero(ref["shape"] == paraview_fibres.FIBRE)
    rounds = np.flatnonzero(ref["shape"] != paraview_fibres.FIBRE)
    assert len(fibres) == 11 and len(rounds) == (5 if dim == 3 else 0)
    # VTK builds glyphs in float32: coordinates of size |x| + L carry ~1e-7 relative error
    tol = 1e-5 * (np.abs(ref["x"]).max() + ref["length"].max())
    for k in range(len(ref["times"])):
        for kind, members in (("fibres", fibres), ("round", rounds)):
            blocks = _glyph_blocks(pv[f"glyph_{kind}_{k}"], len(members))
            for i, pts in zip(members, blocks):
                half, radius = 0.5 * ref["length"][i], ref["radius"][i]
                rel = pts - np.append(ref["x"][k, i], [0.0] * (3 - dim))
                axis = np.append(ref["p"][k, i], [0.0] * (3 - dim))
                along = rel @ axis
                across = np.linalg.norm(rel - np.outer(along, axis), axis=1)
                assert abs(along.max() - half) < tol and abs(along.min() + half) < tol
                assert abs(across.max() - radius) < tol
                if kind == "fibres":
                    assert len(pts) >= 4 * paraview_fibres.RESOLUTION
                    # a cylinder: its caps lie at +-L/2, its side at distance R
                    on_cap = np.abs(np.abs(along) - half) < tol
                    on_side = np.abs(across - radius) < tol
                    assert np.all(on_cap | on_side)
                else:
                    # an ellipsoid: (along / (L/2))^2 + (across / R)^2 = 1 on every glyph point;
                    # an error tol in either coordinate moves the sum by at most 2 tol (1/(L/2) + 1/R)
                    ellipse = (along / half) ** 2 + (across / radius) ** 2
                    assert np.all(np.abs(ellipse - 1.0) < 2 * tol * (1 / half + 1 / radius))


def _png_size(path: Path) -> tuple[int, int]:
    """Width and height from a PNG's IHDR chunk."""
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def test_png_draws_the_last_frame_or_the_one_asked_for(loaded, display, tmp_path):
    import paraview_fibres

    run, pv = loaded
    times = pv["times"]
    xmf = run.with_suffix(".xmf")
    png = tmp_path / "last.png"
    proc = pvpython(display, str(SCRIPT), str(xmf), "--png", str(png), "--color-by", "shape")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"frame t = {times[-1]:g} drawn to {png}" in proc.stdout
    assert _png_size(png) == paraview_fibres.IMAGE_SIZE
    png_first = tmp_path / "first.png"
    proc = pvpython(display, str(SCRIPT), str(xmf), "--png", str(png_first), "--time", f"{times[0]:g}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"frame t = {times[0]:g} drawn to {png_first}" in proc.stdout
    assert png_first.read_bytes() != png.read_bytes()  # another frame, another colouring


@pytest.mark.parametrize("args, message", [
    (["--color-by", "speed"], "--color-by: no point array 'speed'; choose one of family, glyph_scale, length, p"),
    (["--time", "7.5"], "--time: 7.5 is not a frame time of the file; frames at t = 0 .. 0.2 (3 frames, every 0.1)"),
])
def test_png_refuses_unknown_arrays_and_times_naming_what_exists(loaded, display, tmp_path, args, message):
    run, _ = loaded
    png = tmp_path / "none.png"
    proc = pvpython(display, str(SCRIPT), str(run.with_suffix(".xmf")), "--png", str(png), *args)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert not png.exists()


def test_png_without_an_x_display_fails_naming_xvfb_run_instead_of_crashing(loaded, tmp_path):
    import paraview_fibres

    run, _ = loaded
    png = tmp_path / "none.png"
    env = {key: value for key, value in os.environ.items() if key != "DISPLAY"}
    proc = subprocess.run([_tool("pvpython", "paraview"), str(SCRIPT), str(run.with_suffix(".xmf")), "--png", str(png)],
                          capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "DISPLAY is not set" in proc.stderr and paraview_fibres.XVFB_RUN in proc.stderr
    assert not png.exists()


def test_frame_time_picks_the_nearest_frame_within_half_an_interval():
    import paraview_fibres

    times = [0.0, 0.1, 0.2]
    assert paraview_fibres.frame_time(times, None) == 0.2
    assert paraview_fibres.frame_time(times, 0.1) == 0.1
    assert paraview_fibres.frame_time(times, 0.149) == 0.1
    with pytest.raises(ValueError, match="not a frame time"):
        paraview_fibres.frame_time(times, 0.26)
    with pytest.raises(ValueError, match="not a frame time"):
        paraview_fibres.frame_time(times, float("nan"))
