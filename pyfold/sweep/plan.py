"""A sweep's runs: one scene per (point, seed), identified by a hash of its normalised scene.

The scene of a run is the base scene with the point's and ``[arguments]``' keys set
(a key path such as ``numerics.t_end`` or ``particles[0].count``) and ``numerics.seed``
set to the seed, or what the builder returns for the point's and ``[arguments]``'
keyword arguments and ``seed=``. Each scene is validated and normalised like
``pyfold validate`` does (:func:`pyfold.scene.parse_scene`); its identity
(:func:`run_id`) is a SHA-256 over the normalised scene without its title, so two
sweeps, orders or machines that ask for the same simulation name the same run.
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import importlib
import importlib.util
import json
import re
import sys
import tomllib
from pathlib import Path
from typing import Any, Callable

from pyfold.errors import InputError
from pyfold.sweep.spec import SweepSpec

#: Hex digits of the SHA-256 kept in a run's identity (64 bits: no collision in any sweep's size).
ID_LENGTH = 16
#: Normalised-scene keys left out of the identity: they do not change what is simulated.
COSMETIC_KEYS = ("title",)
_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$")


@dataclasses.dataclass(frozen=True)
class PlannedRun:
    """One run of a sweep."""

    point: dict[str, Any]  # axis name -> value
    seed: int
    toml: str  # the scene file's text
    run_id: str


def run_id(resolved) -> str:
    """The identity of a run: SHA-256 (first :data:`ID_LENGTH` hex digits) of its normalised
    scene (a :class:`pyfold.scene.ResolvedScene`) as canonical JSON, without :data:`COSMETIC_KEYS`
    and without the settings added later that are at their default (the registry's
    ``identity_at_default = False``: a run named before such a setting existed keeps its name)."""
    from pyfold.scene import registry

    data = resolved.scene.model_dump(mode="json", exclude_none=True)
    for key in COSMETIC_KEYS:
        data.pop(key, None)
    for s in registry.SETTINGS:
        if not s.identity_at_default:
            *tables, name = s.path.split(".")
            node = data
            for t in tables:
                node = node.get(t, {}) if isinstance(node, dict) else {}
            if isinstance(node, dict) and name in node and node[name] == s.default:
                del node[name]
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:ID_LENGTH]


def set_key(table: dict[str, Any], path: str, value: Any) -> None:
    """Set the scene key ``path`` (``a.b``, ``particles[0].count``, ``cell.size[1]``) in ``table``;
    missing tables are created. InputError naming ``path`` for a malformed path or an index
    beyond its array."""
    parts = path.split(".")
    node: Any = table
    for depth, part in enumerate(parts):
        m = _SEGMENT.match(part)
        if not m:
            raise InputError(f"{path}: not a scene key path (names joined by '.', array items as name[i])")
        name, indices = m.group(1), [int(i) for i in re.findall(r"\d+", m.group(2))]
        last = depth == len(parts) - 1
        if not isinstance(node, dict):
            raise InputError(f"{path}: {'.'.join(parts[:depth])} is not a table in the base scene")
        if not indices:
            if last:
                node[name] = value
            else:
                node = node.setdefault(name, {})
            continue
        if name not in node or not isinstance(node[name], list):
            raise InputError(f"{path}: {name} is not an array in the base scene")
        node = node[name]
        for k, i in enumerate(indices):
            if i >= len(node):
                raise InputError(f"{path}: index {i} beyond {name}'s {len(node)} item(s) in the base scene")
            if last and k == len(indices) - 1:
                node[i] = value
            else:
                node = node[i]


def load_builder(spec: SweepSpec) -> Callable[..., Any]:
    """The builder function of ``spec``: ``module:function``, or ``file.py:function`` with the
    file relative to the sweep file (imported under a private module name)."""
    target, _, func = spec.builder.rpartition(":")
    try:
        if target.endswith(".py"):
            file = (spec.path.parent / target).resolve()
            if not file.is_file():
                raise InputError(f"sweep.builder: {target} (resolved {file}): no such file")
            name = "_pyfold_sweep_builder_" + hashlib.sha1(str(file).encode()).hexdigest()[:8]
            module = sys.modules.get(name)
            if module is None:
                loader = importlib.util.spec_from_file_location(name, file)
                module = importlib.util.module_from_spec(loader)
                sys.modules[name] = module
                loader.loader.exec_module(module)
        else:
            module = importlib.import_module(target)
    except ImportError as exc:
        raise InputError(f"sweep.builder: cannot import {target}: {exc}") from None
    fn = getattr(module, func, None)
    if not callable(fn):
        raise InputError(f"sweep.builder: {target} has no function {func}")
    return fn


def _scene_text(spec: SweepSpec, point: dict[str, Any], seed: int, base: dict | None, builder) -> str:
    if builder is not None:
        try:
            made = builder(**spec.arguments, **point, seed=seed)
        except TypeError as exc:
            raise InputError(f"sweep.builder: {spec.builder} does not take these arguments "
                             f"({', '.join([*spec.arguments, *point, 'seed'])}): {exc}") from None
        text = made if isinstance(made, str) else getattr(made, "toml", None)
        if not isinstance(text, str):
            raise InputError(f"sweep.builder: {spec.builder} must return a scene's TOML text (or an object "
                             "with a .toml attribute)")
        return text
    import tomli_w

    table = copy.deepcopy(base)
    for key, value in {**spec.arguments, **point}.items():
        where = "arguments" if key in spec.arguments else "axes"
        try:
            set_key(table, key, value)
        except InputError as exc:
            raise InputError(f"{where}.{exc}") from None
    set_key(table, "numerics.seed", seed)
    return tomli_w.dumps(table)


def plan(spec: SweepSpec, progress: Callable[[str], None] | None = None) -> list[PlannedRun]:
    """Every run of ``spec`` (points in order, seeds inner), each scene checked.

    Raises
    ------
    InputError
        A key path the base scene cannot take, a builder that cannot be called, or a scene
        that does not validate: named with its point and seed, nothing written.
    """
    from pyfold.scene import parse_scene, read_scene_text

    base = builder = None
    if spec.scene is not None:
        base = tomllib.loads(read_scene_text(spec.scene))
    else:
        builder = load_builder(spec)
    runs = []
    for point in spec.points:
        for seed in spec.seeds:
            label = ", ".join([f"{k} = {v!r}" for k, v in point.items()] + [f"seed {seed}"])
            text = _scene_text(spec, point, seed, base, builder)
            try:
                resolved = parse_scene(text, source=f"SWEEP: {spec.path}: run ({label})")
            except InputError as exc:
                raise InputError(str(exc)) from None
            runs.append(PlannedRun(point=dict(point), seed=seed, toml=text, run_id=run_id(resolved)))
            if progress:
                progress(label)
    return runs
