"""A cloth from a mesh file (`cloth.mesh`) in the simulator: against the grid cloth it can
equal, at rest in its own shape, with pins, colliders, self-collision and the integrators."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import cloth_dict, scene_dict
from pipeline import Simulation, load_scene
from pipeline.scene import SceneError
from test_mesh_model import cylinder_patch, grid_mesh


def write_obj(path: Path, points: np.ndarray, tris: np.ndarray, corner_uv=None) -> Path:
    """An OBJ with one vt per triangle corner when corner_uv is given."""
    lines = ["v %r %r %r" % tuple(map(float, p)) for p in points]
    if corner_uv is None:
        lines += ["f %d %d %d" % tuple(t + 1) for t in tris]
    else:
        lines += ["vt %r %r" % tuple(map(float, uv)) for uv in corner_uv.reshape(-1, 2)]
        lines += ["f " + " ".join(f"{v + 1}/{3 * k + c + 1}" for c, v in enumerate(t))
                  for k, t in enumerate(tris)]
    path.write_text("\n".join(lines) + "\n")
    return path


def horizontal_grid_obj(tmp_path: Path, nw: int, nh: int, width=1.0, height=1.0) -> Path:
    """The course grid's points of a horizontal cloth, (x, 1, z), and triangles, as an OBJ."""
    points, tris, corner_uv = grid_mesh(nw, nh, width, height)
    placed = np.stack([points[:, 0], np.ones(len(points)), points[:, 1]], axis=1)
    return write_obj(tmp_path / f"grid{nw}x{nh}.obj", placed, tris, corner_uv)


def mesh_scene(obj: Path, *, pinned=(), model="classic", integrator="verlet", **kw) -> dict:
    scene = scene_dict(**kw)
    scene["cloth"] = {"mesh": str(obj), "thickness": 0.01, "damping": 0.2, "density": 1.0,
                      "ks": 1000.0, "pinned": list(pinned)}
    scene["simulation"].update(model=model, integrator=integrator)
    return scene


def test_a_grid_mesh_with_the_fem_moves_as_the_grid_fem_cloth(tmp_path):
    """The issue's check: a flat square mesh of the course grid's triangles under the FEM
    gives the grid FEM cloth's positions after 1 s to within 1e-9 m."""
    nw = nh = 9
    grid = scene_dict(cloth_dict(nw, nh, orientation=0, damping=0.2, pinned=((0, 0), (8, 0))))
    grid["simulation"]["model"] = "fem"
    mesh = mesh_scene(horizontal_grid_obj(tmp_path, nw, nh), pinned=(0, 8), model="fem")
    runs = []
    for scene in (grid, mesh):
        sim = Simulation(scene)
        sim.step(int(round(1.0 / sim.dt)))
        runs.append(sim.positions.copy())
    assert np.abs(runs[1] - runs[0]).max() < 1e-9
    assert np.abs(runs[0] - Simulation(grid).positions).max() > 0.1  # it did fall


@pytest.mark.parametrize("model", ["classic", "fem"])
def test_a_curved_mesh_without_gravity_stays_in_its_own_shape(tmp_path, model):
    points, tris, corner_uv = cylinder_patch()
    obj = write_obj(tmp_path / "patch.obj", points, tris, corner_uv)
    sim = Simulation(mesh_scene(obj, model=model, gravity=(0.0, 0.0, 0.0)))
    start = sim.positions.copy()
    sim.step(900)
    assert np.abs(sim.positions - start).max() < 1e-12


@pytest.mark.parametrize("integrator", ["verlet", "euler", "symplectic-euler", "rk4",
                                        "implicit-euler"])
def test_pins_hold_and_the_cloth_falls_with_every_mesh_integrator(tmp_path, integrator):
    obj = horizontal_grid_obj(tmp_path, 8, 8)
    sim = Simulation(mesh_scene(obj, pinned=(0, 7), integrator=integrator))
    start = sim.positions.copy()
    sim.step(450)  # 1/6 s: explicit Euler diverges later (it is unstable for any step)
    assert np.array_equal(sim.positions[[0, 7]], start[[0, 7]])
    assert sim.positions[:, 1].min() < start[:, 1].min() - 0.08


def test_provots_limit_holds_the_structural_springs(tmp_path):
    """Heavy, soft cloth: without the limit its springs stretch far beyond 10 %; with it,
    each step ends with every structural spring within about 1.1 rest (one Gauss-Seidel
    walk leaves a little)."""
    obj = horizontal_grid_obj(tmp_path, 10, 10)
    scene = mesh_scene(obj, pinned=(0, 9))
    scene["cloth"].update(ks=5.0, density=5.0)
    sim = Simulation(scene)
    sim.step(900)
    s = sim.model.mesh.springs
    x = sim.positions
    ratio = np.linalg.norm(x[s.a] - x[s.b], axis=1)[:s.structural] / s.rest[:s.structural]
    assert 1.1 < ratio.max() < 1.2


def test_a_draped_mesh_stays_outside_the_sphere(tmp_path):
    obj = horizontal_grid_obj(tmp_path, 12, 12)
    scene = mesh_scene(obj, spheres=[((0.5, 0.5, 0.5), 0.3, 0.3)])
    sim = Simulation(scene)
    sim.step(2700)
    r = np.linalg.norm(sim.positions - np.array([0.5, 0.5, 0.5]), axis=1)
    assert r.min() >= 0.3 - 1e-9 and r.min() < 0.33  # resting on it


def test_self_collision_boxes_of_a_mesh_are_three_mean_edges(tmp_path):
    obj = horizontal_grid_obj(tmp_path, 11, 11)
    sim = Simulation(mesh_scene(obj, self_collision=True))
    mean_edge = (220 * 0.1 + 100 * 0.02 ** 0.5) / 320  # 10 x 11 x 2 sides, 100 diagonals
    assert sim.system.collision_box == pytest.approx((3 * mean_edge,) * 2, rel=1e-12)
    sim.step(100)
    assert np.isfinite(sim.positions).all()


@pytest.mark.parametrize("model", ["classic", "fem"])
def test_implicit_euler_on_a_grid_mesh_moves_as_on_the_grid(tmp_path, model):
    """Backward Euler (CG to 1e-9) on the grid's triangles: the mesh FEM moves as the grid
    FEM. The classic mesh has other springs than the grid (no shearing springs, bending
    springs across edges), so it is checked for falling and staying finite only."""
    nw = nh = 9
    mesh = mesh_scene(horizontal_grid_obj(tmp_path, nw, nh), pinned=(0, 8), model=model,
                      integrator="implicit-euler")
    mesh["simulation"]["self_collision"] = False
    sim = Simulation(mesh)
    sim.step(int(round(0.3 / sim.dt)))
    if model == "classic":
        assert sim.positions[:, 1].min() < 0.8 and np.isfinite(sim.positions).all()
        return
    grid = scene_dict(cloth_dict(nw, nh, orientation=0, damping=0.2, pinned=((0, 0), (8, 0))))
    grid["simulation"].update(model="fem", integrator="implicit-euler")
    reference = Simulation(grid)
    reference.step(sim.step_count)
    moved = np.abs(reference.positions - reference.model.initial_positions).max()
    assert moved > 0.1
    assert np.abs(sim.positions - reference.positions).max() < 1e-6 * moved


def test_wind_on_a_grid_mesh_is_the_grid_clothes_wind(tmp_path):
    """The wind's force on a mesh of the course grid's triangles, moving points in gusty
    air, against pipeline.physics.wind's grid kernel (float32 inside both: 1e-5)."""
    from pipeline.physics.mesh_wind import add_mesh_wind_force
    from pipeline.physics.wind import add_wind_force

    nw = nh = 12
    obj = horizontal_grid_obj(tmp_path, nw, nh)
    wind = {"velocity": [2.0, 0.5, -1.0], "gust": 1.5, "lift": 0.3}
    grid = scene_dict(cloth_dict(nw, nh, orientation=0))
    grid["wind"] = wind
    mesh = mesh_scene(obj)
    mesh["wind"] = wind
    forces = []
    for scene, kernel in ((grid, add_wind_force), (mesh, add_mesh_wind_force)):
        s = Simulation(scene).system
        x = s.x0.copy()
        x[1] += 0.02 * np.sin(7 * x[0])
        v = np.ascontiguousarray(np.cos(5 * x) * 0.7)
        f = np.zeros_like(x)
        kernel(x, v, 0.37, s.wind, f)
        forces.append(f)
    assert np.abs(forces[0]).max() > 1e-4
    assert np.abs(forces[1] - forces[0]).max() < 1e-5 * np.abs(forces[0]).max()


def test_stability_limit_of_a_mesh_is_its_highest_frequency(tmp_path):
    """omega_max (power iteration on finite differences of the forces, raised 5 %) against
    the largest eigenvalue of M^-1 K assembled here from the springs (k u u^T blocks) and
    solved densely."""
    obj = horizontal_grid_obj(tmp_path, 13, 13)
    sim = Simulation(mesh_scene(obj))
    s, x, m = sim.model.mesh.springs, sim.model.x0.T, sim.model.point_mass
    n = len(x)
    k = np.zeros((3 * n, 3 * n))
    for a, b, stiffness in zip(s.a, s.b, s.stiffness):
        u = (x[b] - x[a]) / np.linalg.norm(x[b] - x[a])
        block = stiffness * np.outer(u, u)
        for p, q, sign in ((a, a, 1), (b, b, 1), (a, b, -1), (b, a, -1)):
            k[3 * p:3 * p + 3, 3 * q:3 * q + 3] += sign * block
    scale = 1.0 / np.sqrt(np.repeat(m, 3))
    largest = np.linalg.eigvalsh(scale[:, None] * k * scale[None, :]).max()
    assert sim.omega_max == pytest.approx(1.05 * largest ** 0.5, rel=0.03)


def test_loads_with_the_course_keys_refused(tmp_path):
    obj = horizontal_grid_obj(tmp_path, 4, 4)
    scene = mesh_scene(obj)
    scene["cloth"]["width"] = 1.0
    with pytest.raises(SceneError, match="cloth.width"):
        load_scene(scene)


def test_keyframed_pins_follow_their_pose_about_their_centroid(tmp_path):
    """Two corners held and carried: up 0.5 m while turning 90 degrees about y around their
    centroid (0.5, 1, 0), linear in between; the free cloth follows."""
    obj = horizontal_grid_obj(tmp_path, 10, 10)
    scene = mesh_scene(obj)
    scene["cloth"]["pinned"] = [{"indices": [0, 9], "keyframes": [
        {"time": 0.0}, {"time": 1.0, "translation": [0.0, 0.5, 0.0], "rotation": [0, 90, 0]}]}]
    sim = Simulation(scene)
    steps = int(round(0.5 / sim.dt))
    sim.step(steps)
    half = np.radians(45.0)  # at t = 0.5 s: halfway
    for p, x0 in ((0, -0.5), (9, 0.5)):
        expected = [0.5 + np.cos(half) * x0, 1.25, -np.sin(half) * x0]
        assert np.allclose(sim.positions[p], expected, atol=1e-12)
    sim.step(steps)
    assert np.allclose(sim.positions[[0, 9]], [[0.5, 1.5, 0.5], [0.5, 1.5, -0.5]], atol=1e-12)
    assert sim.positions[:, 1].max() > 1.2  # the cloth was lifted with them


def test_a_hanging_strip_sags_as_the_grid_strip_of_the_same_material(tmp_path):
    """FEM statics on another triangulation: a 1 m x 0.1 m strip held at both short ends,
    its cells cut along the other diagonal, comes to rest within 2 % of the grid strip's
    sag (both fine enough that halving the grid spacing changes the grid's sag by < 1 %)."""
    def sag(scene):
        sim = Simulation(scene)
        sim.step(int(round(3.0 / sim.dt)))
        x = sim.positions
        return 1.0 - x[:, 1].min(), np.abs(x - sim.last_positions).max()

    def grid_scene(nw, nh):
        pins = [(j, i) for i in range(nh) for j in (0, nw - 1)]
        scene = scene_dict(cloth_dict(nw, nh, width=1.0, height=0.1, orientation=0,
                                      damping=2.0, pinned=pins))
        scene["simulation"]["model"] = "fem"
        return scene

    nw, nh = 41, 5
    coarse, _ = sag(grid_scene(21, 3))
    grid, still = sag(grid_scene(nw, nh))
    assert still < 1e-9 and abs(coarse - grid) < 0.01 * grid
    points, tris, corner_uv = grid_mesh(nw, nh, 1.0, 0.1)
    a, b, c, d = tris[: len(tris) // 2, 0], tris[: len(tris) // 2, 2], tris[: len(tris) // 2, 1], None
    d = c + 1  # the cells' corners A, B, C, D: cut along A-D instead of B-C
    other = np.concatenate([np.stack([a, c, d], 1), np.stack([a, d, b], 1)])
    uv = np.stack([points[:, 0], points[:, 1] / 0.1], 1)
    placed = np.stack([points[:, 0], np.ones(len(points)), points[:, 1]], 1)
    obj = write_obj(tmp_path / "strip.obj", placed, other, uv[other])
    ends = [int(p) for p in np.nonzero((points[:, 0] == 0.0) | (points[:, 0] == 1.0))[0]]
    mesh = mesh_scene(obj, pinned=ends, model="fem")
    mesh["cloth"]["damping"] = 2.0
    mesh["simulation"]["self_collision"] = False
    got, still = sag(mesh)
    assert still < 1e-9 and got > 0.01
    assert abs(got - grid) < 0.02 * grid, (got, grid)


def test_a_mass_map_image_is_read_at_each_points_uv(tmp_path):
    """On a mesh of the grid's points with the grid's uvs, the image's multipliers are the
    grid cloth's (pipeline.physics.model.mass_multipliers resamples the image to the grid
    on its own)."""
    from PIL import Image

    image = tmp_path / "map.png"
    Image.fromarray(np.array([[0, 80, 255, 30, 200], [255, 0, 120, 60, 10],
                              [40, 90, 250, 0, 255]], np.uint8)).save(image)
    grid = scene_dict(cloth_dict(9, 7, orientation=0))
    grid["cloth"].update(mass_map=str(image), mass_map_range=[1.0, 3.0])
    mesh = mesh_scene(horizontal_grid_obj(tmp_path, 9, 7))
    mesh["cloth"].update(mass_map=str(image), mass_map_range=[1.0, 3.0])
    m_grid, m_mesh = Simulation(grid).model, Simulation(mesh).model
    uniform = Simulation(mesh_scene(horizontal_grid_obj(tmp_path, 9, 7))).model.point_mass
    expected = m_grid.point_mass / m_grid.mass
    assert np.allclose(m_mesh.point_mass / uniform, expected, rtol=1e-12)
    assert expected.max() > 2.5 and expected.min() < 1.2


def test_edges_under_twice_the_thickness_are_warned_of_with_self_collision(tmp_path):
    from pipeline.physics.errors import SelfCollisionWarning

    obj = horizontal_grid_obj(tmp_path, 11, 11)  # edges 0.1 and 0.14 m
    scene = mesh_scene(obj, self_collision=True)
    scene["cloth"]["thickness"] = 0.06
    with pytest.warns(SelfCollisionWarning, match="220 edges shorter than 2 x cloth.thickness"):
        Simulation(scene)
    scene["cloth"]["thickness"] = 0.04
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Simulation(scene)
