"""`pyfold analyse RUN.h5 --model ...`: orientation-model parameters with errors, and their export."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import base_scene, write_scene

from pyfold.cli import main
from pyfold.fit import fit_parameters
from pyfold.models import FolgarTucker
from pyfold.moulding_export import read_export
from pyfold.run_results import open_run


#: The model behind the synthetic records: RSC with IBOF (Wang, O'Gara & Tucker 2008).
TRUE = {"ci": 0.01, "kappa": 0.3}


@pytest.fixture(scope="module")
def run_file(tmp_path_factory) -> Path:
    """A dilute Jeffery run (8 fibres, beta = 10) to a strain of 2 with the real fold_run."""
    import os

    folder = tmp_path_factory.mktemp("models")
    s = base_scene()
    s["numerics"].update(t_end=2.0, dt=0.01)
    s["output"] = {"interval": 0.1, "snapshot_interval": 1.0}
    scene = write_scene(folder / "scene.toml", s)
    os.environ.pop("PYFOLD_FOLD_RUN", None)
    assert main(["run", str(scene), "-o", str(folder / "run.h5")]) == 0
    return folder / "run.h5"


@pytest.fixture(scope="module")
def rsc_run(run_file, tmp_path_factory) -> Path:
    """The run file with its records replaced by RSC's a2(t) (IBOF, TRUE) from its own
    first record, and a4 = IBOF(a2): a run whose answer is known. HDF5 recomputes the
    Fletcher32 checksums of the rewritten chunks, so the file still verifies."""
    import shutil

    import h5py

    from pyfold.closures import get_closure
    from pyfold.kinematics import simple_shear
    from pyfold.models import RSC, solve_orientation

    path = tmp_path_factory.mktemp("rsc") / "rsc.h5"
    shutil.copy(run_file, path)
    with h5py.File(path, "a") as f:
        t = f["time"][()]
        xi = float(f["initial/xi"][0])
        model = RSC(ci=TRUE["ci"], kappa=TRUE["kappa"], xi=xi, closure="ibof")
        sol = solve_orientation(model, f["a2"][0], simple_shear(1.0), t, rtol=1e-11, atol=1e-13)
        a2 = np.asarray(sol.a2)
        f["a2"][...] = a2
        f["a4"][...] = np.asarray(get_closure("ibof")(a2))
    return path


def test_open_run_gives_what_a_model_fit_needs(run_file):
    ds = open_run(run_file)
    np.testing.assert_array_equal(ds.attrs["velocity_gradient"], [0, 1, 0, 0, 0, 0, 0, 0, 0])
    assert ds.attrs["xi"] == float(ds["particle_xi"].values[0])
    fit = fit_parameters(ds, FolgarTucker(ci=1e-3, xi=ds.attrs["xi"]), params=("ci",), closure="ibof")
    assert fit.success, fit.message


def test_rsc_parameters_recovered_with_errors_and_exported(rsc_run, tmp_path, capsys):
    """Noise-free records of RSC: the fit returns its parameters. The records were solved to
    rtol 1e-11 and the fit's solves run at rtol 1e-9, so the misfit at the truth is ~1e-9 and
    the parameters (sensitivities of order 0.1-1 over a strain of 2) are off by ~1e-8: a
    relative 1e-5 is a bound with three decades of margin."""
    export = tmp_path / "params.toml"
    assert main(["analyse", str(rsc_run), "--model", "rsc", "--export", str(export)]) == 0, \
        capsys.readouterr()
    out = capsys.readouterr().out
    assert "rsc / ibof: ci = " in out and "kappa = " in out and "±" in out
    doc = read_export(export)
    assert doc["format"] == "pyfold.orientation_parameters"
    assert doc["source"]["file"] == str(rsc_run) and doc["source"]["strain_end"] == pytest.approx(2.0)
    (fit,) = doc["fits"]
    assert fit["model"] == "rsc" and fit["closure"] == "ibof" and fit["success"]
    assert set(fit["parameters"]) == {"C_I", "kappa", "lambda"}
    for name, key in (("C_I", "ci"), ("kappa", "kappa")):
        entry = fit["parameters"][name]
        assert entry["fitted"] and entry["stderr"] >= 0 and not entry["at_bound"]
        assert entry["value"] == pytest.approx(TRUE[key], rel=1e-5)
    assert fit["parameters"]["lambda"]["fitted"] is False


@pytest.mark.parametrize("argv, key", [
    (["--model", "ard"], "--model"),
    (["--model", ""], "--model"),
    (["--model", "ft,rsc", "--params", "ci"], "--params"),
    (["--model", "rsc", "--params", "b1"], "--params"),
    (["--model", "ft", "--closures", "nope"], "--closures"),
    (["--model", "ft", "--export", "p.csv"], "--export"),
])
def test_bad_model_options_are_refused(run_file, tmp_path, capsys, argv, key):
    assert main(["analyse", str(run_file), *argv]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err


def test_an_undetermined_parameter_is_said_so():
    """iARD's C_M has no effect once C_I sits on 0: its linearised error is not finite,
    and the line says the records do not determine it instead of printing ± nan."""
    from pyfold.model_fit import ModelFit, describe

    fit = ModelFit(model="iard", closure="ibof", values={"ci": 0.0, "cm": 0.5, "xi": 0.97}, fitted=("ci", "cm"),
                   stderr={"ci": 1e-5, "cm": float("nan")}, at_bound={"ci": True, "cm": False}, residual_rms=0.01,
                   success=True, message="")
    line = describe(fit)
    assert "ci = 0 ± 1e-05 (on its bound)" in line and "cm = 0.5 (not determined by the records)" in line
    assert "nan" not in line
