"""``pyfold validate SCENE.toml``: check a scene completely and print it normalised.

The normalised scene has every default filled in and every ``auto`` choice made;
it is itself a valid scene. It is printed as TOML (``--json``: JSON), preceded
by comment lines with the resolved regime, choices, counts and shape factors.
Exit status 2 with every problem listed (key path, allowed range) if invalid.
Warnings (a valid scene whose results would be compromised, e.g. a Stokes grid
coarser than 4 voxels per diameter) are printed on stderr, exit status 0.
"""
from __future__ import annotations

import argparse
import json
import sys

import tomli_w

from pyfold.scene import load_scene


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE.toml", help="scene file")
    parser.add_argument("--json", action="store_true", help="print the normalised scene as JSON instead of TOML")


def run(args: argparse.Namespace) -> int:
    resolved = load_scene(args.scene)
    for warning in resolved.warnings:
        print(f"pyfold validate: warning: {warning}", file=sys.stderr)
    data = resolved.scene.model_dump(mode="json", exclude_none=True)
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        print(f"# {args.scene}: valid scene, normalised")
        for line in resolved.summary().splitlines():
            print(f"# {line}")
        print(tomli_w.dumps(data), end="")
    return 0
