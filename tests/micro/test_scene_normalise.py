"""Scene normalisation: regime and `auto` choices, Jeffery shape factors, counts, defaults."""
from __future__ import annotations

import numpy as np
import pytest
import tomli_w

from pyfold.errors import InputError
from pyfold.scene import parse_scene


def scene(particles, cell=(4.0, 4.0, 4.0), dim=3, **model):
    data = {
        "cell": {"dim": dim, "size": list(cell)},
        "flow": {"type": "simple_shear", "rate": 1.0},
        "particles": particles,
        "model": model,
        "numerics": {"dt": 0.01, "t_end": 1.0},
    }
    return parse_scene(tomli_w.dumps(data))


FIBRE = {"shape": "fibre", "length": 1.0, "radius": 0.02}  # L/d = 25


@pytest.mark.parametrize("count, regime, collisions", [
    (32, "dilute", "none"),          # n L^3 = 0.5
    (320, "semi-dilute", "strategy"),  # 5
    (1920, "concentrated", "strategy"),  # 30 > L/d = 25
])
def test_auto_choice_follows_the_regime(count, regime, collisions):
    r = scene([dict(FIBRE, count=count)])
    assert r.regime == regime and r.collisions == collisions
    assert r.regime_measure == pytest.approx(count / 64.0)
    assert r.hydrodynamics == "jeffery"
    assert f"collisions = {collisions} (auto): {regime}" in r.reason
    # dilute: no interactions; otherwise the 400^3 Stokes grid is over the default budget
    assert ("max_grid_points" in r.reason) == (regime != "dilute")
    assert ("neglected" in r.reason) == (regime != "dilute")
    # the normalised scene records the choice, and is itself valid
    assert r.scene.model.collisions == collisions and r.scene.model.hydrodynamics == "jeffery"


def test_explicit_choice_is_kept_and_said_so():
    r = scene([dict(FIBRE, count=32)], collisions="naive", hydrodynamics="jeffery")
    assert r.collisions == "naive" and "collisions = naive (requested)" in r.reason


def test_spheres_keep_contacts_under_auto():
    """n d^3 < 1 for 50 % disks: the rod rule would call them dilute; contacts stay on."""
    r = scene([{"shape": "sphere", "radius": 0.075, "volume_fraction": 0.5}], cell=(1.5, 1.0), dim=2)
    assert r.regime == "spheres" and r.collisions == "strategy"
    assert r.families[0].count == 42  # round(0.5 * 1.5 / (pi 0.075^2)) = round(42.4)


@pytest.mark.parametrize("rule, beta_e", [("cox", 8.17), ("zhang", 7.61), ("harris_pittman", 7.96)])
def test_cylinder_xi_from_the_equivalent_aspect_ratio(rule, beta_e):
    """beta = 10 -> beta_e = 8.17 / 7.61 / 7.96
    (docs/physics.md#equivalent-aspect-ratio-of-a-finite-cylinder)."""
    fam = scene([dict(FIBRE, radius=0.05, count=1, equivalent_aspect_ratio=rule)]).families[0]
    assert fam.aspect_ratio == pytest.approx(10.0)
    assert fam.equivalent_aspect_ratio == pytest.approx(beta_e, abs=0.006)
    assert fam.xi == pytest.approx((fam.equivalent_aspect_ratio**2 - 1) / (fam.equivalent_aspect_ratio**2 + 1), rel=1e-14)


def test_spheroid_and_sphere_xi_exact():
    r = scene([{"shape": "spheroid", "radius": 0.1, "aspect_ratio": 5.0, "count": 1},
               {"shape": "sphere", "radius": 0.1, "count": 1}])
    spheroid, sphere = r.families
    assert spheroid.length == pytest.approx(1.0) and spheroid.xi == pytest.approx(24.0 / 26.0, rel=1e-15)
    assert sphere.xi == 0.0 and sphere.length == pytest.approx(0.2)


def test_defaults_filled_and_resolved_values():
    r = scene([dict(FIBRE, count=10)])
    assert r.alpha == pytest.approx(0.002)  # a tenth of the smallest radius
    assert r.n_steps == 100 and r.output_every == 1 and r.snapshot_every == 10 and r.checkpoint_every == 5
    assert r.scene.numerics.seed == 0 and r.scene.numerics.stokes.kappa == 1e3
    assert r.scene.particles[0].name == "family0" and r.scene.particles[0].equivalent_aspect_ratio == "cox"
    G = np.zeros((3, 3))
    G[0, 1] = 1.0
    np.testing.assert_array_equal(r.velocity_gradient, G)
    assert r.shear_rate == 1.0 and r.wall_speed == 0.0


def test_two_dimensional_scene_uses_two_dimensional_arrays():
    r = scene([{"shape": "fibre", "length": 0.5, "radius": 0.02, "count": 4, "orientation": "aligned",
                "direction": [0.0, 2.0]}], cell=(2.0, 2.0), dim=2)
    assert r.dim == 2 and r.families[0].axes.shape == (1, 2)
    np.testing.assert_array_equal(r.families[0].axes[0], [0.0, 1.0])
    np.testing.assert_array_equal(r.cell_lengths, [2.0, 2.0, 0.0])


def test_general_gradient_of_simple_shear_form_accepted_and_rate_computed():
    data = {"cell": {"size": [4.0, 4.0, 4.0], "boundary": "couette"},
            "flow": {"type": "general", "gradient": [[0.0, -2.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]},
            "particles": [dict(FIBRE, count=4)], "numerics": {"dt": 0.01, "t_end": 1.0}}
    r = parse_scene(tomli_w.dumps(data))
    assert r.shear_rate == pytest.approx(2.0) and r.wall_speed == pytest.approx(-4.0)  # U = G_xy Ly / 2


def test_volume_fraction_too_small_for_one_particle():
    with pytest.raises(InputError, match=r"particles\[0\].volume_fraction: .* holds no whole particle"):
        scene([dict(FIBRE, volume_fraction=1e-6)])
