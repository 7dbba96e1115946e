"""Extreme numbers in a scene: `pyfold validate` answers within seconds, exit 2 with the
key and the allowed range (or a warning and exit 0), never a traceback or a hang.

Every case runs under a time limit (SIGALRM in-process; a subprocess with a timeout
where the work is in native code that a signal cannot interrupt), so a hang fails
the test instead of hanging CI.
"""
from __future__ import annotations

import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
import tomllib

from conftest import base_scene, write_scene
from pyfold.cli import main

ROOT = Path(__file__).resolve().parents[2]
STOKES_SMALL = ROOT / "data" / "scenes" / "stokes_small.toml"
LIMIT = 30  # seconds; validation takes well under 5 s


@contextmanager
def time_limit(seconds: int = LIMIT):
    def hang(signum, frame):
        raise TimeoutError(f"pyfold validate did not answer within {seconds} s (a hang)")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    hung = None
    try:
        yield
    except TimeoutError as exc:
        hung = str(exc)  # reported below, without the traceback of the interrupted frames
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    if hung:
        pytest.fail(hung, pytrace=False)


def validate(path: Path, capsys) -> tuple[int, str, str]:
    with time_limit():
        status = main(["validate", str(path)])
    out = capsys.readouterr()
    return status, out.out, out.err


def _fibres_by_fraction(scene, fraction=0.01):
    fam = scene["particles"][0]
    fam.pop("count")
    fam["volume_fraction"] = fraction


def _tiny_radius_by_fraction(scene):
    fam = scene["particles"][0]
    fam.pop("length")
    fam.update(radius=1e-200, aspect_ratio=10.0)
    _fibres_by_fraction(scene)


def _spheres_by_fraction(scene, side, fraction):
    scene["cell"]["size"] = [side] * 3
    scene["particles"] = [{"name": "beads", "shape": "sphere", "radius": 0.05, "volume_fraction": fraction}]


def _general(gradient):
    def edit(scene):
        scene["flow"] = {"type": "general", "gradient": gradient}
    return edit


# (case id, edit of the base scene, texts the message must contain: the key path and the allowed range)
REJECTED = [
    ("cell size 1e300", lambda s: s["cell"].update(size=[1e300] * 3),
     ["cell.size[0]", "less than or equal to 1e+30", "got 1e+300"]),
    ("radius 1e-300", lambda s: s["particles"][0].update(radius=1e-300),
     ["particles[0].radius", "greater than or equal to 1e-30"]),
    ("cell size 1e200 with a volume fraction", lambda s: (s["cell"].update(size=[1e200] * 3), _fibres_by_fraction(s)),
     ["cell.size[0]", "1e+30"]),
    ("tiny radius with a volume fraction", _tiny_radius_by_fraction,
     ["particles[0].radius", "greater than or equal to 1e-30"]),
    ("cell 2 million radii wide", lambda s: s["cell"].update(size=[1e5] * 3),
     ["cell.size", "particles[0].radius", "allowed: cell.size <= 1e+06 x the smallest radius"]),
    ("radius 1e-20 in a cell of 4", lambda s: s["particles"][0].update(radius=1e-20),
     ["cell.size", "particles[0].radius >= 4e-06"]),
    ("dt 5e-324", lambda s: s["numerics"].update(dt=5e-324),
     ["numerics.dt", "must be >= 9.31e-11", "2147483647 steps"]),
    ("strain per step below round-off", lambda s: (s["flow"].update(rate=1e6), s["numerics"].update(dt=1e-19, t_end=1e-10),
                                                   s.pop("output")),
     ["numerics.dt", "strain max|G_ij| dt >= 2.2e-13"]),
    ("total strain beyond 1/eps", lambda s: (s["numerics"].update(dt=1e7, t_end=1e16), s.pop("output")),
     ["numerics.t_end", "allowed: numerics.t_end <= 4.5e+15"]),
    ("volume fraction giving 1e14 particles", lambda s: _spheres_by_fraction(s, 2e4, 0.01),
     ["particles[0].volume_fraction", "1.53e+14 particles", "at most 10000000 per family"]),
    ("rate 1e300", lambda s: s["flow"].update(rate=1e300), ["flow.rate", "less than or equal to 1e+30"]),
    ("aspect ratio 1e300", lambda s: (s["particles"][0].pop("length"), s["particles"][0].update(aspect_ratio=1e300)),
     ["particles[0].aspect_ratio", "less than or equal to 1e+06"]),
    ("viscosity 1e-300", lambda s: s.update(fluid={"viscosity": 1e-300}),
     ["fluid.viscosity", "greater than or equal to 1e-30"]),
    ("rate 0, Jeffery", lambda s: s["flow"].update(rate=0.0), ["flow.rate", "must be non-zero"]),
    ("zero general gradient", _general([[0.0] * 3] * 3), ["flow.gradient", "non-zero entry"]),
    ("gradient entry 1e300", _general([[0.0, 1e300, 0.0], [0.0] * 3, [0.0] * 3]),
     ["flow.gradient[0][1]", "less than or equal to 1e+30"]),
    ("cell.dim 3.0", lambda s: s["cell"].update(dim=3.0), ["cell.dim", "must be an integer, got 3.0"]),
]


@pytest.mark.parametrize("case, edit, expected", REJECTED, ids=[c[0] for c in REJECTED])
def test_extreme_scene_rejected_quickly_naming_key_and_range(case, edit, expected, tmp_path, capsys):
    scene = base_scene()
    edit(scene)
    status, _, err = validate(write_scene(tmp_path / "extreme.toml", scene), capsys)
    assert status == 2, f"{case}: exit {status}\n{err}"
    assert err.startswith("pyfold validate: error:") and "Traceback" not in err
    for text in expected:
        assert text in err, f"{case}: {text!r} not in the message:\n{err}"


# Every integer key is a strict integer: an integral float such as 3.0 is refused like 1.5.
INTEGER_KEYS = [
    ("cell.dim", lambda s, v: s["cell"].update(dim=v), 3),
    ("particles[0].count", lambda s, v: s["particles"][0].update(count=v), 8),
    ("model.contact_max_iter", lambda s, v: s["model"].update(contact_max_iter=v), 100),
    ("numerics.seed", lambda s, v: s["numerics"].update(seed=v), 3),
    ("numerics.stokes.max_iterations", lambda s, v: s["numerics"].setdefault("stokes", {}).update(max_iterations=v), 50),
    ("numerics.stokes.cells_per_diameter", lambda s, v: s["numerics"].setdefault("stokes", {}).update(cells_per_diameter=v), 4),
    ("numerics.stokes.max_grid_points", lambda s, v: s["numerics"].setdefault("stokes", {}).update(max_grid_points=v), 4096),
]


def test_every_integer_key_is_strict(tmp_path, capsys):
    """One rule for every integer key (cell.dim included): 3 passes, 3.0 is refused."""
    for key, edit, value in INTEGER_KEYS:
        scene = base_scene()
        edit(scene, value)
        status, _, err = validate(write_scene(tmp_path / "int.toml", scene), capsys)
        assert status == 0, f"{key} = {value}: {err}"
        scene = base_scene()
        edit(scene, float(value))
        status, _, err = validate(write_scene(tmp_path / "float.toml", scene), capsys)
        assert status == 2 and f"{key}: must be an integer, got {float(value)!r}" in err, f"{key} = {float(value)}: {err}"


def _stokes_scene(tmp_path, **changes) -> Path:
    scene = tomllib.loads(STOKES_SMALL.read_text(encoding="utf-8"))
    for path, value in changes.items():
        table, key = path.rsplit(".", 1)
        node = scene
        for part in table.split("."):
            node = node.setdefault(part, {})
        node[key] = value
    return write_scene(tmp_path / "stokes.toml", scene)


def test_rate_zero_with_stokes_rejected(tmp_path, capsys):
    # the effective viscosity sigma:E / (2 E:E) of a Stokes run has no meaning at rate 0
    status, _, err = validate(_stokes_scene(tmp_path, **{"flow.rate": 0.0, "model.hydrodynamics": "stokes"}), capsys)
    assert status == 2 and "flow.rate: must be non-zero" in err, err


def test_coarse_stokes_grid_warns_but_is_valid(tmp_path, capsys):
    """Below 4 voxels per diameter (docs/physics.md#resolution) a Stokes scene is valid
    but validate warns (stderr and the printed summary); at 4 it does not."""
    for cells in (1, 2):
        status, out, err = validate(_stokes_scene(tmp_path, **{"numerics.stokes.cells_per_diameter": cells}), capsys)
        assert status == 0, err
        assert "pyfold validate: warning: numerics.stokes.cells_per_diameter" in err
        assert f"by {cells} voxels, below 4" in err and "docs/physics.md#resolution" in err
        assert "# warning: numerics.stokes.cells_per_diameter" in out
    status, _, err = validate(_stokes_scene(tmp_path, **{"numerics.stokes.cells_per_diameter": 4}), capsys)
    assert status == 0 and "warning" not in err, err


def test_jeffery_scene_never_computes_the_stokes_grid(tmp_path, capsys, monkeypatch):
    """The grid is computed only when hydrodynamics can be stokes (requested, or auto in
    a periodic simple shear): a Jeffery scene or an elongational flow never needs it."""
    import importlib

    normalise = importlib.import_module("pyfold.scene.normalise")  # the module (the package exports a function)

    def no_grid(*args, **kwargs):
        raise AssertionError("stokes_grid computed for a scene that cannot use Stokes hydrodynamics")

    monkeypatch.setattr(normalise, "stokes_grid", no_grid)
    scene = base_scene()
    scene["model"]["hydrodynamics"] = "jeffery"
    scene["cell"]["size"] = [1e4] * 3  # 1e4 / (0.1 / 4) = 4e5 voxels per side if it were computed
    status, _, err = validate(write_scene(tmp_path / "jeffery.toml", scene), capsys)
    assert status == 0, err
    scene = base_scene()
    scene["flow"]["type"] = "planar_elongation"
    scene["cell"]["size"] = [4.0, 4.0, 4.0]
    assert validate(write_scene(tmp_path / "elong.toml", scene), capsys)[0] == 0


def test_stokes_grid_is_bounded_before_rounding():
    """An over-budget grid is returned unrounded at once; the FFT-size search is bounded."""
    from pyfold.scene.normalise import _fft_size, stokes_grid

    def smooth(m):
        for q in (2, 3, 5, 7):
            while m % q == 0:
                m //= q
        return m == 1

    with time_limit(10):
        assert stokes_grid([1e30, 1e30, 1e30], 1e-30, 64, max_points=64**3)[0] >= 10**61
        big = _fft_size(2**61 + 1)
        assert 2**61 < big <= 2**62 and smooth(big)
    assert stokes_grid([4.0, 4.0, 4.0], 0.1, 4, max_points=64**3) == (160, 160, 160)
    assert stokes_grid([1.0, 1.0], 0.125, 4) == (32, 32, 1)
    assert [_fft_size(n) for n in range(1, 3000)] == [next(m for m in range(max(2, n), 2 * n + 2) if smooth(m))
                                                      for n in range(1, 3000)]


def test_long_deforming_lattice_check_answers_within_seconds(tmp_path):
    """2e9 steps of uniaxial elongation: the lattice-thickness check is native code
    looping over steps (a signal cannot stop it), so this runs in a subprocess."""
    scene = base_scene()
    scene["flow"]["type"] = "uniaxial_elongation"
    scene["numerics"].update(dt=1e-10, t_end=0.2)
    scene.pop("output")
    path = write_scene(tmp_path / "long.toml", scene)
    proc = subprocess.run([sys.executable, "-m", "pyfold.cli", "validate", str(path)], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    # 2e9 steps to t = 2: the lattice gets too thin at t = 1.089454 (checked step by step with dt = 1e-6)
    scene["numerics"].update(dt=1e-9, t_end=2.0)
    path = write_scene(tmp_path / "too_long.toml", scene)
    proc = subprocess.run([sys.executable, "-m", "pyfold.cli", "validate", str(path)], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "numerics.t_end: flow.type = 'uniaxial_elongation' deforms the periodic lattice" in proc.stderr
    allowed = float(proc.stderr.split("allowed: numerics.t_end <= ")[1].split()[0])
    assert 1.0894 <= allowed <= 1.089454  # step by step (dt = 1e-6): 1.089454; the coarse check stays below
