"""Scenes: the TOML description of a direct simulation, validated completely before anything runs.

>>> from pyfold.scene import load_scene
>>> resolved = load_scene("data/scenes/default.toml")   # doctest: +SKIP
>>> resolved.regime, resolved.n_particles                # doctest: +SKIP

:func:`load_scene` reads the file, checks it against the schema
(:mod:`pyfold.scene.schema`: types, ranges, unknown keys with a "did you mean"
hint) and the rules that tie keys together (:mod:`pyfold.scene.normalise`), and
returns a :class:`ResolvedScene`: defaults filled in, ``auto`` choices made and
explained, counts, Jeffery shape factors and step counts computed. Every
problem is reported at once, each under its key path (``particles[1].radius``),
as one :class:`pyfold.errors.InputError`. The format is documented in
``docs/scenes.md``; ``data/scenes/annotated.toml`` shows every key.
"""
from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

from pydantic import ValidationError

from pyfold.errors import InputError
from pyfold.scene._problems import Problems, add_validation_errors
from pyfold.scene.normalise import Family, ResolvedScene, normalise
from pyfold.scene.schema import Scene

__all__ = ["Scene", "ResolvedScene", "Family", "load_scene", "parse_scene", "normalise"]


def parse_scene(text: str, source: str = "scene") -> ResolvedScene:
    """Validate and resolve a scene given as TOML text.

    Raises
    ------
    InputError
        TOML syntax error (with line and column), or every schema and consistency
        problem, each under its key path.
    """
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: not valid TOML: {exc}") from exc
    try:
        scene = Scene.model_validate(raw)
    except ValidationError as exc:
        problems = Problems()
        add_validation_errors(problems, exc, Scene)
        problems.raise_if_any(source)
        raise  # pragma: no cover - raise_if_any always raises here
    return dataclasses.replace(normalise(scene, source=source), toml=text)


def load_scene(path: str | Path) -> ResolvedScene:
    """Read, validate and resolve the scene file at ``path`` (see :func:`parse_scene`)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise InputError(f"SCENE: no such file: {path}") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"SCENE: cannot read {path}: {exc}") from exc
    return parse_scene(text, source=str(path))
