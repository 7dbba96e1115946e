"""`pyfold fit-ci`: Tucker's FitCI from a measured steady A11, and its export."""
from __future__ import annotations

import json

import pytest

from pyfold.cli import main
from pyfold.fit import steady_state_a2
from pyfold.kinematics import simple_shear
from pyfold.models import FolgarTucker
from pyfold.moulding_export import read_export


def _ci(out: str) -> float:
    return float(out.split("C_I = ")[1].split()[0])


def test_tucker_fitci_example(capsys):
    """Tucker's FitCI example: A11 = 0.8261, IBOF, xi = 1 -> C_I = 0.0054 (4 decimals published)."""
    assert main(["fit-ci", "--a11", "0.8261", "--closure", "ibof"]) == 0
    out = capsys.readouterr().out
    assert round(_ci(out), 4) == 0.0054
    assert "A11 = 0.826100" in out


@pytest.mark.parametrize("closure", ["ibof", "orw3", "hybrid"])
def test_fit_ci_inverts_the_steady_state(tmp_path, capsys, closure):
    """Forward: the steady A11 of Folgar-Tucker with C_I = 0.01 at beta = 10; back: fit-ci
    recovers C_I. Error bound: the steady state is solved to |da2/dt| <= 1e-13 and Brent's
    method stops at 1e-12 in C_I; with d a11/d C_I of order 10 the recovered C_I is within
    ~1e-11 of the true one: 1e-9 leaves two decades of margin."""
    beta = 10.0
    xi = (beta**2 - 1) / (beta**2 + 1)
    a11 = float(steady_state_a2(FolgarTucker(ci=0.01, xi=xi, closure=closure), simple_shear(1.0))[0, 0])
    export = tmp_path / "ci.json"
    assert main(["fit-ci", "--a11", repr(a11), "--beta", "10", "--closure", closure, "--export", str(export)]) == 0
    assert _ci(capsys.readouterr().out) == pytest.approx(0.01, abs=1e-9)
    doc = read_export(export)
    assert doc["format"] == "pyfold.orientation_parameters"
    fit = doc["fits"][0]
    assert fit["model"] == "folgar-tucker" and fit["closure"] == closure
    assert fit["parameters"]["C_I"]["value"] == pytest.approx(0.01, abs=1e-9)
    assert fit["parameters"]["lambda"]["value"] == pytest.approx(xi, rel=1e-15)
    assert doc["source"]["a11"] == a11 and doc["source"]["beta"] == 10.0


def test_fit_ci_exports_toml(tmp_path, capsys):
    export = tmp_path / "ci.toml"
    assert main(["fit-ci", "--a11", "0.8261", "--export", str(export)]) == 0
    doc = read_export(export)
    assert round(doc["fits"][0]["parameters"]["C_I"]["value"], 4) == 0.0054
    assert json.dumps(doc)  # plain data


@pytest.mark.parametrize("argv, key", [
    (["--a11", "0.3"], "--a11"),
    (["--a11", "1.2"], "--a11"),
    (["--a11", "nan"], "--a11"),
    (["--a11", "0.8", "--beta", "0"], "--beta"),
    (["--a11", "0.8", "--xi", "1.5"], "--xi"),
    (["--a11", "0.8", "--closure", "nope"], "--closure"),
    (["--a11", "0.8", "--export", "ci.csv"], "--export"),
])
def test_bad_input_is_refused_naming_the_option(capsys, argv, key):
    assert main(["fit-ci", *argv]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err


def test_an_existing_export_is_not_replaced(tmp_path, capsys):
    export = tmp_path / "ci.json"
    export.write_text("keep")
    assert main(["fit-ci", "--a11", "0.8261", "--export", str(export)]) == 2
    assert "exists" in capsys.readouterr().err and export.read_text() == "keep"
