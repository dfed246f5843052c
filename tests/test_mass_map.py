"""Per-point mass (`cloth.mass_map`): the mapping, the statics it implies, the stability limit."""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from conftest import cloth_dict, scene_dict
from pipeline import Simulation
from pipeline.physics.model import build_model
from pipeline.scene import load_scene
from pipeline.physics.system import stability_limit
from test_stability import _stiffness_matrix


def _model(cloth: dict):
    return build_model(load_scene(scene_dict(cloth)))


def test_rows_map_top_edge_first_onto_the_grid():
    cloth = cloth_dict(3, 2, density=6.0)  # uniform point mass 1 * 1 * 6 / 6 = 1 kg
    cloth["mass_map"] = [[1, 2, 3], [4, 5, 6]]  # first row = top edge = row y_index 1
    m = _model(cloth)
    assert m.mass == 1.0
    np.testing.assert_array_equal(m.point_mass, [4, 5, 6, 1, 2, 3])


def test_small_map_is_resampled_bilinearly():
    cloth = cloth_dict(5, 3, density=15.0)  # point mass 1 kg
    cloth["mass_map"] = [[1.0, 3.0], [2.0, 4.0]]
    grid = _model(cloth).point_mass.reshape(3, 5)[::-1]  # back to top-first rows
    np.testing.assert_allclose(grid[0], [1.0, 1.5, 2.0, 2.5, 3.0])
    np.testing.assert_allclose(grid[2], [2.0, 2.5, 3.0, 3.5, 4.0])
    np.testing.assert_allclose(grid[1], [1.5, 2.0, 2.5, 3.0, 3.5])


def test_image_map_uses_the_range(tmp_path):
    img = np.zeros((2, 4), dtype=np.uint8)
    img[1] = 255  # bottom row of the picture white: a heavy hem
    Image.fromarray(img, mode="L").save(tmp_path / "hem.png")
    d = scene_dict(cloth_dict(4, 2, density=8.0))  # point mass 1 kg
    d["cloth"]["mass_map"] = "hem.png"
    d["cloth"]["mass_map_range"] = [0.5, 3.0]
    (tmp_path / "scene.json").write_text(__import__("json").dumps(d))
    m = build_model(load_scene(tmp_path / "scene.json"))
    np.testing.assert_allclose(m.point_mass, [3.0] * 4 + [0.5] * 4)  # row 0 is the bottom


@pytest.mark.parametrize("integrator", ["verlet", "implicit-euler"])
def test_hanging_strip_tension_carries_the_weight_below(integrator):
    """A 2-wide vertical strip pinned at the top, structural springs only, comes to rest with
    each vertical spring stretched by k dl = g * (mass of the points below it), the masses
    coming from the map (a hem four times heavier than the rest)."""
    nh, ks, g = 8, 4000.0, 9.8
    # horizontal cloth (rows along z, no jitter) hanging along -z from its last row
    cloth = cloth_dict(2, nh, width=0.1, height=0.7, orientation=0, density=20.0, ks=ks,
                       damping=2.0, shearing=False, bending=False,
                       pinned=[(0, nh - 1), (1, nh - 1)])
    cloth["mass_map"] = [[1.0, 1.0]] * (nh - 1) + [[4.0, 4.0]]
    d = scene_dict(cloth, gravity=(0.0, 0.0, -g), frames_per_sec=60, steps_per_frame=40)
    d["simulation"]["integrator"] = integrator
    sim = Simulation(d)
    sim.advance(180)
    y = sim.positions[:, 2].reshape(nh, 2)
    rest = 0.7 / (nh - 1)
    mass = sim.model.point_mass.reshape(nh, 2)
    for i in range(nh - 1):  # the spring between rows i and i + 1 holds rows 0..i
        stretch = (y[i + 1] - y[i]) - rest
        expected = g * mass[: i + 1, 0].sum() / ks
        np.testing.assert_allclose(stretch, expected, rtol=2e-3)
    assert mass[0, 0] == 4.0 * mass[1, 0]


def test_stability_limit_follows_the_lightest_point():
    cloth = cloth_dict(12, 12, width=1.0, height=1.0, ks=5000.0, density=150.0)
    omega_uniform, _ = stability_limit(_model(cloth))
    cloth["mass_map"] = [[0.25] * 12] * 12
    omega_light, _ = stability_limit(_model(cloth))
    assert omega_light == pytest.approx(2.0 * omega_uniform, rel=1e-12)


def test_stability_limit_bounds_the_finite_cloth_with_a_heavy_hem():
    """omega_max from the lightest point is an upper bound of the finite cloth's highest
    frequency sqrt(max eig of M^-1 K) with a mass map, and within 15% of it when the light
    points fill most of the cloth."""
    cloth = cloth_dict(12, 12, width=1.0, height=1.0, ks=5000.0, density=150.0)
    cloth["mass_map"] = [[1.0] * 12] * 10 + [[3.0] * 12] * 2
    K, _ = _stiffness_matrix(cloth)
    model = _model(cloth)
    y = np.arange(1, K.shape[0], 3)
    xz = np.setdiff1d(np.arange(K.shape[0]), y)
    inv_sqrt_m = 1.0 / np.sqrt(np.repeat(model.point_mass, 3)[xz])
    sym = K[np.ix_(xz, xz)] * inv_sqrt_m[:, None] * inv_sqrt_m[None, :]
    lam = np.linalg.eigvalsh(sym).max()
    omega, _ = stability_limit(model)
    assert lam <= omega ** 2 * (1 + 1e-9)
    assert lam >= (0.85 * omega) ** 2
