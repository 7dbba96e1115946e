"""A scene as flat keys: what `pyfold run --resume` and the ensemble checks of `pyfold report`
compare between runs.

The normalised scene (``/setup/scene_json``) becomes ``{"numerics.dt": 0.01,
"particles[0].radius": 0.05, ...}`` and every resolved value (``/setup/resolved``) is added
as ``resolved/<name>`` (numeric arrays as nested lists, so that they compare with ``==``).
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np


def flatten(value: Any, prefix: str = "") -> dict[str, object]:
    """Nested dicts/lists as ``{"a.b[0].c": leaf}``."""
    out: dict[str, object] = {}
    if isinstance(value, dict):
        for key, item in value.items():
            out.update(flatten(item, f"{prefix}.{key}" if prefix else str(key)))
    elif isinstance(value, (list, tuple)):
        for k, item in enumerate(value):
            out.update(flatten(item, f"{prefix}[{k}]"))
    else:
        out[prefix] = value
    return out


def setup_keys(scene: dict, resolved: Mapping[str, Any]) -> dict[str, object]:
    """The normalised ``scene`` flattened (:func:`flatten`) and each ``resolved`` value as ``resolved/<name>``."""
    keys = flatten(scene)
    for name, value in resolved.items():
        arr = np.asarray(value)
        keys[f"resolved/{name}"] = arr.tolist() if arr.dtype.kind in "fiub" else value
    return keys
