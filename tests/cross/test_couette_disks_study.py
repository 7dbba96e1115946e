"""The seed's Couette-disk study (studies/seed_examples/couette_disks.py) in its smallest
form: its scenes are the bundled scene with only the case's keys changed, and its
contacts-only runs reproduce the slides (no overlap with the collision strategy,
overlaps without it); the Stokes form resolves to the hypre backend and, once that
backend is built, runs with a wall shear stress above the fluid's."""
from __future__ import annotations

import numpy as np
import pytest

from pyfold.native import stokes as stokes_codes
from pyfold.scene import parse_scene

from study_import import import_study  # helper module next to this file


@pytest.fixture(scope="module")
def study():
    return import_study("seed_examples", "couette_disks")


def _tiny(study):
    # 2 s = 40 steps of the slide's dt: the no-strategy runs overlap within the first second
    return study.Form(seeds=(1,), t_end=2.0, cells_per_diameter=4)


@pytest.mark.parametrize("hydrodynamics", ["jeffery", "stokes"])
def test_study_scenes_change_only_the_case_keys_of_the_bundled_scene(study, hydrodynamics):
    import tomli_w

    base = study.base_scene()
    for case, (collisions, alpha) in study.CASES.items():
        scene = study.scene_of(case, 2, hydrodynamics, study.SMALL)
        for table in ("cell", "flow", "particles"):
            assert scene[table] == base[table]
        assert scene["model"] == dict(base["model"], hydrodynamics=hydrodynamics, collisions=collisions, alpha=alpha)
        res = parse_scene(tomli_w.dumps(scene))
        assert res.hydrodynamics == hydrodynamics and res.collisions == collisions and res.alpha == alpha
        assert res.output_every == res.snapshot_every == 1 and res.seed == 2
        if hydrodynamics == "stokes":
            assert int(res.resolved_datasets()["stokes_backend"][0]) == stokes_codes.BACKENDS["hypre"]


def test_contacts_only_strategy_never_overlaps_and_no_strategy_does(study, tmp_path):
    ds = study.run("jeffery", _tiny(study), tmp_path, figures=False)
    overlaps = ds["overlaps"]
    assert overlaps.sizes["time"] == 41
    assert int(overlaps.sel(case="strategy").max()) == 0
    assert int(ds["in_zone"].sel(case="strategy").max()) == 0
    assert int(overlaps.sel(case="none").max()) > 0
    assert float(ds["n_corrections"].sel(case="strategy").sum()) > 0  # the strategy did act
    # fold_run's min_gap and the snapshot's are the same configuration: they differ by the
    # round-off of a distance in a cell of side <= 1.5, a few eps; the contact loop's own
    # tolerance 64 eps max(L) bounds it
    assert float(ds["min_gap_check"].max()) <= 64 * np.finfo(float).eps * 1.5
    assert (tmp_path / "couette_disks.nc").exists() and (tmp_path / "couette_disks.md").exists()


def test_stokes_form_runs_with_the_hypre_backend(study, tmp_path):
    ds = study.run("stokes", study.Form(seeds=(1,), t_end=0.5, cells_per_diameter=4), tmp_path, figures=False)
    assert int(ds["overlaps"].sel(case="strategy").max()) == 0
    # rigid disks only add dissipation: the power the walls put in, tau_w 2U Lx, is at least
    # the particle-free eta gamma_dot^2 Lx Ly, so tau_w >= eta gamma_dot = 1 Pa
    assert float(ds["wall_shear_stress"].min()) > 1.0
