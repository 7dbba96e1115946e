"""Serialised exports of compiled programs (pyfold._jax.exported_call): a file that
does not verify is never used, and a program run from a file gives what a fresh
trace gives.

A stale or damaged file must cost a new export, never a different answer: each case
below puts a bad file where the export of a program belongs and checks that the
program is traced again (``build`` called), that the answer is the traced one, and
that the file is replaced by a valid export.
"""
from __future__ import annotations

import numpy as np
import pytest

from pyfold import _jax
from pyfold._jax import exported_call, jax, jnp

pytestmark = pytest.mark.skipif(not _jax._can_serialise(), reason="jax export serialisation needs flatbuffers")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty export folder of its own, and no programs loaded in this process."""
    monkeypatch.setattr(_jax, "_CACHE", tmp_path)
    monkeypatch.setattr(_jax, "_LOADED", {})
    return tmp_path / "export"


def _counting_build(scale: float):
    calls = []

    def build():
        calls.append(1)

        @jax.jit
        def f(x, pair):
            y, z = pair
            return jnp.sin(x) * scale + y @ z, jnp.sum(x)

        return f

    return build, calls


ARGS = (np.linspace(0.0, 1.0, 5), (np.arange(6.0).reshape(2, 3), np.ones((3, 5))))


def _expected(scale: float):
    x, (y, z) = ARGS
    return np.sin(x) * scale + y @ z, np.sum(x)


def _only_file(folder):
    files = [p for p in folder.iterdir() if p.suffix == ".jaxexport"]
    assert len(files) == 1, files
    return files[0]


def test_exported_program_gives_the_traced_result_and_is_read_back_without_tracing(cache):
    build, calls = _counting_build(2.0)
    first = exported_call("toy", build, ARGS)
    assert len(calls) == 1
    path = _only_file(cache)
    _jax._LOADED.clear()  # a new process: only the file is left
    second = exported_call("toy", build, ARGS)
    assert len(calls) == 1, "a valid export must be used, not traced again"
    direct = build()(*ARGS)
    for a, b, c in zip(first, second, direct):
        # the same program text compiled the same way: the same floating-point operations
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))
        np.testing.assert_array_equal(np.asarray(b), np.asarray(c))
    np.testing.assert_allclose(np.asarray(first[0]), _expected(2.0)[0], rtol=1e-14, atol=1e-14)
    assert _only_file(cache) == path


def _garbage(blob: bytes) -> bytes:
    return b"not an export at all"


def _flipped_payload(blob: bytes) -> bytes:
    data = bytearray(blob)
    data[-10] ^= 0x01  # the checksum no longer matches
    return bytes(data)


def _truncated(blob: bytes) -> bytes:
    return blob[: len(blob) // 2]


@pytest.mark.parametrize("damage", [_garbage, _flipped_payload, _truncated], ids=["garbage", "flipped", "truncated"])
def test_damaged_export_file_is_traced_again_and_rewritten(cache, damage):
    build, calls = _counting_build(3.0)
    exported_call("toy", build, ARGS)
    path = _only_file(cache)
    good = path.read_bytes()
    path.write_bytes(damage(good))
    _jax._LOADED.clear()
    out = exported_call("toy", build, ARGS)
    assert len(calls) == 2, "a damaged file must not be used"
    np.testing.assert_allclose(np.asarray(out[0]), _expected(3.0)[0], rtol=1e-14, atol=1e-14)
    _jax._LOADED.clear()
    exported_call("toy", build, ARGS)
    assert len(calls) == 2, "the damaged file must have been replaced by a valid export"


def test_valid_export_of_other_shapes_under_this_name_is_refused(cache):
    """A file that verifies but declares other argument shapes (a copied or renamed
    file) is not used."""
    build, calls = _counting_build(1.0)
    other = (np.linspace(0.0, 1.0, 4), (np.ones((2, 3)), np.ones((3, 4))))
    exported_call("toy", build, other)
    foreign = _only_file(cache)
    _jax._LOADED.clear()
    exported_call("toy", build, ARGS)
    assert len(calls) == 2
    mine = [p for p in cache.iterdir() if p != foreign][0]
    mine.write_bytes(foreign.read_bytes())
    _jax._LOADED.clear()
    out = exported_call("toy", build, ARGS)
    assert len(calls) == 3, "an export of other shapes must not be used"
    np.testing.assert_allclose(np.asarray(out[0]), _expected(1.0)[0], rtol=1e-14, atol=1e-14)


def test_an_edit_of_the_package_sources_selects_another_file(cache, monkeypatch):
    """The file name hashes every pyfold source file: a stale export of an edited
    program is never found (here: the same program, under another source digest)."""
    build, calls = _counting_build(1.0)
    exported_call("toy", build, ARGS)
    first = _only_file(cache)
    monkeypatch.setattr(_jax, "_SOURCE_DIGEST", "0" * 64)
    _jax._LOADED.clear()
    exported_call("toy", build, ARGS)
    assert len(calls) == 2
    assert {p.name for p in cache.iterdir()} - {first.name}


def test_without_the_cache_the_program_is_traced_every_time(tmp_path, monkeypatch):
    monkeypatch.setattr(_jax, "_CACHE", None)
    monkeypatch.setattr(_jax, "_LOADED", {})
    build, calls = _counting_build(1.0)
    out = exported_call("toy", build, ARGS)
    exported_call("toy", build, ARGS)
    assert len(calls) == 2
    assert not any(tmp_path.iterdir())
    np.testing.assert_allclose(np.asarray(out[0]), _expected(1.0)[0], rtol=1e-14, atol=1e-14)


def test_least_recently_used_exports_of_a_name_are_removed_beyond_the_limit(cache, monkeypatch):
    import os

    monkeypatch.setattr(_jax, "MAX_EXPORTS_PER_NAME", 2)
    build, calls = _counting_build(1.0)

    def args(n):
        return (np.linspace(0.0, 1.0, n), (np.ones((2, 3)), np.ones((3, n))))

    exported_call("toy", build, args(3))
    oldest = _only_file(cache)
    os.utime(oldest, (1_000_000_000, 1_000_000_000))  # long unused
    exported_call("toy", build, args(4))
    second = [p for p in cache.iterdir() if p != oldest][0]
    os.utime(second, (1_000_000_100, 1_000_000_100))
    _jax._LOADED.clear()
    exported_call("toy", build, args(3))  # read back: marked used, now the newest
    assert len(calls) == 2
    exported_call("toy", build, args(5))  # a third: the least recently used goes
    names = {p.name for p in cache.iterdir()}
    assert len(names) == 2 and oldest.name in names and second.name not in names
