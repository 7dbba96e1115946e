"""Sweep files: every bad one refused with exit 2 naming the key and what it accepts,
nothing written; runs identified by their normalised scene."""
from __future__ import annotations

from pathlib import Path

import pytest

from _sweep_helpers import EXAMPLE, EXAMPLE_SCENE, no_traceback, pyfold, write_sweep
from pyfold.errors import InputError
from pyfold.sweep.plan import plan, set_key
from pyfold.sweep.spec import read_sweep

GOOD_HEAD = f'[sweep]\nscene = "{EXAMPLE_SCENE}"\nseeds = [1]\n'

#: (sweep file text, words the message must hold)
BAD = [
    ('[sweep]\nseeds = [1]\n', ["sweep.scene", "sweep.builder"]),
    (GOOD_HEAD + 'colour = "red"\n', ["sweep.colour", "allowed", "seeds"]),
    (GOOD_HEAD.replace("[1]", "[]"), ["sweep.seeds", "non-empty"]),
    (GOOD_HEAD.replace("[1]", "[1, 1]"), ["sweep.seeds", "distinct"]),
    (GOOD_HEAD.replace("[1]", "[-3]"), ["sweep.seeds", "from 0"]),
    (GOOD_HEAD + '[resources]\nnp = 0\n', ["resources.np", "from 1"]),
    (GOOD_HEAD + '[resources]\ntime = "soon"\n', ["resources.time", "HH:MM:SS"]),
    (GOOD_HEAD + '[resources]\nmem = "lots"\n', ["resources.mem", "K, M, G or T"]),
    (GOOD_HEAD + '[resources]\ngpus = 1\n', ["resources.gpus", "allowed", "np", "partition"]),
    (GOOD_HEAD + '[axes]\n"particles[0].count" = []\n', ["axes.particles[0].count", "non-empty"]),
    (GOOD_HEAD + '[axes]\n"particles[3].count" = [8]\n', ["particles[3].count", "index 3"]),
    (GOOD_HEAD + '[axes]\n"particles[0].count" = [-5]\n', ["particles[0].count"]),
    (GOOD_HEAD + '[axes]\n"numerics.dt" = [0.0]\n', ["numerics.dt"]),
    (GOOD_HEAD + '[colours]\nred = 1\n', ["colours", "allowed", "axes"]),
    ('[sweep]\nbuilder = "no colon"\nseeds = [1]\n', ["sweep.builder", "module:function"]),
    ('[sweep]\nbuilder = "pyfold.scene.sheared_fibres:sheared_fibres"\nseeds = [1]\n[arguments]\nbeta = 0.5\n'
     'n_l3 = 1.0\nt_end = 1.0\n', ["beta", ">= 1"]),
    ("[sweep\n", ["not valid TOML"]),
]


@pytest.mark.parametrize("text, words", BAD, ids=[f"bad{i}" for i in range(len(BAD))])
def test_bad_sweep_file_exit_2_nothing_written(tmp_path, text, words):
    sweep = write_sweep(tmp_path / "bad.toml", text)
    out = tmp_path / "out"
    proc = pyfold("sweep", "run", str(sweep), "--out", str(out))
    no_traceback(proc)
    assert proc.returncode == 2, proc.stderr
    for word in words:
        assert word in proc.stderr, (word, proc.stderr)
    assert not out.exists()


def test_bad_command_line_values(tmp_path):
    out = tmp_path / "out"
    for args, word in ((["--executor", "cloud"], "--executor"), (["--np", "0"], "np"),
                       (["--time", "forever"], "time"), (["--parallel", "0"], "--parallel")):
        proc = pyfold("sweep", "run", str(EXAMPLE), "--out", str(out), *args)
        no_traceback(proc)
        assert proc.returncode == 2 and word in proc.stderr, (args, proc.stderr)
    assert not out.exists()
    proc = pyfold("sweep", "status", str(tmp_path))
    assert proc.returncode == 2 and "not a sweep folder" in proc.stderr


def test_out_holding_another_sweep_refused(tmp_path):
    """A sweep folder is reused only by the sweep that made it (same runs)."""
    from pyfold.sweep import store

    spec = read_sweep(EXAMPLE)
    store.prepare(tmp_path / "out", spec, plan(spec))
    other = write_sweep(tmp_path / "other.toml", GOOD_HEAD + '[axes]\n"particles[0].count" = [30]\n')
    before = sorted(p.name for p in (tmp_path / "out" / "runs").iterdir())
    proc = pyfold("sweep", "run", str(other), "--out", str(tmp_path / "out"))
    assert proc.returncode == 2 and "holds another sweep" in proc.stderr, proc.stderr
    assert sorted(p.name for p in (tmp_path / "out" / "runs").iterdir()) == before


def test_example_has_four_distinct_runs():
    spec = read_sweep(EXAMPLE)
    runs = plan(spec)
    assert len(runs) == 4 and len({r.run_id for r in runs}) == 4
    assert [(r.point["particles[0].count"], r.seed) for r in runs] == [(24, 1), (24, 2), (48, 1), (48, 2)]


def test_identity_is_the_normalised_scene(tmp_path):
    """Same simulation -> same id, whatever the key order, spelling of defaults or title;
    another value -> another id."""
    text = EXAMPLE_SCENE.read_text()
    reordered = tmp_path / "reordered.toml"
    # the title changed and a default written out explicitly: the same simulation
    reordered.write_text(text.replace('title = "sweep example: fibres in simple shear"', 'title = "other"')
                         .replace("[output]\n", "[output]\nsnapshot_interval = 20.0\n", 1)
                         .replace("snapshot_interval = 20.0\n", "", 1)
                         .replace("[model]\n", "[model]\nlubrication = false\n"))

    def ids(scene: Path, counts: str) -> list[str]:
        sweep = write_sweep(tmp_path / "s.toml", f'[sweep]\nscene = "{scene}"\nseeds = [1, 2]\n[axes]\n'
                                                 f'"particles[0].count" = {counts}\n')
        return [r.run_id for r in plan(read_sweep(sweep))]

    assert ids(EXAMPLE_SCENE, "[24, 48]") == ids(reordered, "[24, 48]")
    assert ids(EXAMPLE_SCENE, "[48, 24]") == [*ids(EXAMPLE_SCENE, "[24, 48]")[2:], *ids(EXAMPLE_SCENE, "[24, 48]")[:2]]
    assert set(ids(EXAMPLE_SCENE, "[24, 30]")) & set(ids(EXAMPLE_SCENE, "[48]")) == set()


def test_set_key_paths():
    table = {"a": {"b": [1, 2]}, "particles": [{"count": 1}]}
    set_key(table, "a.b[1]", 5)
    set_key(table, "particles[0].count", 9)
    set_key(table, "numerics.seed", 4)
    assert table == {"a": {"b": [1, 5]}, "particles": [{"count": 9}], "numerics": {"seed": 4}}
    for bad in ("a..b", "particles[1].count", "a.b.c"):
        with pytest.raises(InputError, match=bad.replace("[", r"\[").replace("]", r"\]")):
            set_key(table, bad, 1)


def test_builder_sweep_with_points(tmp_path):
    """A Python builder with explicit points: its arguments and seed go to the builder."""
    sweep = write_sweep(tmp_path / "b.toml", '''[sweep]
builder = "pyfold.scene.sheared_fibres:sheared_fibres"
seeds = [1, 2]
[arguments]
t_end = 1.0
[[points]]
beta = 5.0
n_l3 = 2.0
[[points]]
beta = 10.0
n_l3 = 4.0
''')
    spec = read_sweep(sweep)
    runs = plan(spec)
    assert spec.axes == {"beta": (5.0, 10.0), "n_l3": (2.0, 4.0)}
    assert len(runs) == 4 and len({r.run_id for r in runs}) == 4
    assert "seed = 2" in runs[1].toml


def test_same_sweep_narrowed_takes_the_folder_over(tmp_path):
    """The same sweep (same name) with fewer seeds reuses the folder and its runs' folders."""
    import dataclasses

    from pyfold.sweep import store

    spec = read_sweep(EXAMPLE)
    runs = plan(spec)
    store.prepare(tmp_path / "out", spec, runs)
    narrowed = dataclasses.replace(spec, seeds=(1,))
    data = store.prepare(tmp_path / "out", narrowed, plan(narrowed))
    assert [r["id"] for r in data["runs"]] == [r.run_id for r in runs if r.seed == 1]
    assert store.read_manifest(tmp_path / "out")["seeds"] == [1]
    assert len(list((tmp_path / "out" / "runs").iterdir())) == 4  # the other runs' folders stay


#: The names of the example sweep's runs (data/sweeps/example.toml), fixed when it was written: a
#: setting added to the scene schema later must leave them as they are (the registry's
#: ``identity_at_default = False``), or every sweep folder made before it would start afresh.
EXAMPLE_IDS = ["6af34cd3a8a47f85", "515500aaa3e461b6", "3a72d51ceaff1714", "fed7639bf2f1876d"]


def test_runs_named_before_a_later_setting_keep_their_names_and_the_setting_counts_when_set(tmp_path):
    assert [r.run_id for r in plan(read_sweep(EXAMPLE))] == EXAMPLE_IDS
    text = EXAMPLE_SCENE.read_text()
    assert "[numerics.stokes]" not in text

    def ids(extra: str) -> list[str]:
        scene = tmp_path / "scene.toml"
        scene.write_text(text + extra)
        sweep = write_sweep(tmp_path / "s.toml", f'[sweep]\nscene = "{scene}"\nseeds = [1, 2]\n[axes]\n'
                                                 f'"particles[0].count" = [24, 48]\n')
        return [r.run_id for r in plan(read_sweep(sweep))]

    assert ids("\n[numerics.stokes]\nfibre_radius_scale = 1.0\n") == EXAMPLE_IDS
    assert set(ids("\n[numerics.stokes]\nfibre_radius_scale = 1.2\n")).isdisjoint(EXAMPLE_IDS)
