"""Meshes, camera, textures and the image-comparison helper."""
from __future__ import annotations

import json

import numpy as np
import pytest

import shading
from pipeline.view.framing import default_camera
from pipeline.run.frames import scene_meshes
from pipeline.physics.model import build_model
from pipeline.scene import load_scene
from shading.testing import assert_image_close
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def grid(nw, nh):
    j = np.tile(np.arange(nw, dtype=float), nh)
    i = np.repeat(np.arange(nh, dtype=float), nw)
    return np.stack([j / (nw - 1), np.ones(nw * nh), i / (nh - 1)], axis=1)


def test_cloth_mesh_layout_normals_tangents():
    m = shading.cloth_mesh(grid(4, 3), 4, 3)
    A, B, C, D = 0, 1, 4, 5
    assert m.triangles[:2].tolist() == [[A, C, B], [B, C, D]]
    assert m.triangles.shape == (2 * 3 * 2, 3) and m.triangles.dtype == np.int32
    np.testing.assert_allclose(m.uvs[6], [2 / 3, 1 / 2])
    np.testing.assert_allclose(m.normals, np.tile([0, 1, 0], (12, 1)), atol=1e-12)
    np.testing.assert_allclose(m.tangents, np.tile([1, 0, 0], (12, 1)), atol=1e-12)
    # area weighting: a bent grid, against the normalised sum of raw cross products
    rng = np.random.default_rng(0)
    p = grid(5, 5) + rng.normal(0, 0.05, (25, 3))
    m = shading.cloth_mesh(p, 5, 5)
    acc = np.zeros((25, 3))
    for a, b, c in m.triangles:
        acc[[a, b, c]] += np.cross(p[b] - p[a], p[c] - p[a])
    np.testing.assert_allclose(m.normals, acc / np.linalg.norm(acc, axis=1)[:, None], atol=1e-12)
    assert np.allclose(np.sum(m.normals * m.tangents, axis=1), 0, atol=1e-12)


def test_sphere_and_plane_meshes():
    s = shading.sphere_mesh((0.5, 0.2, 0.5), 0.2)
    d = s.positions - [0.5, 0.2, 0.5]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 0.92 * 0.2)
    radial = d / np.linalg.norm(d, axis=1)[:, None]
    assert np.min(np.sum(radial * s.normals, axis=1)) > 0.99  # outward, seam welded
    p = shading.plane_mesh((0, 0, 0), (0, 2, 0))
    np.testing.assert_allclose(p.normals, np.tile([0, 1, 0], (len(p.normals), 1)), atol=1e-12)
    assert np.abs(p.positions[:, [0, 2]]).max() == pytest.approx(2.0)
    np.testing.assert_allclose(p.colour, 0.7)


def test_frames_meshes_and_default_camera():
    scene = load_scene(ROOT / "scenes" / "sphere.json")
    model = build_model(scene)
    ms = scene_meshes(scene, model.initial_positions, model)
    assert [m.name for m in ms] == ["cloth", "sphere_0"]
    assert len(ms[0].edges) == int(np.sum(model.spring_enabled))
    cam = default_camera(scene, model.initial_positions, 100, 80)
    np.testing.assert_allclose(cam.target, (0.5, 0.5, 0.5), atol=1e-12)
    np.testing.assert_allclose(cam.eye, (0.5, 0.5, 2.3), atol=1e-12)
    assert (cam.vfov, cam.near, cam.far, cam.width, cam.height) == (35.0, 0.01, 100.0, 100, 80)


def test_new_collider_kinds_are_drawn_posed_and_kd_colours_the_cloth():
    """Box and mesh colliders get meshes (the box a hair inside its collision faces, so
    cloth resting on it shows), keyframed colliders are drawn at their pose at the frame's
    time, and render.k_d colours the cloth."""
    d = json.loads((ROOT / "scenes" / "sphere.json").read_text())
    d["render"] = {"k_d": [0.8, 0.2, 0.25]}
    d["box"] = {"center": [0, 0, 0], "half_extents": [0.5, 0.1, 0.2], "friction": 0.3,
                "rotation": [0, 90, 0]}
    d["mesh"] = {"path": str(ROOT / "scenes" / "meshes" / "torus.obj"), "friction": 0.3,
                 "translation": [1, 0, 0]}
    d["sphere"]["keyframes"] = [{"time": 0}, {"time": 2, "translation": [0, 1, 0]}]
    scene = load_scene(d)
    model = build_model(scene)
    at0 = scene_meshes(scene, model.initial_positions, model, 0.0)
    at1 = scene_meshes(scene, model.initial_positions, model, 1.0)
    assert [m.name for m in at0] == ["cloth", "sphere_0", "box_0", "mesh_0"]
    np.testing.assert_allclose(at0[0].colour, (0.8, 0.2, 0.25))
    box = at0[2].positions
    # turned 90 degrees about y: the 0.5 half extent lies along z, drawn 2 mm inside
    np.testing.assert_allclose(np.abs(box).max(axis=0), (0.198, 0.098, 0.498), atol=1e-12)
    torus = at0[3].positions
    np.testing.assert_allclose(torus.mean(axis=0), (1, 0, 0), atol=1e-6)
    np.testing.assert_allclose(at1[1].positions - at0[1].positions, np.tile([0, 0.5, 0],
                               (len(at0[1].positions), 1)), atol=1e-12)
    assert at1[2] is at0[2]  # static colliders: one shared mesh


def test_texture_errors_and_cache(tmp_path):
    missing = tmp_path / "nope.png"
    with pytest.raises(shading.TextureError, match="nope.png"):
        shading.load_texture(missing)
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    with pytest.raises(shading.TextureError, match="bad.png"):
        shading.load_texture(bad)
    cam = shading.Camera(width=8, height=8)
    with pytest.raises(shading.TextureError, match="nope.png"):
        shading.render([], cam, None, "texture", {"texture": missing})
    from shading.textures import packaged_textures_dir
    t = packaged_textures_dir() / "cloth.png"
    assert shading.load_texture(t) is shading.load_texture(t)
    assert shading.load_cubemap(packaged_textures_dir() / "cubemap").shape[0] == 6


def test_bilinear_texel_centres_and_wrap():
    from shading.textures import bilinear
    img = np.zeros((2, 4, 3))
    img[0, :, 0] = [0.0, 0.2, 0.4, 0.6]
    img[1, :, 0] = 1.0
    assert bilinear(img, 1.5 / 4, 0.5 / 2, True)[0] == pytest.approx(0.2)  # texel centre
    assert bilinear(img, 2.0 / 4, 0.5 / 2, True)[0] == pytest.approx(0.3)
    assert bilinear(img, 0.0, 0.5 / 2, True)[0] == pytest.approx(0.3)  # wraps 0.6 / 0.0
    assert bilinear(img, 0.5 / 4, 1.0, True)[0] == pytest.approx(0.5)  # rows 1 and 0


def test_assert_image_close(tmp_path, monkeypatch):
    a = np.zeros((10, 10, 3), np.uint8)
    b = a.copy()
    b[0, 0] = 200
    assert_image_close(a, a)
    with pytest.raises(AssertionError, match="PSNR .*diff image"):
        assert_image_close(b, a, diff_path=tmp_path / "d.png")
    assert (tmp_path / "d.png").exists()
    g = tmp_path / "g.png"
    monkeypatch.setenv("BLESS_GOLDENS", "1")
    assert_image_close(b, g)
    monkeypatch.delenv("BLESS_GOLDENS")
    assert_image_close(b, g)
    with pytest.raises(AssertionError):
        assert_image_close(a, g, diff_path=tmp_path / "d2.png")
