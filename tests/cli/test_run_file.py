"""Run files: a valid scene goes into /setup and /initial and comes back unchanged;
open_run labels fold_run's results; the XDMF file shows every frame as written."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

import pyfold
from _fake_results import append_results
from pyfold.errors import InputError
from pyfold.run_input import FORMAT_VERSION, fixed_string, read_setup, write_run_file
from pyfold.run_results import write_xdmf
from pyfold.scene import load_scene
from pyfold.scene.initial import initial_state

ROOT = Path(__file__).resolve().parents[2]
SEED_DISKS = ROOT / "data" / "scenes" / "couette_disks_seed.toml"


@pytest.fixture(scope="module")
def disks():
    resolved = load_scene(SEED_DISKS)
    return resolved, initial_state(resolved)


@pytest.fixture
def run_file(tmp_path, disks):
    resolved, initial = disks
    path = tmp_path / "disks.h5"
    write_run_file(path, resolved, initial, "pyfold run couette_disks_seed.toml")
    return path


def test_scene_round_trips_verbatim_and_normalised(run_file, disks):
    resolved, _ = disks
    setup = read_setup(run_file)
    assert setup.scene_toml == SEED_DISKS.read_text(encoding="utf-8")
    assert setup.scene == json.loads(resolved.scene_json())
    # defaults are filled in the normalised scene
    assert setup.scene["model"]["on_contact_cap"] == "stop" and setup.scene["fluid"]["viscosity"] == 1.0
    assert setup.scene["model"]["contact_max_iter"] == 2000  # given in the file
    r = setup.resolved
    assert r["dim"] == 2 and r["walls"] == 1 and r["collisions"] == 2 and r["hydrodynamics"] == 0
    assert r["n_steps"] == 600 and r["output_every"] == 10 and r["snapshot_every"] == 20
    assert r["wall_speed"] == pytest.approx(0.5)  # U = rate Ly / 2
    assert r["family_names"] == ["disks"] and r["family_count"].tolist() == [42]
    np.testing.assert_array_equal(r["velocity_gradient"], [[0, 1, 0], [0, 0, 0], [0, 0, 0]])


def test_resolved_datasets_carry_units(run_file):
    with h5py.File(run_file) as f:
        res = f["setup/resolved"]
        assert res["velocity_gradient"].attrs["units"] == b"1/s"
        assert res["alpha"].attrs["units"] == b"m" and res["dt"].attrs["units"] == b"s"
        assert res["viscosity"].attrs["units"] == b"Pa s"
        assert f["initial/x"].shape == (42, 2) and f["initial/x"].attrs["units"] == b"m"
        assert f.attrs["format"] == b"pyfold.run" and f.attrs["format_version"] == FORMAT_VERSION.encode()
        assert f.attrs["creator"].startswith(b"pyfold ")


def test_initial_disks_respect_the_security_zone(disks):
    """Seed disks: every centre distance >= 2R + alpha (x periodic, y between walls)
    and every disk alpha/2 clear of the walls."""
    resolved, initial = disks
    R, alpha, (lx, ly) = 0.075, 0.005, resolved.cell_lengths[:2]
    d = initial.x[:, None, :] - initial.x[None, :, :]
    d[..., 0] -= lx * np.round(d[..., 0] / lx)
    dist = np.linalg.norm(d, axis=-1) + np.eye(len(d)) * 10
    assert dist.min() >= 2 * R + alpha - 1e-12
    assert initial.x[:, 1].min() >= R + alpha / 2 - 1e-12 and initial.x[:, 1].max() <= ly - R - alpha / 2 + 1e-12
    np.testing.assert_allclose(np.linalg.norm(initial.p, axis=1), 1.0, atol=1e-14)


def test_placement_is_reproducible_from_the_seed(disks):
    resolved, initial = disks
    again = initial_state(resolved)
    np.testing.assert_array_equal(again.x, initial.x)
    np.testing.assert_array_equal(again.p, initial.p)


def _append(path, dim, n, p, x):
    append_results(path, dim, n, 1, [0.0, 0.5, 1.0], [0, 20], [0.0, 1.0],
                   np.repeat((np.einsum("ni,nj->ij", p, p) / n)[None], 3, axis=0),
                   np.stack([x, x]), np.stack([p, p]), [3.0, 2.0, 1.5])


def test_open_run_labels_dims_and_keeps_units(run_file, disks):
    _, initial = disks
    _append(run_file, 2, 42, initial.p, initial.x)
    ds = pyfold.open_run(run_file)
    try:
        assert list(ds["a2"].dims) == ["time", "i", "j"]
        assert ds["i"].values.tolist() == ["x", "y"] and ds["xyz"].values.tolist() == ["x", "y"]
        assert ds["family"].values.tolist() == ["disks"]
        assert ds["a4"].dims == ("time", "i", "j", "k", "l")
        assert ds["x"].dims == ("snapshot", "particle", "xyz") and "snapshot_time" in ds.coords
        assert ds["time"].attrs["units"] == "s" and ds["x"].attrs["units"] == "m"
        a2 = np.einsum("ni,nj->ij", initial.p, initial.p) / 42
        assert float(ds["a2"].sel(i="x", j="y").isel(time=-1)) == pytest.approx(a2[0, 1], abs=1e-15)
        np.testing.assert_array_equal(ds["initial_x"].values, initial.x)
        assert ds["particle_radius"].attrs["units"] == "m"
        assert ds.attrs["status"] == "ok" and ds.attrs["regime"] == "spheres"
        assert ds.attrs["scene_toml"] == SEED_DISKS.read_text(encoding="utf-8")
        assert "collisions = strategy" in ds.attrs["hydrodynamics_reason"]
    finally:
        ds.close()


def _xdmf_arrays(xmf: Path) -> list[list[tuple[str, tuple[int, ...], np.ndarray]]]:
    """Per frame of ``xmf``: (element, Dimensions, values read from the HDF5 file named) of each HDF item."""
    root = ET.parse(xmf).getroot()
    frames = []
    for grid in root.findall("./Domain/Grid/Grid"):
        items = []
        for parent in grid:
            for item in parent.iter("DataItem"):
                name, _, dataset = item.text.partition(":")
                assert "|" not in dataset  # whole datasets: the form every XDMF reader reads
                with h5py.File(xmf.parent / name) as f:
                    values = f[dataset][()]
                items.append((parent.get("Name", parent.tag), tuple(int(v) for v in item.get("Dimensions").split()),
                              values))
        frames.append(items)
    return frames


def test_xdmf_frames_show_each_snapshot_as_vertex_cells_padded_to_three_components(run_file, disks):
    _, initial = disks
    n = len(initial.x)
    x1, p1 = initial.x + 0.25, -initial.p  # a second frame unlike the first: each frame must be its own
    append_results(run_file, 2, n, 1, [0.0, 0.5, 1.0], [0, 20], [0.0, 1.0],
                   np.repeat((np.einsum("ni,nj->ij", initial.p, initial.p) / n)[None], 3, axis=0),
                   np.stack([initial.x, x1]), np.stack([initial.p, p1]), [3.0, 2.0, 1.5])
    xmf = write_xdmf(run_file)
    assert xmf == run_file.with_suffix(".xmf")
    root = ET.parse(xmf).getroot()
    grids = root.findall("./Domain/Grid/Grid")
    assert [float(g.find("Time").get("Value")) for g in grids] == [0.0, 1.0]
    for grid in grids:
        topology = grid.find("Topology")
        assert topology.get("TopologyType") == "Polyvertex" and topology.get("NumberOfElements") == str(n)
        assert topology.get("NodesPerElement") == "1"
    with h5py.File(run_file) as f:
        length, radius = f["initial/length"][()], f["initial/radius"][()]
    for (x, p), items in zip([(initial.x, initial.p), (x1, p1)], _xdmf_arrays(xmf)):
        got = {name: (dims, values) for name, dims, values in items}
        for dims, values in got.values():
            assert values.shape == dims  # the Dimensions declared are those of the dataset
        np.testing.assert_array_equal(got["Topology"][1], np.arange(n))  # one vertex cell per particle
        np.testing.assert_array_equal(got["Geometry"][1], np.column_stack([x, np.zeros(n)]))
        np.testing.assert_array_equal(got["p"][1], np.column_stack([p, np.zeros(n)]))
        np.testing.assert_array_equal(got["glyph_scale"][1], np.column_stack([length, 2 * radius, 2 * radius]))
        np.testing.assert_array_equal(got["length"][1], length)


def test_xdmf_without_snapshots_shows_the_initial_state(run_file, disks):
    _, initial = disks
    xmf = write_xdmf(run_file)
    (frame,) = _xdmf_arrays(xmf)
    geometry = [values for name, _, values in frame if name == "Geometry"][0]
    np.testing.assert_array_equal(geometry[:, :2], initial.x)


def test_xdmf_refers_to_the_run_file_by_a_path_relative_to_the_xmf(run_file, disks, tmp_path):
    _, initial = disks
    elsewhere = tmp_path / "views" / "disks.xmf"
    elsewhere.parent.mkdir()
    write_xdmf(run_file, elsewhere)
    moved = tmp_path.parent / (tmp_path.name + "-moved")
    tmp_path.rename(moved)  # the three files moved together still find each other
    try:
        (frame,) = _xdmf_arrays(moved / "views" / "disks.xmf")
        geometry = [values for name, _, values in frame if name == "Geometry"][0]
        np.testing.assert_array_equal(geometry[:, :2], initial.x)
    finally:
        moved.rename(tmp_path)


def test_open_run_refuses_other_files_and_major_versions(tmp_path, run_file):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = fixed_string("something.else")
    with pytest.raises(InputError, match="not a pyfold run file"):
        pyfold.open_run(other)
    with h5py.File(run_file, "a") as f:
        f.attrs["format_version"] = fixed_string("2.0")
    with pytest.raises(InputError, match="format_version '2.0'"):
        pyfold.open_run(run_file)


@pytest.mark.parametrize("version", ["1.x-garbage", "1", "1.0.0", "", "one.two"])
def test_open_run_refuses_a_malformed_format_version(run_file, version):
    with h5py.File(run_file, "a") as f:
        f.attrs["format_version"] = fixed_string(version)
    with pytest.raises(InputError, match="format_version .* not of the form MAJOR.MINOR"):
        pyfold.open_run(run_file)


def test_gap_summary_shows_a_negative_gap_as_negative_even_with_alpha_zero():
    from pyfold.run_results import gap_summary

    huge = np.finfo(np.float64).max  # a record with no pair in range
    text = gap_summary(np.array([huge, 1e-3, -4e-14]), alpha=0.0)
    assert "-4e-14 m" in text and "NEGATIVE" in text and "alpha" not in text
    text = gap_summary(np.array([2e-3, 5e-3]), alpha=1e-3)
    assert "0.002 m = 2 alpha" in text and "NEGATIVE" not in text
    assert "no particle pairs" in gap_summary(np.array([huge]), alpha=1e-3)
