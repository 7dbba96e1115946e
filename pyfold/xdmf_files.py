"""Names of the files that describe a run file for XDMF readers (ParaView).

``OUT.xmf`` (XML) and the HDF5 file it reads its arrays from, ``OUT.xmf.h5``;
:func:`pyfold.run_results.write_xdmf` writes both. Kept free of heavy imports: ``pyfold
run`` checks these names before it starts.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["XDMF_SUFFIX", "XDMF_DATA_SUFFIX", "xdmf_data_path", "xdmf_paths"]

#: Suffix of the XDMF file written beside a run file ``OUT.h5`` (``OUT.xmf``).
XDMF_SUFFIX = ".xmf"
#: Appended to the XDMF file's name for the HDF5 file it reads (``OUT.xmf.h5``).
XDMF_DATA_SUFFIX = ".h5"


def xdmf_data_path(xmf: str | Path) -> Path:
    """The HDF5 file that ``xmf`` reads its arrays from: ``OUT.xmf`` -> ``OUT.xmf.h5``."""
    xmf = Path(xmf)
    return xmf.with_name(xmf.name + XDMF_DATA_SUFFIX)


def xdmf_paths(run: str | Path) -> tuple[Path, Path]:
    """``(OUT.xmf, OUT.xmf.h5)`` for the run file ``run`` (``OUT.h5``)."""
    xmf = Path(run).with_suffix(XDMF_SUFFIX)
    return xmf, xdmf_data_path(xmf)
