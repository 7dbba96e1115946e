"""Scenes of a contacts-only fibre suspension in simple shear, sized from (beta, n L^3).

The C_I studies, the closure verdict, the main job's ensemble and the cross-validation
tests all simulate the same kind of scene: ``count`` rigid fibres of length ``L = 1 m``
and aspect ratio ``beta = L/d`` in a cubic periodic cell (Lees-Edwards), simple shear
at ``rate = 1 1/s``, Jeffery kinematics (no hydrodynamic interactions) with the seed's
collision strategy: the model of Sundararajakumar & Koch (1997)
(docs/physics.md#collision-driven-orientation-diffusion). This module builds that
scene once, so that every study means the same thing by "beta = 10, n L^3 = 15".

Choices, and why:

* security zone ``alpha = alpha_over_d * d`` (default :data:`DEFAULT_ALPHA_OVER_D` = 0.05 d, i.e.
  the scene default of ``model.alpha``, a tenth of the radius: pyfold/scene/registry.py,
  docs/physics.md#collision-strategy);
* time step ``dt = alpha / (rate L)``: a fibre tip moves at most ``rate L / 2`` so it
  travels at most ``alpha / 2`` per step (docs/physics.md#time-step);
* cell side: the smallest multiple of 0.1 L (at least ``min_side``) that clears fold_run's
  range rule ``side > 2 rc`` (:func:`pyfold.scene.shapes.interaction_range`);
* ``count = round(n L^3 side^3)``; the realised ``n L^3`` is returned.

``hydrodynamics = "stokes"`` gives the fluid-coupled twin of the same scene (same
particles, cell, time step and seed, so the placement is identical): the fictitious-domain
FFT Stokes solver (docs/physics.md#fft-stokes-solver) replaces Jeffery kinematics, with
its ``[numerics.stokes]`` keys given by ``stokes`` (``cells_per_diameter``, ``tolerance``,
``kappa``, ``max_iterations``, ...; the solver's defaults otherwise) and the time scheme
by ``time_scheme`` (docs/scenes.md#numerics). The contacts-only scene is unchanged.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Mapping

from pyfold.errors import InputError
from pyfold.scene.registry import DEFAULT_ALPHA_OVER_RADIUS
from pyfold.scene.shapes import interaction_range

#: Default security zone in fibre diameters: the scene's default alpha (a fraction
#: DEFAULT_ALPHA_OVER_RADIUS of the radius, the registry's), so a scene built here and a
#: scene file without model.alpha mean the same zone.
DEFAULT_ALPHA_OVER_D = DEFAULT_ALPHA_OVER_RADIUS / 2.0


@dataclasses.dataclass(frozen=True)
class ShearedFibres:
    """A contacts-only fibre scene: its TOML text and what it realises."""

    toml: str
    beta: float
    n_l3: float  # realised count / side^3 (L = 1)
    count: int
    side: float
    alpha: float
    dt: float
    t_end: float
    seed: int
    hydrodynamics: str = "jeffery"


def sheared_fibres(beta: float, n_l3: float, seed: int, t_end: float, *, alpha_over_d: float = DEFAULT_ALPHA_OVER_D,
                   interval: float = 0.2, min_side: float = 2.2, collisions: str = "strategy",
                   dt: float | None = None, title: str | None = None, hydrodynamics: str = "jeffery",
                   stokes: Mapping[str, int | float | str] | None = None,
                   time_scheme: str | None = None, equivalent_aspect_ratio: str | None = None) -> ShearedFibres:
    """Build the scene (see the module docstring). ``collisions = "none"`` gives the no-contact twin,
    ``hydrodynamics = "stokes"`` the fluid-coupled twin (``stokes``: its ``[numerics.stokes]`` keys);
    ``equivalent_aspect_ratio``: the rule of the fibres' Jeffery β_e (particles.equivalent_aspect_ratio;
    None: the scene default)."""
    if not beta >= 1.0:
        raise InputError(f"beta: must be >= 1, got {beta}")
    if not n_l3 > 0.0:
        raise InputError(f"n_l3: must be > 0, got {n_l3}")
    # Only the sign here: the upper bound (alpha <= the fibre radius, alpha_over_d <= 0.5) is
    # the scene validation's model.alpha rule, which every scene built here goes through.
    if not alpha_over_d > 0.0:
        raise InputError(f"alpha_over_d: must be > 0, got {alpha_over_d}")
    if collisions not in ("strategy", "none"):
        raise InputError(f"collisions: 'strategy' or 'none', got {collisions!r}")
    if hydrodynamics not in ("jeffery", "stokes"):
        raise InputError(f"hydrodynamics: 'jeffery' or 'stokes', got {hydrodynamics!r}")
    if hydrodynamics == "jeffery" and (stokes or time_scheme is not None):
        raise InputError("stokes, time_scheme: only with hydrodynamics = 'stokes'")
    length = 1.0
    radius = length / beta / 2.0
    alpha = round(alpha_over_d * 2.0 * radius, 12)
    step = round(dt if dt is not None else alpha / length, 12)  # rate = 1
    rc = interaction_range([("fibre", radius, length)], alpha)
    side = max(min_side, math.floor(2.0 * rc / 0.1 + 1.0 + 1e-9) * 0.1)
    side = round(side, 6)
    count = max(2, int(round(n_l3 * side ** 3)))
    records = max(1, int(round(interval / step)))
    interval = round(records * step, 12)
    n_steps = int(round(t_end / step))
    t_end = round(n_steps * step, 12)
    model_words = "contacts-only" if hydrodynamics == "jeffery" else "Stokes-coupled"
    title = title or f"{model_words} fibres, beta {beta:g}, n L^3 {count / side ** 3:.3g}, seed {seed}"
    toml = sheared_fibres_toml(title=title, side=side, count=count, radius=radius, length=length, dt=step,
                               t_end=t_end, seed=int(seed), interval=interval, snapshot_interval=t_end,
                               hydrodynamics=hydrodynamics, collisions=collisions, alpha=alpha,
                               stokes=(stokes or {}) if hydrodynamics == "stokes" else None,
                               time_scheme=time_scheme, equivalent_aspect_ratio=equivalent_aspect_ratio)
    return ShearedFibres(toml=toml, beta=float(beta), n_l3=count / side ** 3, count=count, side=side,
                         alpha=alpha, dt=step, t_end=t_end, seed=int(seed), hydrodynamics=hydrodynamics)


def sheared_fibres_toml(*, title: str, side: float, count: int, radius: float, dt: float, t_end: float,
                        seed: int | str, length: float = 1.0, interval: float | None = None,
                        snapshot_interval: float | None = None, checkpoint_interval: float | None = None,
                        hydrodynamics: str | None = None, collisions: str | None = None,
                        alpha: float | None = None, stokes: Mapping[str, int | float | str] | None = None,
                        time_scheme: str | None = None, equivalent_aspect_ratio: str | None = None) -> str:
    """The scene text of ``count`` fibres (``length``, ``radius``) in a cubic cell of ``side``
    in simple shear at rate 1, as given (no sizing: :func:`sheared_fibres` sizes it from beta
    and n L^3). Keys given as ``None`` are left out (the scene defaults apply); ``stokes``
    (even empty) adds the ``[numerics.stokes]`` table; ``seed`` may be a placeholder text."""
    numerics_extra = ""
    if time_scheme is not None:
        numerics_extra += f'time_scheme = "{time_scheme}"\n'
    if stokes is not None:
        numerics_extra += "\n[numerics.stokes]\n" + "".join(
            f"{key} = {_toml_value(value)}\n" for key, value in stokes.items())
    model = _toml_keys(hydrodynamics=hydrodynamics, collisions=collisions, alpha=alpha)
    output = _toml_keys(interval=interval, snapshot_interval=snapshot_interval,
                        checkpoint_interval=checkpoint_interval)
    return f'''title = "{title}"
[cell]
dim = 3
size = [{side!r}, {side!r}, {side!r}]

[flow]
type = "simple_shear"
rate = 1.0

[[particles]]
name = "fibres"
shape = "fibre"
length = {length!r}
radius = {radius!r}
count = {count}
orientation = "isotropic"
{_toml_keys(equivalent_aspect_ratio=equivalent_aspect_ratio)}
[model]
{model}
[numerics]
dt = {dt!r}
t_end = {t_end!r}
seed = {seed}
{numerics_extra}
[output]
{output}'''


def _toml_keys(**values: int | float | str | None) -> str:
    """``key = value`` lines of the values given (``None`` left out)."""
    return "".join(f"{key} = {_toml_value(value)}\n" for key, value in values.items() if value is not None)


def _toml_value(value: int | float | str) -> str:
    """A scalar as TOML text (strings quoted; ``repr`` keeps integers integers and reals exact)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(value)
