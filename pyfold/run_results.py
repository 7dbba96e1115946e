"""Reading the results of a run file: :func:`open_run` (labelled xarray view),
:func:`run_summary`, :func:`write_xdmf` (the particles for ParaView).

The input part of a run file (root attributes, ``/setup``, ``/initial``) is written and
read by :mod:`pyfold.run_input`.

The results ``fold_run`` appends at the root of a run file are netCDF-compatible
(HDF5 dimension scales, micro contract): ``time``, tensor indices ``i, j, k, l``,
vector components ``xyz``, ``family``, ``snapshot``, ``particle``. :func:`open_run`
opens them with xarray, labels the index dimensions (``"x", "y"[, "z"]``, family
names), adds the initial state from ``/initial`` and puts the scene and the
resolved choices in ``attrs``.
"""
from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import h5py
import numpy as np
import xarray as xr

from pyfold.errors import DamagedRunWarning, InputError, PyfoldError, UnverifiedRunWarning
from pyfold.files import atomic_output
from pyfold.integrity import Damage, DamagedRunError, held_by_writer, refuse, tolerating_damage, verify_path
from pyfold.run_input import attr_text as _text
from pyfold.run_input import check_format, read_setup
from pyfold.xdmf_files import xdmf_data_path

__all__ = ["open_run", "write_xdmf", "xdmf_data_path", "run_summary", "complete_counts", "AXIS_LABELS"]

AXIS_LABELS = ("x", "y", "z")
_INITIAL = {  # /initial dataset -> (variable name in the Dataset, dims after "particle")
    "x": ("initial_x", ("xyz",)),
    "p": ("initial_p", ("xyz",)),
    "shape": ("particle_shape", ()),
    "family": ("particle_family", ()),
    "radius": ("particle_radius", ()),
    "length": ("particle_length", ()),
    "xi": ("particle_xi", ()),
}


def _attr(value):
    """Root attribute as a Python scalar or string (a 1-element array counts as a scalar)."""
    if isinstance(value, bytes | np.bytes_ | str):
        return _text(value)
    if isinstance(value, np.ndarray) and value.size == 1:
        value = value.reshape(())[()]
    return value.item() if hasattr(value, "item") else value


#: Root attributes ``fold_run`` sets once a record / snapshot is completely written
#: (after its datasets are appended and flushed): the number of whole entries along
#: the growing dimensions ``time`` and ``snapshot``.
COMPLETE_COUNT_ATTRS = {"time": "records_complete", "snapshot": "snapshots_complete"}


def _along(dset: h5py.Dataset, dim: str) -> bool:
    """True when the first (growing) axis of a root dataset is the dimension ``dim``."""
    if dset.name == "/" + dim:
        return True
    if dset.ndim == 0:
        return False
    try:
        scales = dset.dims[0]
        return len(scales) > 0 and scales[0].name == "/" + dim
    except (KeyError, RuntimeError, ValueError):
        return False


def complete_counts(f: h5py.File) -> dict[str, int]:
    """Whole entries along ``time`` and ``snapshot`` of an open run file.

    A record (or snapshot) is written as one append per dataset; a killed run can
    leave the datasets at different lengths or the last entry unwritten (read as
    fill values). ``fold_run`` sets the root attributes ``records_complete`` /
    ``snapshots_complete`` after an entry is whole on disk; the count is that
    attribute, and never more than the shortest dataset along the dimension. Files
    of a ``fold_run`` without these attributes: the shortest dataset.
    """
    counts = {}
    for dim, attr in COMPLETE_COUNT_ATTRS.items():
        lengths = [int(d.shape[0]) for d in f.values() if isinstance(d, h5py.Dataset) and _along(d, dim)]
        n = min(lengths) if lengths else 0
        if attr in f.attrs:
            n = min(n, max(int(_attr(f.attrs[attr])), 0))
        counts[dim] = n
    return counts


def _intact_part(f: h5py.File, damaged: dict[str, Damage]) -> tuple[dict[str, int], list[str], dict]:
    """What an ``allow_damaged`` reader keeps of an open run file whose damaged objects are
    ``damaged`` (by name, :func:`pyfold.integrity.verify_file`).

    Returns the whole entries to keep along ``time`` / ``snapshot`` (:func:`complete_counts`,
    cut at the first damaged chunk of any dataset over that dimension), the root datasets
    to leave out of the xarray view (wholly lost, and the damaged dimension coordinates
    ``time`` / ``snapshot``, which xarray would load whole), and for those coordinates
    their intact prefix with its attributes."""
    counts = complete_counts(f)
    for dim in counts:
        for d in damaged.values():
            if d.first_bad is not None and d.name in f and _along(f[d.name], dim):
                counts[dim] = min(counts[dim], d.first_bad)
    lost = [name for name, d in damaged.items() if name.count("/") == 1 and name in f
            and (d.first_bad is None or name[1:] in counts)]
    prefixes = {name[1:]: (f[name][: counts[name[1:]]], dict(f[name].attrs))
                for name in lost if name[1:] in counts and damaged[name].first_bad is not None}
    return counts, lost, prefixes


def open_run(path: str | Path, allow_damaged: bool | None = None) -> xr.Dataset:
    """Open a run file as a labelled :class:`xarray.Dataset`.

    Parameters
    ----------
    path : path
        A run file written by ``pyfold run`` (complete, failed or still partial).
    allow_damaged : bool, optional
        Read the intact part of a damaged file instead of refusing it (see Raises)
        (default: True inside :func:`pyfold.integrity.tolerate_damage`, as ``pyfold
        analyse --allow-damaged`` and ``pyfold report --allow-damaged`` run): a damaged dataset over ``time`` (``snapshot``) cuts every variable over that
        dimension to the entries before its first damaged chunk (chunks hold at most 64
        entries); any other damaged dataset is left out. Each is named in a
        :class:`pyfold.errors.DamagedRunWarning`. ``/setup/resolved/dim`` and
        ``family_names`` are needed: damage there is refused regardless.

    Returns
    -------
    xarray.Dataset
        Results over ``time`` (``a2(time, i, j)``, ``a4(time, i, j, k, l)``,
        ``a2_family(time, family, i, j)``, contact and drift records; Stokes runs
        also ``stokes_iterations``, ``stokes_residual``, ``rigidity_max``,
        ``rigidity_mean``, ``stress(time, i, j)`` [Pa] (deviatoric bulk stress) and
        ``effective_viscosity(time)`` [Pa s]; with walls also ``wall_shear_stress(time)``
        [Pa], the xy entry of ``stress``, which equals the stress on the walls in Stokes flow;
        with lubrication ``lubricated_pairs`` and ``lubrication_correction`` [m/s]),
        snapshots ``x, p (snapshot, particle, xyz)`` with ``snapshot_time``,
        and the initial state ``initial_x, initial_p (particle, xyz)``,
        ``particle_shape, particle_family, particle_radius, particle_length,
        particle_xi (particle)``. Index dimensions are labelled ``"x", "y"[, "z"]``,
        ``family`` by family name. Every variable keeps its ``units`` and
        ``long_name``. Only whole records and snapshots are returned: a run killed
        while appending one is cut to ``records_complete`` / ``snapshots_complete``
        (:func:`complete_counts`). ``attrs`` hold the root attributes (``status``,
        ``steps_done``, ``creator``, ...), ``scene`` (normalised scene, a dict as
        JSON text), ``scene_toml`` (verbatim), the resolved scalars
        (``dim``, ``dt``, ``alpha``, ``regime``, ``hydrodynamics_reason``, ...),
        ``velocity_gradient`` (the imposed ``G_ij`` [1/s], ``dim**2`` values row-major:
        the default ``L`` of :func:`pyfold.fit.fit_parameters`), ``xi`` (the Jeffery shape
        factor, when all particles share one) and
        ``integrity`` (:meth:`pyfold.integrity.Integrity.summary`: "verified: ...",
        "no checksums: not verified" for a format 1.0 file, or "damaged: ...").

    Raises
    ------
    InputError
        Not a pyfold run file, or an unknown major ``format_version``;
        :class:`pyfold.integrity.DamagedRunError` (an InputError) when a dataset fails
        its checksum or a part of the file cannot be read, naming each (every dataset
        is read and verified first: :func:`pyfold.integrity.verify_file`).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"open_run: no such file: {path}")
    if allow_damaged is None:
        allow_damaged = tolerating_damage()
    report = verify_path(path)
    if not allow_damaged:
        refuse(path, report, "refusing to read it (pass --allow-damaged, or open_run(..., allow_damaged=True), "
                             "to read the intact part)")
    if not report.checksummed:
        warnings.warn(UnverifiedRunWarning(f"{path}: format_version 1.0: no checksums: not verified"), stacklevel=2)
    damaged = {d.name: d for d in report.damage}
    if damaged:
        warnings.warn(DamagedRunWarning(f"{path}: {report.summary()}; reading the intact part only (entries before "
                                        "the first damaged chunk; other damaged datasets left out)"), stacklevel=2)
    try:
        with h5py.File(path, "r") as f:
            check_format(f, path)
            root_attrs = {k: _attr(v) for k, v in f.attrs.items()}
            counts, lost, prefixes = _intact_part(f, damaged)
            initial = {name: (f["initial"][name][()], dict(f["initial"][name].attrs)) for name in _INITIAL
                       if "initial" in f and name in f["initial"] and f"/initial/{name}" not in damaged}
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - damaged metadata raises anything
        held = held_by_writer(path, exc)
        if held is not None:
            raise held from None
        raise DamagedRunError(f"{path}: damaged: cannot read it ({' '.join(str(exc).split())})",
                              [Damage(str(path), "cannot read")]) from None
    setup = read_setup(path, allow_damaged=True)
    res = setup.resolved
    needed = [k for k in ("dim", "family_names") if k not in res]
    if needed:
        raise DamagedRunError(f"{path}: damaged: cannot read it without " + ", ".join(
            "/setup/resolved/" + k for k in needed), [Damage("/setup/resolved/" + k, "damaged") for k in needed])
    dim = int(res["dim"])
    names = list(res["family_names"]) if isinstance(res["family_names"], list) else [res["family_names"]]

    try:
        ds = xr.open_dataset(path, engine="h5netcdf", decode_times=False,
                             drop_variables=[name.lstrip("/") for name in lost] or None)
    except Exception as exc:  # noqa: BLE001
        raise DamagedRunError(f"{path}: damaged: cannot read its results ({' '.join(str(exc).split())})",
                              [Damage(str(path), "cannot read its results")]) from None
    # h5netcdf pads a shorter dataset to its dimension's length with fill values:
    # keep the whole entries only.
    cut = {dim: slice(0, n) for dim, n in counts.items() if dim in ds.dims and ds.sizes[dim] != n}
    if cut:
        ds = ds.isel(cut)
    for name, (data, attrs) in prefixes.items():
        ds = ds.assign_coords({name: (name, data, {k: _text(v) for k, v in attrs.items()
                                                   if k in ("units", "long_name")})})
    labels = list(AXIS_LABELS[:dim])
    relabel = {d: labels for d in ("i", "j", "k", "l", "xyz") if d in ds.dims}
    if "family" in ds.dims:
        relabel["family"] = names
    for dim_name, values in relabel.items():
        attrs = dict(ds[dim_name].attrs) if dim_name in ds.coords else {}
        ds = ds.assign_coords({dim_name: (dim_name, values, attrs)})
    if "snapshot_time" in ds:
        ds = ds.set_coords("snapshot_time")
    for name, (data, attrs) in initial.items():
        var, extra = _INITIAL[name]
        attrs = {k: _text(v) for k, v in attrs.items()}
        if extra:
            ds[var] = (("particle", *extra), data, attrs)
        else:
            ds[var] = (("particle",), data, attrs)
    if "xyz" not in ds.coords:
        ds = ds.assign_coords(xyz=labels)
    if "particle" not in ds.coords and "particle" in ds.dims:
        ds = ds.assign_coords(particle=np.arange(ds.sizes["particle"]))
    if "particle_family" in ds:
        ds = ds.assign_coords(family_name=("particle", [names[int(k)] for k in ds["particle_family"].values]))

    if int(res.get("walls", 0)) == 1 and "stress" in ds:
        # Stokes flow between the walls, periodic in x, no body force: the x-momentum flux
        # (1/Lx) integral of sigma_xy dx is the same on every plane y = const, so the cell
        # average of sigma_xy (pressure has no xy part) is the shear stress on the walls.
        ds["wall_shear_stress"] = ds["stress"].sel(i="x", j="y", drop=True).assign_attrs(
            units="Pa", long_name="shear stress sigma_xy on the walls (= the cell-averaged sigma_xy of "
            "stress in Stokes flow between walls)")
    attrs = dict(root_attrs)
    attrs["scene"] = json.dumps(setup.scene)
    attrs["scene_toml"] = setup.scene_toml
    attrs["integrity"] = report.summary()
    for key, value in res.items():
        if isinstance(value, str) or np.ndim(value) == 0:
            attrs[key] = value.item() if hasattr(value, "item") else value
    attrs.update(_model_attrs(res, dim))
    ds.attrs = attrs
    return ds


def _model_attrs(res, dim: int) -> dict[str, object]:
    """What an orientation model needs from a run, as attributes: ``velocity_gradient``
    (``G_ij = du_i/dx_j`` [1/s] of the ``dim`` x ``dim`` block, flattened row-major:
    ``dim**2`` values, which :func:`pyfold.fit.fit_parameters` takes as its default ``L``)
    and ``xi`` (the Jeffery shape factor, when every family has the same one)."""
    out: dict[str, object] = {}
    if "velocity_gradient" in res:
        grad = np.asarray(res["velocity_gradient"], dtype=np.float64).reshape(3, 3)[:dim, :dim]
        out["velocity_gradient"] = np.ascontiguousarray(grad).reshape(-1)
    if "family_xi" in res:
        xi = np.atleast_1d(np.asarray(res["family_xi"], dtype=np.float64))
        if xi.size and np.all(xi == xi[0]):
            out["xi"] = float(xi[0])
    return out


#: Per-particle arrays of ``/initial`` carried to every frame: name -> (XDMF NumberType, Precision).
_XDMF_SCALARS = {"length": ("Float", 8), "radius": ("Float", 8), "shape": ("Int", 4), "family": ("Int", 4)}


def _hdf_item(h5name: str, dataset: str, dims: tuple[int, ...], number: str, precision: int) -> str:
    """An XDMF DataItem reading the whole ``dataset`` of the HDF5 file ``h5name``.

    The file name is XML-escaped (a ``&`` or ``<`` in it would make the XDMF invalid)."""
    return (f'<DataItem Dimensions="{" ".join(map(str, dims))}" NumberType="{number}" Precision="{precision}" '
            f'Format="HDF">{escape(h5name)}:{dataset}</DataItem>')


def _frame_view(out: h5py.File, name: str, source: str, dataset: str, shape: tuple[int, ...],
                index: int | None) -> None:
    """A virtual dataset ``name`` of shape ``(n, 3)`` in ``out`` showing ``dataset[index]``
    (or the whole ``(n, dim)`` dataset) of the run file ``source``, zero-padded to three
    components; it holds no copy of the data, only the mapping."""
    n, dim = shape[-2:]
    layout = h5py.VirtualLayout(shape=(n, 3), dtype="f8")
    src = h5py.VirtualSource(source, dataset, shape=shape, dtype="f8")
    layout[:, :dim] = src[index] if index is not None else src
    out.create_virtual_dataset(name, layout, fillvalue=0.0)


def _write_xdmf_data(tmp: Path, source: str, frames: list[tuple[float, str, int | None]],
                     shapes: dict[str, tuple[int, ...]],
                     initial: dict[str, np.ndarray]) -> None:
    """The HDF5 file beside the XDMF: per frame ``/frame_K/x`` and ``/frame_K/p``
    (virtual views of the run file's frames, three components), the vertex cells
    ``/connectivity`` and the per-particle ``/glyph_scale`` and scalars."""
    n = len(initial["length"])
    with h5py.File(tmp, "w") as out:
        out.attrs["long_name"] = "frames of a pyfold run file, one dataset each, for XDMF readers"
        out.attrs["source"] = source
        for k, (_, group, index) in enumerate(frames):
            for name in ("x", "p"):
                _frame_view(out, f"frame_{k}/{name}", source, group + name, shapes[group + name], index)
        out["connectivity"] = np.arange(n, dtype=np.int64)
        out["connectivity"].attrs["long_name"] = "one vertex cell per particle (point index)"
        scale = np.stack([initial["length"], 2.0 * initial["radius"], 2.0 * initial["radius"]], axis=1)
        out["glyph_scale"] = scale
        out["glyph_scale"].attrs["long_name"] = ("glyph size along p and across it (length, 2 radius, 2 radius): "
                                                 "a unit glyph along x scaled by components")
        out["glyph_scale"].attrs["units"] = "m"
        for name, (number, precision) in _XDMF_SCALARS.items():  # stored as the XDMF declares them
            out[name] = np.asarray(initial[name], dtype=f"{'i' if number == 'Int' else 'f'}{precision}")


def write_xdmf(path: str | Path, xmf: str | Path | None = None) -> Path:
    """Write an XDMF 3 file for ParaView (and other XDMF readers) beside a run file:
    one frame per snapshot.

    Particles are points at their centres, each in its own vertex cell (Polyvertex
    topology, so that filters working on cells, such as Threshold, see them), carrying
    the axis ``p`` (three components; zero third one in 2-D), ``glyph_scale`` =
    (length, 2 radius, 2 radius) and ``length``, ``radius``, ``shape``, ``family``.
    A Glyph filter with orientation ``p``, scale ``glyph_scale`` "by components" and
    scale factor 1 draws each particle along its axis: a sphere glyph of radius 0.5
    gives the ellipsoid of a spheroid (the sphere of a sphere), a cylinder glyph of
    height 1 and radius 0.5, turned onto x, the cylinder of a fibre
    (``scripts/paraview_fibres.py``). Without snapshots the one frame is ``/initial``.

    Every array is a whole HDF5 dataset of ``OUT.xmf.h5`` (:func:`xdmf_data_path`),
    the form that both ParaView's default reader (Xdmf3ReaderS) and its legacy XDMF
    reader read (the first skips XDMF 2 ``HyperSlab`` items, the second cannot parse
    XDMF 3's ``file:/dataset|start:stride:count:dims`` selections). The frames there
    are HDF5 virtual datasets mapping onto the run file's ``/x`` and ``/p`` by its
    relative name: no copy of the data; keep the three files together.

    Returns
    -------
    pathlib.Path
        The ``.xmf`` file written (default: the run file with suffix ``.xmf``).
    """
    path = Path(path)
    xmf = Path(xmf) if xmf is not None else path.with_suffix(".xmf")
    data = xdmf_data_path(xmf)
    source = os.path.relpath(os.path.abspath(path), os.path.abspath(xmf.parent))  # the run file, from the data file
    try:
        f = h5py.File(path, "r")
    except OSError as exc:  # e.g. left unreadable by a full disk: a message, not a traceback
        raise PyfoldError(f"{path} cannot be opened as an HDF5 file: {exc}") from None
    with f:
        check_format(f, path)
        if "initial" not in f or "x" not in f["initial"]:
            raise PyfoldError(f"{path}: no /initial/x to show")
        n, dim = f["initial"]["x"].shape
        initial = {}
        for name in _XDMF_SCALARS:
            try:
                initial[name] = f["initial"][name][()]
            except (KeyError, OSError) as exc:
                raise PyfoldError(f"{path}: /initial/{name} cannot be read ({exc}); no XDMF written") from None
        whole = complete_counts(f)["snapshot"]
        shapes = {"/initial/x": (n, dim), "/initial/p": (n, dim)}
        if "x" in f and "p" in f and f["x"].ndim == 3 and whole > 0:
            shapes.update({name: tuple(int(s) for s in f[name].shape) for name in ("/x", "/p")})
            try:
                times = f["snapshot_time"][()] if "snapshot_time" in f else np.arange(shapes["/x"][0], dtype=float)
            except OSError as exc:  # a chunk that fails its checksum: a message naming it, not a traceback
                raise PyfoldError(f"{path}: /snapshot_time is damaged (cannot be read: {exc}); no XDMF written") from None
            frames = [(float(times[k]), "/", k) for k in range(whole)]
        else:
            frames = [(0.0, "/initial/", None)]
        lengths = f["setup/resolved/cell_lengths"][()] if "setup/resolved/cell_lengths" in f else None
    h5name = data.name
    cells = (f'<Topology TopologyType="Polyvertex" NumberOfElements="{n}" NodesPerElement="1">'
             f'{_hdf_item(h5name, "/connectivity", (n,), "Int", 8)}</Topology>')
    per_particle = (f'<Attribute Name="glyph_scale" AttributeType="Vector" Center="Node">'
                    f'{_hdf_item(h5name, "/glyph_scale", (n, 3), "Float", 8)}</Attribute>'
                    + "".join(f'<Attribute Name="{name}" AttributeType="Scalar" Center="Node">'
                              f'{_hdf_item(h5name, "/" + name, (n,), number, prec)}</Attribute>'
                              for name, (number, prec) in _XDMF_SCALARS.items()))
    grids = []
    for k, (t, _, _) in enumerate(frames):
        grids.append(
            f'<Grid Name={quoteattr(f"snapshot {k}")} GridType="Uniform"><Time Value="{t!r}"/>{cells}'
            f'<Geometry GeometryType="XYZ">{_hdf_item(h5name, f"/frame_{k}/x", (n, 3), "Float", 8)}</Geometry>'
            f'<Attribute Name="p" AttributeType="Vector" Center="Node">'
            f'{_hdf_item(h5name, f"/frame_{k}/p", (n, 3), "Float", 8)}</Attribute>{per_particle}</Grid>')
    box = ("" if lengths is None else
           f'<Information Name="cell_lengths" Value="{" ".join(repr(float(v)) for v in lengths)}"/>')
    text = ('<?xml version="1.0" ?>\n<Xdmf Version="3.0"><Domain>' + box
            + '<Grid Name="particles" GridType="Collection" CollectionType="Temporal">'
            + "\n".join(grids) + "</Grid></Domain></Xdmf>\n")
    with atomic_output(data) as tmp:  # whole or absent, like the .xmf that reads it
        _write_xdmf_data(tmp, source, frames, shapes, initial)
    try:
        with atomic_output(xmf) as tmp:  # whole or absent: a full disk leaves no 0-byte .xmf
            tmp.write_text(text, encoding="utf-8")
    except BaseException:
        data.unlink(missing_ok=True)  # no data file without the .xmf that explains it
        raise
    return xmf


def gap_summary(min_gap: np.ndarray, alpha: float) -> str:
    """The smallest surface gap of the run [m], in units of the security zone when
    ``alpha > 0``; a negative gap (an overlap) is printed as such, however small,
    and flagged. Records with no pair in range hold a huge sentinel (Fortran ``huge``)."""
    gap = np.asarray(min_gap, dtype=np.float64)
    gap = gap[np.isfinite(gap) & (np.abs(gap) < 1e300)]
    if not gap.size:
        return "smallest gap: no particle pairs within range"
    g = float(gap.min())
    text = f"smallest gap over the run: {g:.6g} m"
    if alpha > 0.0:
        text += f" = {g / alpha:.6g} alpha"
    if g < 0.0:
        text += "  -- NEGATIVE: particles overlapped"
    return text


def run_summary(path: str | Path) -> str:
    """A few lines: status, steps, regime and choices, smallest gap / alpha, final a2."""
    ds = open_run(path)
    try:
        a = ds.attrs
        lines = [f"status: {a.get('status', 'unknown')}, steps done: {a.get('steps_done', '?')} of {a.get('n_steps', '?')}",
                 f"regime: {a.get('regime', '?')}; {a.get('hydrodynamics_reason', '')}"]
        lines += [f"warning: {w}" for w in str(a.get("scene_warnings", "")).splitlines() if w.strip()]
        if "min_gap" in ds and ds.sizes.get("time", 0) > 0:
            lines.append(gap_summary(ds["min_gap"].values, float(a.get("alpha", 0.0))))
        if "effective_viscosity" in ds and ds.sizes.get("time", 0) > 0:
            eta = ds["effective_viscosity"].values
            lines.append(f"Stokes: effective viscosity {eta.mean():.6g} Pa s (mean over the records, "
                         f"{eta.min():.6g} ... {eta.max():.6g}); CG iterations <= {int(ds['stokes_iterations'].max())}, "
                         f"residual <= {float(ds['stokes_residual'].max()):.3g}, rigidity <= "
                         f"{float(ds['rigidity_max'].max()):.3g}")
        if "a2" in ds and ds.sizes.get("time", 0) > 0:
            a2 = ds["a2"].isel(time=-1).values
            t = float(ds["time"].values[-1])
            rows = "; ".join(" ".join(f"{v:+.4f}" for v in row) for row in a2)
            lines.append(f"a2 at t = {t:g}: [{rows}]")
        return "\n".join(lines)
    finally:
        ds.close()
