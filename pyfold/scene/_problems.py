"""Collecting scene problems and reporting them all at once, each under its key path.

A scene is checked completely before anything runs: every problem found is
listed (one line each, ``key.path: message``) in a single
:class:`~pyfold.errors.InputError`, so a user fixes a file in one pass.
"""
from __future__ import annotations

import difflib
from collections.abc import Iterable, Sequence
from typing import Any

from pydantic import BaseModel, ValidationError

from pyfold.errors import InputError


def key_path(loc: Iterable[Any]) -> str:
    """``("particles", 1, "radius")`` -> ``"particles[1].radius"``."""
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += ("." if text else "") + str(part)
    return text or "(scene)"


class Problems:
    """An ordered list of ``(key path, message)`` found in one scene."""

    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def add(self, path: str, message: str) -> None:
        self.items.append((path, message))

    def __bool__(self) -> bool:
        return bool(self.items)

    def raise_if_any(self, source: str) -> None:
        if not self.items:
            return
        lines = [f"  {path}: {message}" for path, message in self.items]
        count = len(self.items)
        raise InputError(f"{source}: {count} problem{'s' if count > 1 else ''} in the scene\n" + "\n".join(lines))


def _model_at(root: type[BaseModel], loc: Sequence[Any]) -> type[BaseModel] | None:
    """The pydantic model class holding the key at ``loc`` (for "did you mean")."""
    model: Any = root
    for part in loc[:-1]:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(part) if isinstance(model, type) and issubclass(model, BaseModel) else None
        if field is None:
            return None
        model = _inner_model(field.annotation)
        if model is None:
            return None
    return model if isinstance(model, type) and issubclass(model, BaseModel) else None


def _inner_model(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _inner_model(arg)
        if found is not None:
            return found
    return None


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'radius'?)`` for the closest known key, or the list of known keys."""
    choices = sorted(choices)
    close = difflib.get_close_matches(word, choices, n=1, cutoff=0.6)
    if close:
        return f"did you mean {close[0]!r}? (allowed keys: {', '.join(choices)})"
    return f"allowed keys: {', '.join(choices)}"


def _number(value: Any) -> str:
    """A bound as written in a scene: ``1e-30``, ``0``, ``10000000`` (not 0.000...01)."""
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_union_tag(part: Any) -> bool:
    """pydantic names the branch of a union in ``loc`` (``list[...]``, ``constrained-str``,
    ``function-after[...]``): not a key of the scene."""
    return isinstance(part, str) and (any(c in part for c in "[(") or part in ("constrained-str", "str", "list"))


def add_validation_errors(problems: Problems, error: ValidationError, root: type[BaseModel]) -> None:
    """Translate pydantic's errors into key-path messages stating the allowed range.

    A value matching no branch of a union (``positions``: an array of rows or a file name)
    gets one line naming every accepted form."""
    union: dict[str, list[str]] = {}
    for item in error.errors(include_url=False):
        loc = tuple(item["loc"])
        if item["type"] != "extra_forbidden" and any(_is_union_tag(part) for part in loc):
            clean = tuple(part for part in loc if not _is_union_tag(part))
            branch = Problems()
            add_validation_errors_item(branch, {**item, "loc": clean}, root)
            for path, message in branch.items:
                union.setdefault(path, []).append(message)
            continue
        add_validation_errors_item(problems, item, root)
    for path, messages in union.items():
        if any(other.startswith(path + "[") or other.startswith(path + ".") for other in union):
            continue  # the value has the shape of a branch whose entries are reported: that branch's errors only
        if len(messages) > 1 and all(m.startswith("must be ") for m in messages):
            got = messages[0].rsplit(", got ", 1)[-1] if ", got " in messages[0] else ""
            forms = [m.removeprefix("must be ").rsplit(", got ", 1)[0] for m in messages]
            problems.add(path, f"must be {' or '.join(dict.fromkeys(forms))}{', got ' + got if got else ''}")
        else:
            for message in dict.fromkeys(messages):
                problems.add(path, message)


def add_validation_errors_item(problems: Problems, item: dict, root: type[BaseModel]) -> None:
    """One pydantic error as a key-path message."""
    loc = tuple(item["loc"])
    kind = item["type"]
    path = key_path(loc)
    got = _describe(item.get("input"))
    ctx = item.get("ctx") or {}
    if kind == "extra_forbidden":
        model = _model_at(root, loc)
        hint = did_you_mean(str(loc[-1]), model.model_fields) if model is not None else ""
        problems.add(path, f"unknown key; {hint}")
    elif kind == "missing":
        problems.add(path, "required key is missing")
    elif kind == "literal_error":
        problems.add(path, f"must be one of {ctx.get('expected')}, got {got}")
    elif kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        bound = next(iter(ctx.values()), None)
        words = kind.replace("_equal", " or equal to").replace("_than", " than")  # greater than or equal to
        problems.add(path, f"must be {words} {_number(bound)}, got {got}")
    elif kind in ("too_short", "too_long"):
        problems.add(path, f"{item['msg'].replace('List should have', 'must have')}; got {got}")
    elif kind in ("float_type", "float_parsing", "int_type", "int_from_float", "int_parsing", "bool_type",
                  "string_type", "list_type", "model_type", "dict_type"):
        expected = {
            "float": "a number", "int": "an integer", "bool": "true or false", "string": "a string",
            "list": "an array", "model": "a table", "dict": "a table",
        }[kind.split("_")[0]]
        problems.add(path, f"must be {expected}, got {got}")
    else:
        message = item["msg"].removeprefix("Value error, ")
        problems.add(path, f"{message}, got {got}")
