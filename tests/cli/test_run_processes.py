"""Processes of `pyfold run` / `pyfold main`: --np is bounded by the machine, killing
pyfold (SIGTERM, SIGINT) takes mpirun and every rank with it (exit 143 / 130, the
partial run file kept for --resume), `pyfold main --closures bogus` is refused before
anything runs, and the particle placement shows progress and stops on Ctrl-C."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import sys
import time
from pathlib import Path

import h5py
import pytest

from conftest import base_scene, write_scene
from pyfold.cli import main
import pyfold.commands.run as run_command

ROOT = Path(__file__).resolve().parents[2]
#: The stated bounds of --np (defaults so that each test also runs, and fails, on a pyfold without them).
OVERSUBSCRIBE_FACTOR = getattr(run_command, "OVERSUBSCRIBE_FACTOR", 4)
MAX_RANKS = getattr(run_command, "MAX_RANKS", 4096)


def usable_cores() -> int:
    return len(os.sched_getaffinity(0))


@pytest.fixture
def scene(tmp_path):
    return write_scene(tmp_path / "fibres.toml", base_scene())


@pytest.fixture
def no_real_mpirun(tmp_path, monkeypatch):
    """mpirun / mpiexec stand-ins that fail at once: a pyfold that let a huge --np
    through would otherwise really start that many processes."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name in ("mpirun", "mpiexec"):
        (bin_dir / name).write_text("#!/bin/sh\necho \"stand-in $0: refusing $*\" >&2\nexit 3\n")
        (bin_dir / name).chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")


@pytest.fixture
def no_simulation(monkeypatch):
    """`pyfold main` must refuse before it simulates anything."""
    import pyfold.commands.run

    def refuse(*args, **kwargs):
        raise AssertionError("the simulation was started")

    monkeypatch.setattr(pyfold.commands.run, "run_scene", refuse)


# --np bounds ------------------------------------------------------------------------

def test_np_beyond_the_machine_needs_oversubscribe(scene, tmp_path, fake_fold_run, no_real_mpirun, capsys):
    bound = OVERSUBSCRIBE_FACTOR * usable_cores()
    out = tmp_path / "o.h5"
    assert main(["run", str(scene), "-o", str(out), "--np", str(bound + 1)]) == 2
    err = capsys.readouterr().err
    assert "--np" in err and str(bound) in err and "--oversubscribe" in err
    assert not out.exists() and not out.with_name("o.h5.partial").exists()
    assert main(["run", str(scene), "-o", str(out), "--np", "1000"]) == 2
    assert "--np" in capsys.readouterr().err


@pytest.mark.parametrize("ranks", [str(MAX_RANKS + 1), str(10**20)])
def test_np_absurd_refused_even_with_oversubscribe(scene, tmp_path, no_real_mpirun, capsys, ranks):
    assert main(["run", str(scene), "-o", str(tmp_path / "o.h5"), "--np", ranks, "--oversubscribe"]) == 2
    err = capsys.readouterr().err
    assert "--np" in err and str(MAX_RANKS) in err


def test_main_np_bounded_and_closures_checked_before_anything_runs(tmp_path, no_real_mpirun, no_simulation, capsys):
    out = tmp_path / "main"
    assert main(["main", "--out", str(out), "--np", "1000"]) == 2
    assert "--np" in capsys.readouterr().err
    assert main(["main", "--out", str(out), "--closures", "exact,bogus"]) == 2
    err = capsys.readouterr().err
    assert "--closures" in err and "bogus" in err and "ibof" in err
    assert not out.exists()  # refused before the results folder (or a simulation) exists


def test_main_closures_of_the_scene_dimension(tmp_path, no_simulation, capsys):
    """ibof is not defined in 2-D: refused for a planar scene, naming --closures."""
    scene = ROOT / "data" / "scenes" / "couette_disks_seed.toml"
    assert main(["main", "--scene", str(scene), "--out", str(tmp_path / "m"), "--closures", "ibof"]) == 2
    err = capsys.readouterr().err
    assert "--closures" in err and "2-D" in err


# killing pyfold takes its process group with it ----------------------------------

def _processes_mentioning(text: str) -> list[tuple[int, str]]:
    """Live processes (not zombies) whose command line contains ``text`` (a /proc scan)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if text in cmdline and state != "Z":
            found.append((int(entry.name), cmdline))
    return found


def _long_scene(tmp_path: Path) -> Path:
    """A dilute Jeffery scene of 10^7 steps (well over 20 s with 2 ranks; it is killed
    long before), checkpointing every 1000 time units."""
    s = base_scene()
    s["numerics"].update(t_end=1.0e5, dt=0.01)
    s["output"] = {"interval": 1000.0, "snapshot_interval": 50000.0, "checkpoint_interval": 1000.0}
    return write_scene(tmp_path / "long.toml", s)


@pytest.mark.skipif(sys.platform != "linux", reason="/proc scan")
@pytest.mark.parametrize("sig, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_killing_pyfold_run_kills_mpirun_and_ranks(tmp_path, monkeypatch, sig, status):
    import shutil

    if shutil.which("mpirun") is None and shutil.which("mpiexec") is None:
        pytest.fail("mpirun not found (Open MPI is installed by scripts/bootstrap)")
    monkeypatch.delenv("PYFOLD_FOLD_RUN", raising=False)
    scene = _long_scene(tmp_path)
    out = tmp_path / "killed.h5"
    partial = str(out) + ".partial"
    proc = subprocess.Popen([sys.executable, "-m", "pyfold.cli", "run", str(scene), "-o", str(out), "--np", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while len(_processes_mentioning(partial)) < 3:  # mpirun and two fold_run ranks
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "fold_run did not start within 60 s"
            time.sleep(0.1)
        time.sleep(1.0)  # well inside the run
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=20)
        assert proc.returncode == status, err
        deadline = time.monotonic() + 5
        while _processes_mentioning(partial) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _processes_mentioning(partial), _processes_mentioning(partial)
        assert "interrupted" in err and "--resume" in err
        assert Path(partial).is_file() and not out.exists()  # kept for --resume
        with h5py.File(partial) as f:
            assert f.attrs["status"] != "ok"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for pid, _ in _processes_mentioning(partial):  # never leave a runaway behind
            os.kill(pid, signal.SIGKILL)


# placement: progress and Ctrl-C ----------------------------------------------------

def _dense_scene(tmp_path: Path) -> Path:
    """Rods (beta = 10) at phi = 0.25: the validation allows it, but the placement
    kernel works for minutes (and then fails) on it."""
    s = base_scene()
    s["cell"]["size"] = [3.2, 3.2, 3.2]
    s["particles"] = [{"name": "rods", "shape": "fibre", "length": 1.0, "radius": 0.05, "volume_fraction": 0.25}]
    s["model"] = {"alpha": 0.01}
    s["numerics"].update(seed=2024, t_end=0.1)
    return write_scene(tmp_path / "dense.toml", s)


def test_placement_shows_progress_and_stops_on_ctrl_c(tmp_path, fake_fold_run):
    out = tmp_path / "dense.h5"
    proc = subprocess.Popen([sys.executable, "-m", "pyfold.cli", "run", str(_dense_scene(tmp_path)), "-o", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    chunks: list[bytes] = []
    reader = threading.Thread(target=lambda: chunks.extend(iter(lambda: os.read(proc.stderr.fileno(), 4096), b"")),
                              daemon=True)
    reader.start()
    try:
        # imports and validation take seconds, more on a loaded machine: interrupt once placement
        # has reported progress (it runs for far longer than this wait), not after a fixed delay
        deadline = time.monotonic() + 120.0
        while b"volume fraction reached" not in b"".join(chunks) and time.monotonic() < deadline:
            assert proc.poll() is None, b"".join(chunks).decode(errors="replace")
            time.sleep(0.05)
        assert proc.poll() is None
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
        took = time.monotonic() - sent
        reader.join(timeout=10)
        err = b"".join(chunks).decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert took < 3.0
    assert "placement of 1043 fibres" in err and "random sequential addition" in err and "volume fraction reached" in err
    assert not out.exists() and not out.with_name("dense.h5.partial").exists()  # nothing half-written


def test_hopeless_placement_gives_up_early_naming_the_key(tmp_path, fake_fold_run, capsys):
    """Thick rods (beta = 5) at phi = 0.4: the validation lets it through, random
    placement cannot reach it. The relaxation stalls and the run is refused with
    exit 2 naming particles[0].volume_fraction and the fraction reached, in seconds
    (it took 5000 sweeps, ~35 s on 2 cores, before the stall test)."""
    s = base_scene()
    # the cell clears twice the contact range (longest extent 1.2 + 2 alpha + radius)
    s["cell"]["size"] = [2.75, 2.75, 2.75]
    s["particles"] = [{"name": "rods", "shape": "fibre", "length": 1.0, "radius": 0.1, "volume_fraction": 0.4}]
    s["model"] = {"alpha": 0.01}
    s["numerics"].update(seed=1, t_end=0.1)
    out = tmp_path / "hopeless.h5"
    started = time.monotonic()
    assert main(["run", str(write_scene(tmp_path / "hopeless.toml", s)), "-o", str(out)]) == 2
    took = time.monotonic() - started
    err = capsys.readouterr().err
    assert "particles[0].volume_fraction" in err and "stalled" in err
    reached = float(re.search(r"reached ([0-9.]+)", err).group(1))
    assert 0.0 < reached < 0.4, err
    assert "Hint" in err and "lower the volume fraction" in err
    assert took < 20.0, took
    assert not out.exists() and not out.with_name("hopeless.h5.partial").exists()


# which job: fluid-coupled by default, --quick, or the scene's model ----------------------

def test_the_job_is_fluid_coupled_by_default_and_follows_the_scene_model():
    """No option: the bundled Stokes scene with twins; --quick: the contacts-only scene; --scene:
    the scene's resolved model decides (a contacts-only scene is never reported as fluid-coupled)."""
    from pyfold.commands.main_job import DEFAULT_SCENE, FLUID_SCENE, choose_scene
    from pyfold.scene import load_scene

    assert choose_scene(None, False) == (FLUID_SCENE, True)
    assert load_scene(FLUID_SCENE).hydrodynamics == "stokes"
    assert choose_scene(None, True) == (DEFAULT_SCENE, False)
    assert load_scene(DEFAULT_SCENE).hydrodynamics == "jeffery"
    assert choose_scene(str(DEFAULT_SCENE), False) == (DEFAULT_SCENE, False)
    assert choose_scene(str(FLUID_SCENE), False) == (FLUID_SCENE, True)


def test_quick_and_scene_together_are_refused(tmp_path, no_simulation, capsys):
    out = tmp_path / "m"
    scene = ROOT / "data" / "scenes" / "default.toml"
    with pytest.raises(SystemExit) as exc:
        main(["main", "--quick", "--scene", str(scene), "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--quick" in err and "--scene" in err
    assert not out.exists()


def test_the_contacts_only_twin_differs_from_its_fluid_coupled_run_in_the_model_only():
    """The twin keeps the particles, seed, cell, flow, outputs and the fluid run's step; it
    drops the Stokes settings and the preset, which only the Stokes model reads."""
    import tomllib

    from pyfold.commands.main_job import FLUID_SCENE, contacts_only_twin
    from pyfold.scene import load_scene, parse_scene

    fluid = load_scene(FLUID_SCENE)
    text = FLUID_SCENE.read_text(encoding="utf-8")
    twin_text = contacts_only_twin(text, fluid.dt)
    twin = parse_scene(twin_text, "twin.toml")
    assert fluid.hydrodynamics == "stokes" and twin.hydrodynamics == "jeffery"
    assert twin.dt == fluid.dt and twin.scene.numerics.t_end == fluid.scene.numerics.t_end
    a, b = tomllib.loads(text), tomllib.loads(twin_text)
    for key in ("cell", "flow", "particles", "output"):
        assert a[key] == b[key], key
    assert b["numerics"]["seed"] == a["numerics"]["seed"] and a["model"]["alpha"] == b["model"]["alpha"]
    assert "stokes" not in b["numerics"] and "preset" not in b["numerics"]
