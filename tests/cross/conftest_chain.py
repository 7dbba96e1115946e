"""A small dilute scene for the chain tests (80 fibres, beta = 10, n L^3 = 0.37)."""
from pathlib import Path

from pyfold.scene.sheared_fibres import sheared_fibres_toml

SCENE = sheared_fibres_toml(title="dilute chain test", side=6.0, count=80, radius=0.05, dt=0.01, t_end=4.0, seed=11,
                            interval=0.05)


def write_dilute_scene(path: Path) -> Path:
    path.write_text(SCENE, encoding="utf-8")
    return path
