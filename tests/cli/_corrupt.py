"""Flip bytes of a run file where a given dataset keeps its data (tests and
benchmarks/kill_resume.py): the file offsets come from HDF5 itself (the chunk index of
a chunked dataset, the data address of a contiguous one)."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np


def data_offset(path: str | Path, name: str, index: int = 0) -> int:
    """File offset of the first byte of entry ``index`` (along the first axis) of the
    dataset ``name``; for a chunked, filtered dataset an offset inside the chunk's
    stored bytes that holds that entry (Fletcher32 stores the data unchanged, then its
    checksum)."""
    with h5py.File(path, "r") as f:
        ds = f[name]
        entry = ds.dtype.itemsize * int(np.prod(ds.shape[1:], dtype=np.int64)) if ds.ndim else ds.dtype.itemsize
        if ds.chunks is None:
            offset = ds.id.get_offset()
            if offset is None:
                raise ValueError(f"{name}: no data stored in the file (compact or empty)")
            return int(offset) + index * entry
        rows = ds.chunks[0]
        chunk = (index // rows,) + (0,) * (ds.ndim - 1)
        info = ds.id.get_chunk_info_by_coord(tuple(c * s for c, s in zip(chunk, ds.chunks)))
        per_row = ds.dtype.itemsize * int(np.prod(ds.chunks[1:], dtype=np.int64))
        return int(info.byte_offset) + (index % rows) * per_row


def data_ranges(path: str | Path) -> dict[str, list[tuple[int, int]]]:
    """``{dataset: [(offset, size), ...]}``: the stored bytes of every dataset's data."""
    ranges: dict[str, list[tuple[int, int]]] = {}

    def visit(name, obj):
        if not isinstance(obj, h5py.Dataset):
            return
        if obj.chunks is None:
            offset = obj.id.get_offset()
            if offset is not None:
                ranges["/" + name] = [(int(offset), int(obj.id.get_storage_size()))]
            return
        ranges["/" + name] = [(int(c.byte_offset), int(c.size))
                              for c in (obj.id.get_chunk_info(k) for k in range(obj.id.get_num_chunks()))]

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return ranges


def flip(path: str | Path, offset: int, mask: int = 0x10) -> None:
    """XOR one byte of the file at ``offset`` with ``mask``."""
    with open(path, "r+b") as fh:
        fh.seek(offset)
        byte = fh.read(1)
        fh.seek(offset)
        fh.write(bytes([byte[0] ^ mask]))
