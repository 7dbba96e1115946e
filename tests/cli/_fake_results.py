"""Results laid out as fold_run appends them (fortran/io/fold_output.f90: netCDF
dimension scales at the root), written with h5netcdf: lets the reader be tested before, and
independently of, the Fortran writer. Like fold_run's, every variable is checksummed by
HDF5's Fletcher32 filter (pyfold.integrity)."""
from __future__ import annotations

import h5netcdf
import numpy as np


def append_results(path, dim: int, n: int, n_families: int, times, snapshot_steps, snapshot_times, a2, x, p,
                   min_gap_over_alpha, status: str = "ok") -> None:
    """Append contract-shaped results to an existing run file."""
    nt, ns = len(times), len(snapshot_steps)
    with h5netcdf.File(path, "a") as f:
        f.dimensions.update({"time": None, "i": dim, "j": dim, "k": dim, "l": dim, "xyz": dim,
                             "family": n_families, "snapshot": None, "particle": n})
        for name in ("i", "j", "k", "l", "xyz"):
            f.create_variable(name, (name,), "i4", data=np.arange(dim, dtype=np.int32), fletcher32=True)
        f.create_variable("family", ("family",), "i4", data=np.arange(n_families, dtype=np.int32), fletcher32=True)
        f.create_variable("particle", ("particle",), "i4", data=np.arange(n, dtype=np.int32), fletcher32=True)
        f.resize_dimension("time", nt)
        f.resize_dimension("snapshot", ns)
        v = f.create_variable("time", ("time",), "f8", data=np.asarray(times, float), fletcher32=True)
        v.attrs.update(units="s", long_name="time")
        v = f.create_variable("snapshot", ("snapshot",), "i8", data=np.asarray(snapshot_steps, np.int64),
                              fletcher32=True)
        v = f.create_variable("snapshot_time", ("snapshot",), "f8", data=np.asarray(snapshot_times, float),
                              fletcher32=True)
        v.attrs.update(units="s", long_name="time of the snapshot")
        v = f.create_variable("a2", ("time", "i", "j"), "f8", data=a2, fletcher32=True)
        v.attrs.update(units="1", long_name="second-order orientation tensor")
        a4 = np.zeros((nt,) + (dim,) * 4)
        f.create_variable("a4", ("time", "i", "j", "k", "l"), "f8", data=a4, fletcher32=True)
        f.create_variable("a2_family", ("time", "family", "i", "j"), "f8",
                          data=np.repeat(np.asarray(a2)[:, None], n_families, axis=1), fletcher32=True)
        v = f.create_variable("min_gap_over_alpha", ("time",), "f8", data=np.asarray(min_gap_over_alpha, float),
                              fletcher32=True)
        v.attrs.update(units="1", long_name="smallest gap / alpha")
        v = f.create_variable("x", ("snapshot", "particle", "xyz"), "f8", data=x, fletcher32=True)
        v.attrs.update(units="m", long_name="particle centres")
        f.create_variable("p", ("snapshot", "particle", "xyz"), "f8", data=p, fletcher32=True)
        f.attrs["status"] = status
        f.attrs["steps_done"] = np.int64(0 if not snapshot_steps else max(snapshot_steps))
        f.attrs["mpi_ranks"] = np.int64(1)
