"""The sweep file: what a sweep varies, over which base scene, with which resources.

.. code-block:: toml

    [sweep]
    name = "example"                    # default: the file's name without .toml
    scene = "../scenes/sweep_small.toml"   # base scene, relative to this file ...
    # builder = "pyfold.scene.sheared_fibres:sheared_fibres"  # ... or a Python builder
    seeds = [1, 2]                      # scene: numerics.seed; builder: its seed argument

    [arguments]                         # fixed: scene keys (scene) or keyword arguments (builder)
    "numerics.t_end" = 4.0

    [axes]                              # varied: every combination of the values
    "particles[0].count" = [16, 32]

    # or, instead of [axes], the combinations themselves:
    # [[points]]
    # beta = 5.0
    # n_l3 = 2.0

    [resources]                         # per run; the command line overrides these
    np = 1                              # MPI ranks per run
    time = "00:10:00"                   # Slurm time limit of one run
    partition = ""                      # Slurm partition ("": the cluster's default)
    mem = ""                            # Slurm memory per run, e.g. "2G" ("": the default)
    retries = 3                         # resubmissions of a timed-out or cancelled run

Every problem is an :class:`~pyfold.errors.InputError` naming the key and what it
accepts; nothing is written before the whole file (and every scene it makes,
:mod:`pyfold.sweep.plan`) has been checked.
"""
from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path
from typing import Any

from pyfold.errors import InputError
from pyfold.files import read_bounded

#: Largest sweep file read [bytes].
MAX_SWEEP_BYTES = 1 << 20
#: Top-level tables of a sweep file.
TABLES = ("sweep", "arguments", "axes", "points", "resources")
#: Keys of [sweep].
SWEEP_KEYS = ("name", "scene", "builder", "seeds")
#: Keys of [resources] and their defaults (one source for the file, the command line and the docs).
RESOURCE_DEFAULTS: dict[str, Any] = {"np": 1, "time": "01:00:00", "partition": "", "mem": "", "retries": 3}
#: Largest number of resubmissions of one run.
MAX_RETRIES = 20
#: Most runs in one sweep.
MAX_RUNS = 10000
#: Slurm time limits: minutes, MM:SS, HH:MM:SS, D-HH, D-HH:MM, D-HH:MM:SS.
TIME_PATTERN = re.compile(r"^(\d+|\d+:\d\d|\d+:\d\d:\d\d|\d+-\d+|\d+-\d+:\d\d|\d+-\d+:\d\d:\d\d)$")
#: Slurm memory: an integer with an optional unit K, M, G or T.
MEM_PATTERN = re.compile(r"^\d+[KMGT]?$")
#: A run-name-safe sweep name.
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
#: Scalar types an axis value, an argument or a point may take.
SCALARS = (bool, int, float, str)


@dataclasses.dataclass(frozen=True)
class Resources:
    """Per-run resources (see the module docstring)."""

    np: int = RESOURCE_DEFAULTS["np"]
    time: str = RESOURCE_DEFAULTS["time"]
    partition: str = RESOURCE_DEFAULTS["partition"]
    mem: str = RESOURCE_DEFAULTS["mem"]
    retries: int = RESOURCE_DEFAULTS["retries"]


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A checked sweep file."""

    path: Path
    name: str
    scene: Path | None  # base scene file (absolute), or None with a builder
    builder: str | None  # "module:function" or "file.py:function" (resolved against the file's folder)
    seeds: tuple[int, ...]
    arguments: dict[str, Any]
    axes: dict[str, tuple[Any, ...]]  # axis name -> values (ordered as given)
    points: tuple[dict[str, Any], ...]  # the combinations that are run
    resources: Resources


def _fail(source: str, problems: list[str]) -> None:
    if problems:
        raise InputError(f"{source}: " + ("\n  ".join([""] + problems) if len(problems) > 1 else problems[0]))


def check_resources(values: dict[str, Any], where: str, problems: list[str]) -> Resources:
    """Resources from ``values`` (file or command line), each problem named under ``where``."""
    from pyfold.commands.run import MAX_RANKS

    out = dict(RESOURCE_DEFAULTS)
    for key, value in values.items():
        name = f"{where}.{key}" if where else key
        if key not in RESOURCE_DEFAULTS:
            problems.append(f"{name}: unknown key; allowed: {', '.join(RESOURCE_DEFAULTS)}")
        elif key in ("np", "retries"):
            top = MAX_RANKS if key == "np" else MAX_RETRIES
            low = 1 if key == "np" else 0
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= top:
                problems.append(f"{name}: must be an integer from {low} to {top}, got {value!r}")
            else:
                out[key] = value
        elif not isinstance(value, str):
            problems.append(f"{name}: must be a string, got {value!r}")
        elif key == "time" and not TIME_PATTERN.match(value):
            problems.append(f"{name}: a Slurm time limit (minutes, HH:MM:SS or D-HH:MM:SS), got {value!r}")
        elif key == "mem" and value and not MEM_PATTERN.match(value):
            problems.append(f"{name}: a Slurm memory size (an integer with K, M, G or T; \"\" for the "
                            f"default), got {value!r}")
        elif key == "partition" and value and not re.match(r"^[A-Za-z0-9_.,-]+$", value):
            problems.append(f"{name}: a partition name (letters, digits, _ . , -; \"\" for the default), "
                            f"got {value!r}")
        else:
            out[key] = value
    return Resources(**out)


def _scalar_list(value: Any, name: str, problems: list[str]) -> tuple[Any, ...] | None:
    if not isinstance(value, list) or not value:
        problems.append(f"{name}: must be a non-empty array of numbers, strings or booleans, got {value!r}")
        return None
    bad = [v for v in value if not isinstance(v, SCALARS)]
    if bad:
        problems.append(f"{name}: values must be numbers, strings or booleans, got {bad[0]!r}")
        return None
    if len({(type(v), v) for v in value}) != len(value):
        problems.append(f"{name}: values must be distinct, got {value!r}")
        return None
    return tuple(value)


def read_sweep(path: str | Path) -> SweepSpec:
    """Read and check the sweep file at ``path`` (see the module docstring)."""
    path = Path(path)
    source = f"SWEEP: {path}"
    data = read_bounded(path, "SWEEP", MAX_SWEEP_BYTES)
    try:
        raw = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{source}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: not valid TOML: {exc}") from None
    return parse_sweep(raw, path)


def parse_sweep(raw: dict[str, Any], path: Path) -> SweepSpec:
    """Check a parsed sweep file (``path``: where it lies, for names and relative paths)."""
    source = f"SWEEP: {path}"
    problems: list[str] = []
    for key in raw:
        if key not in TABLES:
            problems.append(f"{key}: unknown table; allowed: {', '.join(TABLES)}")
    head = raw.get("sweep")
    if not isinstance(head, dict):
        problems.append("sweep: missing table [sweep] (keys: " + ", ".join(SWEEP_KEYS) + ")")
        _fail(source, problems)
    for key in head:
        if key not in SWEEP_KEYS:
            problems.append(f"sweep.{key}: unknown key; allowed: {', '.join(SWEEP_KEYS)}")
    name = head.get("name", path.stem)
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        problems.append(f"sweep.name: 1 to 64 letters, digits, _ . - (starting with a letter or digit), got {name!r}")
    scene, builder = head.get("scene"), head.get("builder")
    scene_path = None
    if (scene is None) == (builder is None):
        problems.append("sweep.scene, sweep.builder: give exactly one (a base scene file, or a builder "
                        "\"module:function\" / \"file.py:function\")")
    elif scene is not None:
        if not isinstance(scene, str) or not scene:
            problems.append(f"sweep.scene: a path to a scene file (relative to the sweep file), got {scene!r}")
        else:
            scene_path = (path.parent / scene).resolve()
            if not scene_path.is_file():
                problems.append(f"sweep.scene: {scene} (resolved {scene_path}): no such file")
    elif not isinstance(builder, str) or not re.match(r"^[^:]+:[A-Za-z_][A-Za-z0-9_]*$", builder):
        problems.append(f"sweep.builder: \"module:function\" or \"file.py:function\", got {builder!r}")
    seeds = head.get("seeds")
    seed_values: tuple[int, ...] = ()
    if (not isinstance(seeds, list) or not seeds
            or any(isinstance(s, bool) or not isinstance(s, int) or not 0 <= s < 2 ** 31 for s in seeds)):
        problems.append(f"sweep.seeds: a non-empty array of integers from 0 to {2 ** 31 - 1}, got {seeds!r}")
    elif len(set(seeds)) != len(seeds):
        problems.append(f"sweep.seeds: seeds must be distinct, got {seeds!r}")
    else:
        seed_values = tuple(seeds)

    arguments = raw.get("arguments", {})
    if not isinstance(arguments, dict):
        problems.append(f"arguments: must be a table of key = value, got {arguments!r}")
        arguments = {}
    axes_raw = raw.get("axes", {})
    if not isinstance(axes_raw, dict):
        problems.append(f"axes: must be a table of key = [values], got {axes_raw!r}")
        axes_raw = {}
    axes: dict[str, tuple[Any, ...]] = {}
    for key, value in axes_raw.items():
        values = _scalar_list(value, f"axes.{key}", problems)
        if values is not None:
            axes[key] = values
        if key in arguments:
            problems.append(f"axes.{key}: also fixed in [arguments]; give it in one place")
        if key in ("seed", "numerics.seed"):
            problems.append(f"axes.{key}: seeds are given by sweep.seeds")
    points_raw = raw.get("points")
    points: list[dict[str, Any]] = []
    if points_raw is not None:
        if axes_raw:
            problems.append("points, axes: give one of them ([axes]: every combination; [[points]]: the "
                            "combinations themselves)")
        elif not isinstance(points_raw, list) or not points_raw or not all(isinstance(p, dict) for p in points_raw):
            problems.append("points: an array of tables ([[points]]) with the same keys")
        else:
            keys = list(points_raw[0])
            for i, point in enumerate(points_raw):
                if list(point) != keys:
                    problems.append(f"points[{i}]: keys {list(point)} differ from points[0]'s {keys}")
                    continue
                bad = [k for k, v in point.items() if not isinstance(v, SCALARS)]
                if bad:
                    problems.append(f"points[{i}].{bad[0]}: must be a number, string or boolean")
                    continue
                points.append(dict(point))
            if len({tuple(sorted(p.items())) for p in points}) != len(points):
                problems.append("points: two points are the same combination")
            for k in keys:
                axes[k] = tuple(dict.fromkeys(p[k] for p in points))
    else:
        import itertools

        names = list(axes)
        points = [dict(zip(names, combo)) for combo in itertools.product(*(axes[n] for n in names))]
    res_raw = raw.get("resources", {})
    if not isinstance(res_raw, dict):
        problems.append(f"resources: must be a table; keys: {', '.join(RESOURCE_DEFAULTS)}")
        res_raw = {}
    resources = check_resources(res_raw, "resources", problems)
    if len(points) * max(1, len(seed_values)) > MAX_RUNS:
        problems.append(f"axes, sweep.seeds: {len(points) * len(seed_values)} runs; a sweep holds at most {MAX_RUNS}")
    _fail(source, problems)
    return SweepSpec(path=path.resolve(), name=name, scene=scene_path, builder=builder, seeds=seed_values,
                     arguments=dict(arguments), axes=axes, points=tuple(points), resources=resources)
