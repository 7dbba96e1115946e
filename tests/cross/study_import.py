"""Import a study script as a module, for the tests that check a study's pieces."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import ModuleType

#: The project's ``studies`` folder.
STUDIES = Path(__file__).resolve().parents[2] / "studies"


def import_study(folder: str, name: str) -> ModuleType:
    """The module ``studies/<folder>/<name>.py``; the folder is on ``sys.path`` only
    while it imports (a study imports its sibling modules by bare name)."""
    path = str(STUDIES / folder)
    sys.path.insert(0, path)
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(path)
