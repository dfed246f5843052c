"""The default camera (SPEC 4, issue 15): no `camera` frames the whole shot from the course
direction (pipeline.view.framing); "course" is SPEC 4's camera exactly; an object is unchanged."""
from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import shading
from pipeline.cli import main
from pipeline.cli.render import nearest_sim_frames, output_times
from pipeline.view.framing import FLAT, MARGIN, NEAR_FRACTION, Framing, frame_shot, framed_points
from pipeline.view.framing import default_camera
from pipeline.run.frames import render_frame, render_params, scene_meshes
from pipeline.physics.model import build_model
from pipeline.scene import load_scene
from pipeline.simulation import simulate

from conftest import cloth_dict

SIZE = (80, 48)  # not square: the aspect ratio enters the framing


def _scene(**extra) -> dict:
    d = {"cloth": cloth_dict(9, 9, thickness=0.01, damping=0.2, density=150.0, ks=5000.0)}
    d.update(extra)
    return d


def _inside(cam, points: np.ndarray) -> np.ndarray:
    """Which points project inside the image less its MARGIN on every side."""
    p = cam.project(points)
    mx, my = MARGIN * cam.width, MARGIN * cam.height
    eps = 1e-6
    return ((p[:, 0] >= mx - eps) & (p[:, 0] <= cam.width - mx + eps)
            & (p[:, 1] >= my - eps) & (p[:, 1] <= cam.height - my + eps)
            & (p[:, 2] > 0.0) & (p[:, 2] < 1.0))


def _shot(scene, n: int, fps: float):
    """(positions, time) of the n output frames at fps, as `render` picks them."""
    sim_fps = scene.simulation.frames_per_sec
    js = nearest_sim_frames(output_times(n, fps), sim_fps)
    frames = simulate(scene, js[-1])
    x0 = build_model(scene).initial_positions
    return [(x0 if j == 0 else frames[j - 1], j / sim_fps) for j in js]


def _course(scene, x0, w, h):
    """SPEC 4, written out: target (cx, cy / 2, cz), eye target + (0, 0, 1.8 max(w, h))."""
    c = np.asarray(x0).mean(axis=0)
    target = (c[0], c[1] / 2.0, c[2])
    eye = (c[0], c[1] / 2.0, c[2] + 1.8 * max(scene.cloth.width, scene.cloth.height))
    return shading.Camera(eye, target, (0.0, 1.0, 0.0), 35.0, 0.01, 100.0, w, h)


@pytest.fixture(scope="module")
def draped(tmp_path_factory):
    """A small cloth falling onto a sphere for 1.2 s (25 fps), and its scene file."""
    d = _scene(sphere={"origin": [0.5, 0.2, 0.5], "radius": 0.2, "friction": 0.3})
    path = tmp_path_factory.mktemp("framing") / "draped.json"
    path.write_text(json.dumps(d))
    scene = load_scene(path)
    return path, scene, _shot(scene, 30, 25.0)


def test_framed_camera_contains_every_frame_tightly(draped):
    _, scene, shot = draped
    cam = frame_shot(scene, shot, *SIZE).camera()
    assert cam.up == (0.0, 1.0, 0.0) and cam.vfov == 35.0
    assert cam.eye[:2] == cam.target[:2] and cam.eye[2] > cam.target[2]  # looks down -z
    for positions, _ in shot:
        assert _inside(cam, positions).all()
    # tight: the projected shot reaches the margin on both sides of one axis
    p = np.concatenate([cam.project(x) for x, _ in shot])
    lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
    w, h = SIZE
    gaps = np.abs([lo[0] - MARGIN * w, w - MARGIN * w - hi[0], lo[1] - MARGIN * h,
                   h - MARGIN * h - hi[1]])
    assert (gaps[:2] < 1e-6).all() or (gaps[2:] < 1e-6).all()
    # the drape hangs below where the course camera shows it: that is the issue
    course = _course(scene, shot[0][0], *SIZE)
    assert not _inside(course, shot[-1][0]).all()


def test_framing_is_deterministic_and_order_free(draped):
    _, scene, shot = draped
    a = frame_shot(scene, shot, *SIZE).camera()
    b = frame_shot(scene, shot[::-1], *SIZE).camera()
    assert a == b


def test_render_uses_the_framed_camera_and_at_t_matches_the_animation(draped, tmp_path,
                                                                      capsys):
    path, scene, shot = draped
    size = f"{SIZE[0]}x{SIZE[1]}"
    flags = ["--size", size, "--frames", "30", "--fps", "25", "-q"]
    assert main([str(path), "--out", f"{tmp_path}/f/", *flags]) == 0
    assert main([str(path), "--out", str(tmp_path / "at.png"), "--at", "0.96", *flags]) == 0
    k = 24  # t = 0.96 s
    frame = np.asarray(Image.open(tmp_path / "f" / f"frame_{k:05d}.png"))
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "at.png")), frame)
    model = build_model(scene)
    framing = frame_shot(scene, shot, *SIZE)
    positions, t = shot[k]
    expected = render_frame(scene, positions, model, width=SIZE[0], height=SIZE[1], time=t,
                            shot=framing)
    np.testing.assert_array_equal(frame, expected)


def test_course_camera_is_spec4_exactly(draped, tmp_path):
    path, scene, shot = draped
    course = load_scene(path, ["camera=course"])
    assert course.camera == "course"
    x0, t = shot[0]
    cam = default_camera(course, x0, *SIZE, shot=frame_shot(scene, shot, *SIZE))
    assert cam == _course(course, x0, *SIZE)
    # and `render` draws with it
    out = tmp_path / "course.png"
    assert main([str(path), "--set", "camera=course", "--out", str(out), "--at", "0.96",
                 "--size", f"{SIZE[0]}x{SIZE[1]}", "--frames", "30", "-q"]) == 0
    positions, t = shot[24]
    meshes = scene_meshes(course, positions, build_model(course), t)
    expected = shading.render(meshes, _course(course, x0, *SIZE), course.light, "phong",
                              render_params(course))
    np.testing.assert_array_equal(np.asarray(Image.open(out)), expected)


def test_object_camera_is_unchanged(draped):
    _, scene, shot = draped
    d = _scene(camera={"position": [0.2, 1.5, 3.0], "target": [0.5, 0.3, 0.4],
                       "up": [0.1, 1.0, 0.0], "vfov": 50})
    s = load_scene(d)
    cam = default_camera(s, shot[0][0], *SIZE, shot=frame_shot(scene, shot, *SIZE))
    assert cam == shading.Camera((0.2, 1.5, 3.0), (0.5, 0.3, 0.4), (0.1, 1.0, 0.0), 50.0,
                                 0.01, 100.0, *SIZE)


def test_a_shot_framed_for_another_size_is_refused(draped):
    _, scene, shot = draped
    with pytest.raises(ValueError, match="framed for 80x48"):
        default_camera(scene, shot[0][0], 48, 80, shot=frame_shot(scene, shot, *SIZE))


def _hanging(bottom: float) -> np.ndarray:
    """A vertical 1 m x 1 m cloth in the plane z = 0, its lowest row at y = bottom."""
    u = np.linspace(-0.5, 0.5, 11)
    x, y = np.meshgrid(u, bottom + 0.5 + u)
    return np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]


@pytest.mark.parametrize("collider, below", [  # each collider's top is at y = 0
    ({"plane": {"point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5}},
     [[x, 0.0, 0.0] for x in np.linspace(-0.5, 0.5, 11)]),  # the floor under the hem
    ({"sphere": {"origin": [0, -0.3, 0], "radius": 0.3, "friction": 0.5}},
     [[0.0, 0.0, 0.0]]),  # the sphere's top
    ({"box": {"center": [0, -0.5, 0], "half_extents": [0.2, 0.5, 0.2], "friction": 0.5}},
     [[-0.2, 0.0, 0.0], [0.0, 0.0, 0.0], [0.2, 0.0, 0.0]]),  # the box's top
])
def test_the_collider_under_the_cloth_is_framed(collider, below):
    """A hem 3 cm above a collider: the surface under it is in the image, though framing the
    cloth alone leaves it out; an infinite plane is not framed whole."""
    scene = load_scene(_scene(**collider))
    cloth = _hanging(0.03)
    framing, alone = Framing(*SIZE), Framing(*SIZE)
    framing.add(framed_points(scene, cloth, 0.0))
    alone.add(cloth)
    cam = framing.camera()
    assert _inside(cam, cloth).all()
    assert _inside(cam, np.array(below)).all()
    assert not _inside(alone.camera(), np.array(below)).all()
    assert not _inside(cam, np.array([[10.0, 0.0, 0.0], [-10.0, 0.0, 0.0]])).any()


def test_framed_collider_points_lie_on_the_posed_surface():
    """A keyframed sphere: the framed surface points are on the sphere where it is at t."""
    d = _scene(sphere={"origin": [0, 0, 0], "radius": 0.3, "friction": 0.5,
                       "keyframes": [{"time": 0, "translation": [0, 0, 0]},
                                     {"time": 1, "translation": [2, 0, 0]}]})
    scene = load_scene(d)
    cloth = _hanging(0.33) + [1.0, 0.0, 0.0]  # over where the sphere is at t = 0.5
    extra = framed_points(scene, cloth, 0.5)[len(cloth):]
    assert len(extra) > 0
    np.testing.assert_allclose(np.linalg.norm(extra - [1.0, 0.0, 0.0], axis=1), 0.3)
    assert len(framed_points(scene, cloth, 0.0)) == len(cloth)  # the sphere is 1 m away
    # a box: points inside go to the nearest face, points outside to the nearest point
    box = load_scene(_scene(box={"center": [0, 0, 0], "half_extents": [1.0, 0.5, 1.0],
                                 "friction": 0.5}))
    pts = np.array([[0.3, 0.45, 0.2], [0.3, 0.55, 0.2], [1.05, 0.52, 0.0]])
    np.testing.assert_allclose(framed_points(box, pts, 0.0)[3:],
                               [[0.3, 0.5, 0.2], [0.3, 0.5, 0.2], [1.0, 0.5, 0.0]])
    far = pts + [0.0, NEAR_FRACTION + 0.01, 0.0]  # farther than the cloth's NEAR_FRACTION
    assert len(framed_points(box, far[1:], 0.0)) == 2



def _tight(cam, points: np.ndarray) -> bool:
    """The projected points reach the margin on both sides of one image axis."""
    p = cam.project(points)
    lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
    w, h = cam.width, cam.height
    gaps = np.abs([lo[0] - MARGIN * w, w - MARGIN * w - hi[0], lo[1] - MARGIN * h,
                   h - MARGIN * h - hi[1]])
    return bool((gaps[:2] < 1e-6).all() or (gaps[2:] < 1e-6).all())


def test_a_flat_shot_is_seen_from_above():
    """A cloth lying flat the whole shot (1 m x 1 m at y = 0): framed from its own height it
    was edge on, one row of pixels; it is framed as if FLAT times its depth high, so the eye
    is above it and it spans rows. A shot that high or more is framed as before (tight)."""
    u = np.linspace(-0.5, 0.5, 11)
    x, z = (a.ravel() for a in np.meshgrid(u, u))
    flat = np.c_[x, np.zeros(x.size), z]
    f = Framing(*SIZE)
    f.add(flat)
    cam = f.camera()
    assert cam.eye[1] > 0.0 and _inside(cam, flat).all()
    rows = np.ptp(cam.project(flat)[:, 1])
    assert rows > 0.08 * SIZE[1], rows  # about 48 rows of a 512-row image; 0 before
    sloped = flat + np.c_[np.zeros(x.size), FLAT * (z + 0.5), np.zeros(x.size)]
    g = Framing(*SIZE)
    g.add(sloped)
    assert _inside(g.camera(), sloped).all() and _tight(g.camera(), sloped)

def test_far_plane_follows_a_long_fall():
    f = Framing(*SIZE)
    for y in (0.0, -150.0):  # a cloth falling 150 m
        f.add(_hanging(y))
    cam = f.camera()
    assert cam.far > 100.0
    assert _inside(cam, np.concatenate([_hanging(0.0), _hanging(-150.0)])).all()
    with pytest.raises(ValueError, match="nothing to frame"):
        Framing(*SIZE).camera()


@pytest.mark.parametrize("value, expected", [
    ('"top"', 'camera: expected "course" or a camera object with position and target, '
              'got "top"'),
    ("5", 'camera: expected "course" or a camera object with position and target, got 5'),
    ('{"position": [0, 1, 3]}', "camera.target: missing required key"),
])
def test_bad_camera_values_exit_2(tmp_path, capsys, value, expected):
    path = tmp_path / "bad.json"
    path.write_text(f'{{"cloth": {json.dumps(cloth_dict(3, 3))}, "camera": {value}}}')
    code = main([str(path), "--out", str(tmp_path / "x.png"), "-q"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith(f"render: {path}: {expected}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json"]
