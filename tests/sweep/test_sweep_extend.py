"""A sweep continues finished runs of its scenes to a later end (pyfold.sweep.donors).

Tiny contacts-only scenes (16 fibres, 200 and 400 steps: seconds per run, mostly start-up).
A sweep run to t_end T1 and the same sweep file with t_end T2 > T1 in the same folder:
the long runs start as copies of the short ones (each its own seed's) and are extended;
their records up to T1 equal the short runs' bit for bit, they go on to T2, and each
equals a run of T2 made in one go, dataset for dataset; the short runs stay byte for
byte as they were. Of several donors the one with the latest end is taken.
``--extend-from`` takes donors from another sweep folder; a finished run that differs
in more than t_end (here a record interval pyfold.extend refuses) is no donor; an
extension stopped right after its copy resumes like any interrupted run;
``--extend-from`` naming what is not a sweep folder is exit 2 naming the option.
"""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from _sweep_helpers import EXAMPLE_SCENE, no_traceback, pyfold, write_sweep
from pyfold.sweep import donors, store
from pyfold.sweep.plan import plan
from pyfold.sweep.spec import read_sweep

T1, T2 = 2.0, 4.0


def _sweep(folder: Path, t_end: float, name: str = "tiny", seeds: tuple[int, ...] = (1, 2),
           interval: float = 0.1, checkpoint: float | None = 0.5, scene: Path = EXAMPLE_SCENE) -> Path:
    """16 fibres of the bundled example scene, explicit intervals (so that a run of T1
    extended to T2 and a run of T2 made in one go record alike); ``checkpoint`` None leaves
    the checkpoint interval to ``scene``'s."""
    checkpoint_line = "" if checkpoint is None else f'"output.checkpoint_interval" = {checkpoint!r}\n'
    return write_sweep(folder / f"{name}_{t_end:g}_{interval:g}_{checkpoint}.toml", f'''[sweep]
name = "{name}"
scene = "{scene}"
seeds = {list(seeds)}

[arguments]
"particles[0].count" = 16
"numerics.t_end" = {t_end!r}
"output.interval" = {interval!r}
"output.snapshot_interval" = 1.0
{checkpoint_line}''')


def _run(sweep: Path, out: Path, *extra: str):
    proc = pyfold("sweep", "run", str(sweep), "--out", str(out), *extra)
    no_traceback(proc)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    return proc


def _by_seed(root: Path) -> dict[int, Path]:
    """seed -> run folder of the sweep last run in ``root``."""
    runs = json.loads((root / store.MANIFEST).read_text())["runs"]
    return {r["seed"]: store.run_folder(root, r["id"]) for r in runs}


def _fingerprint(root: Path) -> dict[str, str]:
    """Every file under ``root`` (a sweep folder) with its SHA-256."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _datasets(path: Path) -> dict[str, tuple[np.ndarray, bool]]:
    """Every dataset of a run file: its value, and whether it grows along its first axis (records, snapshots)."""
    out: dict[str, tuple[np.ndarray, bool]] = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            out[name] = (np.asarray(obj[()]), bool(obj.maxshape and obj.maxshape[0] is None))

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return out


def _assert_continues(short: Path, long: Path) -> None:
    """``long`` holds ``short``'s records and snapshots bit for bit, then goes on to T2."""
    a, b = _datasets(short), _datasets(long)
    grown = [name for name, (_, growing) in a.items() if growing]
    assert "time" in grown and "a2" in grown
    for name in grown:
        va, vb = a[name][0], b[name][0]
        assert vb.shape[0] > va.shape[0], name
        assert vb[: va.shape[0]].tobytes() == va.tobytes(), f"{name} differs before t = {T1:g}"
    assert a["time"][0][-1] == T1 and b["time"][0][-1] == T2


def _assert_same_run(a: Path, b: Path) -> None:
    """Every dataset of the two run files equal bit for bit."""
    da, db = _datasets(a), _datasets(b)
    assert sorted(da) == sorted(db)
    for name in da:
        assert da[name][0].dtype == db[name][0].dtype and da[name][0].tobytes() == db[name][0].tobytes(), name


@pytest.fixture(scope="module")
def short(tmp_path_factory) -> Path:
    """A finished sweep of two seeds to T1 (copied by each test that adds runs to it)."""
    folder = tmp_path_factory.mktemp("short")
    root = folder / "sweep"
    _run(_sweep(folder, T1), root)
    return root


def test_extend_from_not_a_sweep_folder_exit_2(tmp_path):
    sweep = _sweep(tmp_path, T2)
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "notes.txt").write_text("not a sweep")
    for given, words in ((tmp_path / "missing", "is not a folder"), (plain, "is not a sweep folder"),
                         (sweep, "is not a folder")):
        out = tmp_path / "out"
        proc = pyfold("sweep", "run", str(sweep), "--out", str(out), "--extend-from", str(given))
        no_traceback(proc)
        assert proc.returncode == 2, proc.stderr
        assert "--extend-from" in proc.stderr and str(given) in proc.stderr and words in proc.stderr, proc.stderr
        assert not out.exists()  # refused before anything was written


def test_raised_t_end_extends_the_short_runs(tmp_path, short):
    root = tmp_path / "sweep"
    shutil.copytree(short, root)
    shorts = _by_seed(root)
    before = {seed: _fingerprint(folder) for seed, folder in shorts.items()}

    proc = _run(_sweep(tmp_path, T2), root)
    longs = _by_seed(root)
    for seed, folder in longs.items():
        note = f"extended from {shorts[seed].name} at t = {T1:g}"
        assert f"{folder.name} started, {note}" in proc.stdout  # each seed continues its own
        assert store.run_state(folder).state == "done"
        _assert_continues(shorts[seed] / store.RUN_FILE, folder / store.RUN_FILE)
        assert donors.extended_from(folder).run_id == shorts[seed].name
    assert {seed: _fingerprint(folder) for seed, folder in shorts.items()} == before  # donors untouched
    status = pyfold("sweep", "status", str(root))
    assert status.returncode == 0 and status.stdout.count(f"done (extended from ") == 2, status.stdout

    # the same sweep of T2 made in one go elsewhere (no donor there) equals the extended runs
    fresh = tmp_path / "fresh"
    proc = _run(_sweep(tmp_path, T2), fresh)
    assert "extended from" not in proc.stdout
    for seed, folder in _by_seed(fresh).items():
        assert folder.name == longs[seed].name
        _assert_same_run(folder / store.RUN_FILE, longs[seed] / store.RUN_FILE)

    again = _run(_sweep(tmp_path, T2), root)
    assert "nothing to run" in again.stdout

    # raised once more: of the two finished runs of each seed, the later end is the donor
    spec = read_sweep(_sweep(tmp_path, 2 * T2))
    runs = plan(spec)
    store.prepare(root, spec, runs)
    found = donors.plan_donors(root, [r.run_id for r in runs])
    assert {r.seed: found[r.run_id].run_id for r in runs} == {seed: f.name for seed, f in longs.items()}
    assert all(d.t_end == T2 for d in found.values())


def test_extend_from_another_sweep_folder(tmp_path, short):
    before = _fingerprint(short)
    root = tmp_path / "longer"
    proc = _run(_sweep(tmp_path, T2, name="longer"), root, "--extend-from", str(short))
    shorts = _by_seed(short)
    for seed, folder in _by_seed(root).items():
        assert f"{folder.name}: extended from {shorts[seed].name} at t = {T1:g}" in proc.stdout
        assert store.run_state(folder).state == "done"
        _assert_continues(shorts[seed] / store.RUN_FILE, folder / store.RUN_FILE)
    assert _fingerprint(short) == before  # the donor sweep stays as it was


def test_donor_differing_in_more_than_t_end_is_not_used(tmp_path, short):
    # the record interval differs: the scenes share everything pyfold.extend may not change
    # but that interval, which a continued run keeps as recorded; so no donor, a run from t = 0
    root = tmp_path / "other_interval"
    proc = _run(_sweep(tmp_path, T2, seeds=(1,), interval=0.2), root, "--extend-from", str(short))
    assert "extended from" not in proc.stdout
    (folder,) = _by_seed(root).values()
    assert not (folder / store.DONOR).exists()
    assert [a["from"] for a in store.attempts(folder)] == ["queued"]
    assert donors.extended_from(folder) is None
    with h5py.File(folder / store.RUN_FILE, "r") as f:
        assert f["time"][-1] == T2 and len(f["time"]) == round(T2 / 0.2) + 1


def test_extension_stopped_after_its_copy_resumes(tmp_path, short):
    # as if the worker was killed between copying its donor and extending it: the copy
    # (status ok, the donor's /setup) is an interrupted run, continued by the next sweep run
    root = tmp_path / "stopped"
    sweep = _sweep(tmp_path, T2, seeds=(1,))
    spec = read_sweep(sweep)
    runs = plan(spec)
    store.prepare(root, spec, runs)
    (rid,) = [r.run_id for r in runs]
    folder = store.run_folder(root, rid)
    found = donors.plan_donors(root, [rid], [short])
    assert found[rid].run_id == _by_seed(short)[1].name
    assert donors.start_from_donor(folder) == found[rid]
    assert store.run_state(folder).state == "interrupted"
    assert donors.start_from_donor(folder) is None  # never over a partial run

    _run(sweep, root)
    assert store.run_state(folder).state == "done"
    assert [a["from"] for a in store.attempts(folder)] == ["interrupted"]
    _assert_continues(_by_seed(short)[1] / store.RUN_FILE, folder / store.RUN_FILE)


def test_donor_with_another_default_interval_is_not_used(tmp_path):
    # the checkpoint interval left to its default (t_end/20) differs between the two ends: an
    # extension would keep the donor's, so one run id could hold two different files (and
    # pyfold sweep gather refuse the ensemble); the run starts at t = 0 instead
    scene = tmp_path / "default_checkpoints.toml"
    text = EXAMPLE_SCENE.read_text(encoding="utf-8")
    scene.write_text("\n".join(line for line in text.splitlines() if not line.startswith("checkpoint_interval")),
                     encoding="utf-8")
    assert "checkpoint_interval" not in scene.read_text(encoding="utf-8") and "checkpoint_interval" in text
    root = tmp_path / "defaults"
    _run(_sweep(tmp_path, T1, seeds=(1,), checkpoint=None, scene=scene), root)
    proc = _run(_sweep(tmp_path, T2, seeds=(1,), checkpoint=None, scene=scene), root)
    assert "extended from" not in proc.stdout
    (folder,) = _by_seed(root).values()
    assert [a["from"] for a in store.attempts(folder)] == ["queued"]
    with h5py.File(folder / store.RUN_FILE, "r") as f:
        assert f["time"][-1] == T2 and int(f["setup/resolved/checkpoint_every"][()]) == round(T2 / 20 / 0.01)
