"""A small dilute scene for the chain tests (80 fibres, beta = 10, n L^3 = 0.37)."""
from pathlib import Path

SCENE = """
title = "dilute chain test"
[cell]
dim = 3
size = [6.0, 6.0, 6.0]
[flow]
type = "simple_shear"
rate = 1.0
[[particles]]
name = "fibres"
shape = "fibre"
length = 1.0
radius = 0.05
count = 80
orientation = "isotropic"
[numerics]
dt = 0.01
t_end = 4.0
seed = 11
[output]
interval = 0.05
"""


def write_dilute_scene(path: Path) -> Path:
    path.write_text(SCENE, encoding="utf-8")
    return path
