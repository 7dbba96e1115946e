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
from pyfold.files import read_bounded
from pyfold.scene._problems import Problems, add_validation_errors
from pyfold.scene.normalise import Family, ResolvedScene, normalise
from pyfold.scene.schema import Scene

__all__ = ["Scene", "ResolvedScene", "Family", "load_scene", "parse_scene", "read_scene_text", "normalise",
           "MAX_SCENE_BYTES"]


#: Largest scene file read [bytes]. A scene is a few kB of TOML; per-particle
#: tables that large belong in a ``.csv`` or ``.npy`` file named by the scene.
MAX_SCENE_BYTES = 16 << 20

_BOM = b"\xef\xbb\xbf"


def parse_scene(text: str, source: str = "scene") -> ResolvedScene:
    """Validate and resolve a scene given as TOML text.

    Raises
    ------
    InputError
        TOML syntax error (with line and column), arrays or tables nested deeper than
        the parser can follow, or every schema and consistency problem, each under
        its key path.
    """
    try:
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
        resolved = normalise(scene, source=source)
    except RecursionError:
        # A scene nests at most three levels (particles[i].orientations[j][k]); the
        # TOML parser (and the schema) recurse once per level.
        raise InputError(f"{source}: arrays or tables nested too deeply to read; a scene nests at most "
                         "3 levels (particles[i].orientations[j][k])") from None
    return dataclasses.replace(resolved, toml=text)


def decode_scene(data: bytes, source: str = "scene") -> str:
    """The text of a scene file's bytes: UTF-8, with or without a byte-order mark
    (removed). Bytes that are not UTF-8 are an :class:`InputError` naming the byte offset."""
    skip = len(_BOM) if data.startswith(_BOM) else 0
    try:
        return data[skip:].decode("utf-8")
    except UnicodeDecodeError as exc:
        offset = skip + exc.start
        raise InputError(f"{source}: not valid UTF-8 text: byte {data[offset:offset + 1].hex()} at byte offset "
                         f"{offset} ({exc.reason}); a scene is a UTF-8 TOML file") from None


def read_scene_text(path: str | Path) -> str:
    """The text of the scene file at ``path``: a regular file of at most
    :data:`MAX_SCENE_BYTES` bytes, UTF-8 (a leading byte-order mark removed).

    A folder, FIFO or device, a larger file, or bytes that are not UTF-8 are an
    :class:`InputError` (``SCENE: ...``) naming the path."""
    path = Path(path)
    return decode_scene(read_bounded(path, "SCENE", MAX_SCENE_BYTES), source=f"SCENE: {path}")


def load_scene(path: str | Path) -> ResolvedScene:
    """Read (:func:`read_scene_text`), validate and resolve the scene file at ``path``
    (see :func:`parse_scene`)."""
    return parse_scene(read_scene_text(path), source=str(path))
