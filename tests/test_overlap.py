"""Cloth points starting inside a collider are moved out before the first step, with a
warning; scenes without such points are not touched (pipeline.physics.overlap)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from conftest import COURSE_SCENES, SCENES, scene_path
from pipeline.physics.model import build_model
from pipeline.physics.overlap import StartInsideWarning, project_out, resolve_start_inside, still_table
from pipeline.scene import load_scene
from pipeline.simulation import Simulation


@pytest.mark.parametrize("name", COURSE_SCENES + ("two_spheres", "tablecloth", "bowl"))
def test_scenes_without_overlap_are_untouched(name):
    scene = load_scene(scene_path(name))
    model = build_model(scene)
    before = model.x0.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error", StartInsideWarning)
        assert resolve_start_inside(scene, model) == []
    assert model.x0.tobytes() == before.tobytes()


def test_curtain_is_moved_out_at_rest_with_a_warning():
    with pytest.warns(StartInsideWarning) as caught:
        sim = Simulation(SCENES / "curtain.json")
    assert len(caught) == 1
    msg = str(caught[0].message)
    assert msg.startswith("120 cloth points started inside the sphere (origin [0.5, 0.45, "
                          "0.12], radius 0.2)")
    x = sim.model.x0
    out = x.copy()
    project_out(out, sim.model.pinned, still_table(sim.scene.colliders))
    assert np.abs(out - x).max() < 1e-12  # on the surface (a re-projection only rounds)
    assert np.all(sim.velocities == 0.0)
    pinned = sim.model.pinned.astype(bool)
    flat = build_model(sim.scene).x0
    assert np.array_equal(x[:, pinned], flat[:, pinned])  # pins stay where the scene put them
    sim.advance(30)  # diverged at frame 1 before
    assert np.all(np.isfinite(sim.positions))


def test_count_is_per_collider_and_planes_never_count():
    scene = load_scene(SCENES / "curtain.json",
                       ["sphere=[{\"origin\": [0.5, 0.45, 0.12], \"radius\": 0.2, "
                        "\"friction\": 0.2}, {\"origin\": [0.2, 0.2, 0.0], \"radius\": 0.05, "
                        "\"friction\": 0}]", "plane={\"point\": [0, 0.5, 0], "
                        "\"normal\": [0, 1, 0], \"friction\": 0.5}"])
    model = build_model(scene)
    with pytest.warns(StartInsideWarning):
        found = resolve_start_inside(scene, model)
    assert [(type(c).__name__, n) for c, n in found] == [("Sphere", 120), ("Sphere", 11)]


def test_a_collider_cutting_through_the_cloths_plane_is_refused_naming_it_and_the_points(
        tmp_path):
    """The sphere scene with the sphere centred on the cloth's plane: the points inside go
    out in the plane (no side to drape to), the springs stay squeezed many times over, so
    the run is refused with exit status 2 before any output, naming the sphere and points,
    instead of diverging on the first step with advice about the step."""
    from pipeline.cli import main
    from pipeline.scene import SceneError

    scene = load_scene(scene_path("sphere"), ["sphere.0.origin=[0.5, 1.0, 0.5]"])
    with pytest.raises(SceneError, match=r"300 cloth points start inside the sphere \(origin "
                                         r"\[0.5, 1, 0.5\], radius 0.2\) \(points \[23, 15\]"):
        Simulation(scene)
    out = tmp_path / "x.gif"
    code = main([str(scene_path("sphere")), "--set", "sphere.0.origin=[0.5,1.0,0.5]",
                 "--out", str(out)])
    assert code == 2 and not out.exists()
