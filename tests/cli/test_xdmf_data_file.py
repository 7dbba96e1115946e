"""``OUT.xmf.h5``, the HDF5 file that ``OUT.xmf`` reads, is an output of ``pyfold run``
like ``OUT.xmf``: an existing one is refused without ``--force`` and left intact, and
``write_xdmf`` leaves both files or neither."""
from __future__ import annotations

import pytest

from conftest import base_scene, write_scene
from pyfold import run_results
from pyfold.cli import main
from pyfold.errors import PyfoldError
from pyfold.xdmf_files import xdmf_paths


@pytest.fixture
def scene(tmp_path):
    return write_scene(tmp_path / "fibres.toml", base_scene())


def test_existing_xdmf_data_file_refused_without_force_and_kept(scene, tmp_path, fake_fold_run, capsys):
    out = tmp_path / "x.h5"
    xmf, data = xdmf_paths(out)
    assert data.name == "x.xmf.h5"
    data.write_bytes(b"a user's own file")
    assert main(["run", str(scene), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "x.xmf.h5 exists" in err and "--force" in err
    assert data.read_bytes() == b"a user's own file" and not out.exists() and not xmf.exists()
    assert main(["run", str(scene), "-o", str(out), "--force"]) == 0
    assert xmf.is_file() and data.read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"


def test_scene_given_as_the_xdmf_data_file_is_refused(tmp_path, fake_fold_run, capsys):
    out = tmp_path / "x.h5"
    _, data = xdmf_paths(out)
    write_scene(data, base_scene())  # a scene file that happens to carry that name
    assert main(["run", str(data), "-o", str(out)]) == 2
    assert "scene file" in capsys.readouterr().err
    assert not out.exists()


def test_failed_xmf_write_leaves_no_data_file(scene, tmp_path, fake_fold_run, monkeypatch):
    out = tmp_path / "x.h5"
    assert main(["run", str(scene), "-o", str(out)]) == 0
    xmf, data = xdmf_paths(out)
    xmf.unlink()
    data.unlink()
    real = run_results.atomic_output

    def failing_for_xmf(path):
        if str(path).endswith(".xmf"):
            raise PyfoldError(f"cannot write {path}: No space left on device (ENOSPC)")
        return real(path)

    monkeypatch.setattr(run_results, "atomic_output", failing_for_xmf)
    with pytest.raises(PyfoldError, match="ENOSPC"):
        run_results.write_xdmf(out)
    assert not xmf.exists() and not data.exists()
