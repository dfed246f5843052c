"""Analytic checks of the rasteriser and shaders (SPEC 3-5), each against values
computed independently here."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

import shading
from shading import Camera, Mesh, Renderer, Shader
from shading.mesh import normals_tangents
from shading import shade


@njit(cache=True)
def _flat(p, n0, v, uv, t, kd, lp, li, prm, tex, hmap, cube, lit):
    return kd


FLAT = Shader("flat", _flat)  # made at run time: the uncached fragment stage


def quad(z=0.0, half=1.0, flip=False, colour=(1, 1, 1), nx=2, ny=2):
    """A square in the plane z, facing +z (or -z with flip), uv (0,0) at (-h, +h)."""
    u, v = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny))
    pos = np.stack([-half + 2 * half * u.ravel(), half - 2 * half * v.ravel(),
                    np.full(u.size, z)], axis=1)
    uvs = np.stack([u.ravel(), v.ravel()], axis=1)
    tris = []
    for i in range(ny - 1):
        for j in range(nx - 1):
            a = i * nx + j
            tri1, tri2 = (a, a + 1, a + nx), (a + 1, a + nx + 1, a + nx)
            tris += [tri1[::-1], tri2[::-1]] if flip else [tri1, tri2]
    tris = np.array(tris, np.int32)
    n, t = normals_tangents(pos, uvs, tris)
    return Mesh(pos, n, uvs, t, tris, colour)


def pixel_ray(cam: Camera, x, y):
    """World ray through the centre of pixel (x, y), computed from the camera basis."""
    eye, tgt = np.array(cam.eye), np.array(cam.target)
    f = (tgt - eye) / np.linalg.norm(tgt - eye)
    s = np.cross(f, cam.up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    th = math.tan(math.radians(cam.vfov) / 2)
    nx = (x + 0.5) / cam.width * 2 - 1
    ny = 1 - (y + 0.5) / cam.height * 2
    d = f + nx * th * cam.aspect * s + ny * th * u
    return eye, d / np.linalg.norm(d)


def hit_z_plane(cam, x, y, z=0.0):
    o, d = pixel_ray(cam, x, y)
    return o + d * (z - o[2]) / d[2]


def test_quad_centre_diffuse_and_blinn_phong_exact():
    cam = Camera((0.3, 0.2, 3.0), (0.3, 0.2, 0.0), width=65, height=65)
    lp, li = (0.5, 0.4, 2.0), (1.2, 1.0, 0.8)
    params = {"light_position": lp, "light_intensity": li}
    m = quad(colour=(0.9, 0.8, 0.7))
    p = hit_z_plane(cam, 32, 32)
    n = np.array([0.0, 0.0, 1.0])
    lv = np.array(lp) - p
    r2 = lv @ lv
    l = lv / np.sqrt(r2)
    v = np.array(cam.eye) - p
    v /= np.linalg.norm(v)
    h = (l + v) / np.linalg.norm(l + v)
    kd, I = np.array([0.9, 0.8, 0.7]), np.array(li)
    diffuse = kd * I / r2 * max(0, n @ l)
    phong = 0.1 + diffuse + 0.5 * I / r2 * max(0, n @ h) ** 100
    exp = {"diffuse": diffuse, "phong": phong}
    for sh in ("diffuse", "phong"):
        img = shading.render([m], cam, None, sh, params)
        want = np.floor(np.clip(exp[sh], 0, 1) * 255 + 0.5)
        np.testing.assert_allclose(img[32, 32], want, atol=1, err_msg=sh)
    # constants are overridable
    img = shading.render([m], cam, None, "phong", dict(params, k_a=0.0, k_s=0.0))
    np.testing.assert_allclose(img[32, 32], np.floor(diffuse * 255 + 0.5), atol=1)


def test_shared_edges_cover_every_pixel_exactly_once():
    rng = np.random.default_rng(1)
    nw, nh = 13, 9
    j, i = np.meshgrid(np.arange(nw), np.arange(nh))
    x, y = -1 + 2 * j / (nw - 1), -1 + 2 * i / (nh - 1)
    inner = (j > 0) & (j < nw - 1) & (i > 0) & (i < nh - 1)
    x = x + inner * rng.uniform(-0.06, 0.06, x.shape)
    y = y + inner * rng.uniform(-0.06, 0.06, y.shape)
    z = inner * rng.uniform(-0.2, 0.2, x.shape)
    pos = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    cloth = shading.cloth_mesh(pos, nw, nh)
    cam = Camera((0.05, -0.03, 4.0), (0.05, -0.03, 0.0), width=97, height=83)
    r = Renderer(97, 83)
    r.render([cloth], cam, None, "normal", count_coverage=True)
    count = r.count.reshape(83, 97)
    assert count.max() == 1
    # every pixel whose centre projects strictly inside the outline square is covered
    sx = cam.project(np.array([[-1, -1, 0], [1, 1, 0]]))
    x0, x1 = sorted(sx[:, 0])
    y0, y1 = sorted(sx[:, 1])
    xs = np.arange(97) + 0.5
    ys = np.arange(83) + 0.5
    inside = ((ys[:, None] > y0 + 0.5) & (ys[:, None] < y1 - 0.5)
              & (xs[None] > x0 + 0.5) & (xs[None] < x1 - 0.5))
    assert np.all(count[inside] == 1)
    outside = ((ys[:, None] < y0 - 0.5) | (ys[:, None] > y1 + 0.5)
               | (xs[None] < x0 - 0.5) | (xs[None] > x1 + 0.5))
    assert np.all(count[outside] == 0)


def test_top_left_rule_on_shared_edges():
    # vfov 90 and distance 1: world x = ndc x, so x = 0.3125 is the pixel centre 10.5
    cam = Camera((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), vfov=90.0, width=16, height=16)
    e = 0.3125  # a vertical and a horizontal shared edge through pixel centres

    def tri(pts, colour):
        pos = np.array(pts, float)
        t = np.array([[0, 1, 2]], np.int32)
        n, tg = normals_tangents(pos, np.zeros((3, 2)), t)
        return Mesh(pos, n, np.zeros((3, 2)), tg, t, colour)

    left = tri([(-0.9, -0.9, 0), (e, -0.9, 0), (e, 0.9, 0)], (1, 0, 0))
    right = tri([(e, -0.9, 0), (0.9, 0.0, 0), (e, 0.9, 0)], (0, 1, 0))
    r = Renderer(16, 16)
    img = r.render([left, right], cam, None, FLAT, count_coverage=True).copy()
    col = 10  # pixel column whose centre is on the shared edge
    rows = [y for y in range(16) if r.count.reshape(16, 16)[y, col]]
    assert rows and r.count.max() == 1
    assert all(tuple(img[y, col]) == (0, 255, 0) for y in rows)  # left edge of "right"
    # horizontal edge y = -e (window row centre 10.5): it belongs to the lower triangle
    top = tri([(-0.9, -e, 0), (0.9, -e, 0), (0.0, 0.9, 0)], (1, 0, 0))
    bot = tri([(-0.9, -e, 0), (0.0, -0.95, 0), (0.9, -e, 0)], (0, 0, 1))
    img = r.render([top, bot], cam, None, FLAT, count_coverage=True).copy()
    assert r.count.max() == 1
    assert tuple(img[10, 8]) == (0, 0, 255) and tuple(img[9, 8]) == (255, 0, 0)


def test_depth_test_keeps_nearer_regardless_of_order():
    cam = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), width=32, height=32)
    near, far = quad(z=0.5, half=0.5, colour=(0, 1, 0)), quad(z=-0.5, colour=(1, 0, 0))
    a = shading.render([near, far], cam, None, FLAT)
    b = shading.render([far, near], cam, None, FLAT)
    np.testing.assert_array_equal(a, b)
    assert tuple(a[16, 16]) == (0, 255, 0) and tuple(a[2, 16]) == (255, 0, 0)
    # equal depth: the object drawn first wins
    c = shading.render([quad(colour=(0, 0, 1)), quad(colour=(1, 0, 0))], cam, None, FLAT)
    assert tuple(c[16, 16]) == (0, 0, 255)


def test_perspective_correct_uv_at_steep_angle():
    cam = Camera((0.0, 0.3, 0.8), (0.0, 0.0, -3.0), width=64, height=48)
    m = quad(z=-1.0, half=1.0)  # its plane seen at a grazing angle
    m.positions[:, 2] = -1.0 - 2.0 * (m.positions[:, 1] + 1.0)  # tilt: z from -1 to -5
    r = Renderer(64, 48)
    r.render([m], cam, None, "normal")
    prim, bary = r.prim.reshape(48, 64), r.bary.reshape(48, 64, 2)
    p0, p1, p2 = m.positions[0], m.positions[1], m.positions[2]  # (u,v) = (0,0),(1,0),(0,1)
    nrm = np.cross(p1 - p0, p2 - p0)
    checked, err = 0, 0.0
    for y in range(48):
        for x in range(64):
            k = prim[y, x]
            if k < 0:
                continue
            o, d = pixel_ray(cam, x, y)
            hit = o + d * ((p0 - o) @ nrm) / (d @ nrm)
            u_ref = (hit[0] - p0[0]) / (p1[0] - p0[0])
            v_ref = (hit[1] - p0[1]) / (p2[1] - p0[1])
            tri = m.triangles[k]
            b1, b2 = bary[y, x]
            uv = (1 - b1 - b2) * m.uvs[tri[0]] + b1 * m.uvs[tri[1]] + b2 * m.uvs[tri[2]]
            # vertices are snapped to 1/256 pixel: a tiny, bounded error; screen-linear
            # (affine) interpolation would be off by more than 0.05 here
            err = max(err, abs(uv[0] - u_ref), abs(uv[1] - v_ref))
            checked += 1
    assert checked > 300
    assert err < 5e-4


def test_mirror_shows_face_behind_camera_with_orientation():
    S = 16
    cube = np.zeros((6, S, S, 3))
    for f in range(6):
        cube[f, :, :, 2] = f / 5.0
    g = (np.arange(S) + 0.5) / S
    cube[4, :, :, 0] = g[None, :]  # posz: red = s (columns)
    cube[4, :, :, 1] = g[:, None]  # green = t (rows, first row t = 0)
    cam = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), width=41, height=41)
    img = shading.render([quad(half=0.5)], cam, None, "mirror", {"cubemap": cube})
    assert img[20, 20, 2] == round(4 / 5 * 255)  # the +z face, behind the camera
    for (x, y) in [(20, 20), (27, 15), (14, 24)]:
        p = hit_z_plane(cam, x, y)
        v = np.array(cam.eye) - p
        v /= np.linalg.norm(v)
        w = 2 * v[2] * np.array([0, 0, 1.0]) - v
        s, t = (w[0] / w[2] + 1) / 2, (-w[1] / w[2] + 1) / 2
        assert abs(img[y, x, 0] - s * 255) <= 1 and abs(img[y, x, 1] - t * 255) <= 1
    # image right -> larger s, image up -> smaller t (the face seen unmirrored)
    assert img[20, 27, 0] > img[20, 20, 0] and img[15, 20, 1] < img[20, 20, 1]


def test_two_sided_shading():
    cam = Camera((0.2, 0.1, 3.0), (0.0, 0.0, 0.0), width=24, height=24)
    front = shading.render([quad()], cam, None, "normal")
    back = shading.render([quad(flip=True)], cam, None, "normal")
    np.testing.assert_array_equal(front, back)
    assert tuple(front[12, 12]) == (128, 128, 255)
    d1 = shading.render([quad()], cam, None, "diffuse")
    d2 = shading.render([quad(flip=True)], cam, None, "diffuse")
    np.testing.assert_array_equal(d1, d2)


def test_supersampling_box_filter():
    cam = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), width=20, height=20)
    big = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), width=60, height=60)
    m = quad(half=0.37, colour=(1, 1, 1))
    ss = shading.render([m], cam, None, FLAT, {"aa": 3, "background": (0, 0, 0)})
    ref = shading.render([m], big, None, FLAT, {"background": (0, 0, 0)}).astype(float)
    box = ref.reshape(20, 3, 20, 3, 3).mean(axis=(1, 3))
    assert np.abs(ss - np.floor(box + 0.5)).max() <= 1


def test_near_plane_clipping_and_background():
    cam = Camera((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), width=32, height=32)
    m = quad(half=0.3)
    m.positions[:, 2] = np.where(m.positions[:, 1] > 0, 1.0, -1.0)  # crosses the eye plane
    img = shading.render([m], cam, None, FLAT, {"background": (0, 0, 0)})
    assert img.shape == (32, 32, 3) and img.max() == 255
    empty = shading.render([], cam, None, "phong", {"background": (0.2, 0.25, 0.3)})
    assert tuple(empty[0, 0]) == (51, 64, 77)


def _scene_meshes():
    nw = nh = 20
    j = np.tile(np.arange(nw, dtype=float), nh)
    i = np.repeat(np.arange(nh, dtype=float), nw)
    pos = np.stack([j / (nw - 1), 1.0 + 0.1 * np.sin(j / 3.0) * np.cos(i / 4.0),
                    i / (nh - 1)], axis=1)
    return [shading.cloth_mesh(pos, nw, nh, edges=np.array([[0, 1], [1, 21], [5, 300]])),
            shading.sphere_mesh((0.5, 0.2, 0.5), 0.2)], pos


@pytest.mark.parametrize("aa", [1, 2])
def test_image_independent_of_thread_count(aa):
    meshes, pos = _scene_meshes()
    cam = Camera.default_for_cloth(pos, 1.0, 1.0, width=61, height=47)
    for sh in shading.SHADERS:
        imgs = []
        for threads in (1, 2, 3, 7):
            r = Renderer(61, 47, aa)
            r.threads = threads
            imgs.append(r.render(meshes, cam, None, sh).copy())
        for img in imgs[1:]:
            np.testing.assert_array_equal(img, imgs[0], err_msg=f"{sh} aa={aa}")


def test_reused_renderer_matches_fresh_one():
    """Buffers are cleared only where the previous frame wrote: a reused renderer must
    give exactly what a new one gives, whatever was drawn before (bigger or smaller
    objects, lines then triangles, coverage counting on and off)."""
    meshes, pos = _scene_meshes()
    cam = Camera.default_for_cloth(pos, 1.0, 1.0, width=50, height=40)
    near = Camera((0.5, 0.5, 1.2), (0.5, 0.5, 0.5), width=50, height=40)
    r = Renderer(50, 40, 2)
    sequence = [(meshes, near, "phong", False), (meshes[:1], cam, "normal", True),
                (meshes, cam, "wireframe", False), ([], cam, "phong", False),
                (meshes[1:], cam, "toon", True), (meshes, near, "wireframe", True),
                (meshes, cam, "diffuse", False)]
    for ms, c, sh, cnt in sequence:
        got = r.render(ms, c, None, sh, count_coverage=cnt).copy()
        want = Renderer(50, 40, 2).render(ms, c, None, sh)
        np.testing.assert_array_equal(got, want, err_msg=sh)


def test_one_fragment_stage_specialised_per_shader():
    """shade.fragment_stage serves every registered shader, compiled once per shader key
    (a literal: the shader's fragment inlined); a run-time shader gets a negative key and
    the uncached twin."""
    cam = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), width=32, height=32)
    near, far = quad(z=0.5, half=0.5, colour=(0, 1, 0)), quad(z=-0.5, colour=(1, 0, 0))
    a = shading.render([near, far], cam, None, FLAT)
    assert tuple(a[16, 16]) == (0, 255, 0) and tuple(a[2, 16]) == (255, 0, 0)
    assert FLAT.stage_key() < 0
    keys = {shading.REGISTRY[n].stage_key() for n in ("normal", "toon")}
    assert len(keys) == 2 and min(keys) >= 0
    for name in ("normal", "toon"):
        shading.render([near, far], cam, None, name)
    compiled = {sig[-2].literal_value for sig in shade.fragment_stage.signatures}
    assert keys <= compiled and FLAT.stage_key() not in compiled


def test_reuse_after_a_bigger_mesh_with_many_clipped_triangles():
    """Extra vertex slots made by clipping, in a renderer whose buffers were grown by a
    bigger mesh before (regression: the slots' weights must have room too)."""
    cam = Camera((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), width=40, height=30)
    r = Renderer(40, 30)
    big = quad(z=-3.0, half=1.0, nx=100, ny=100)
    r.render([big], cam, None, "normal")
    # ~3000 extra vertex slots: more than the old sizing gave their weights
    crossing = quad(z=0.0, half=0.2, nx=60, ny=60)  # most triangles cross the near plane
    rng = np.random.default_rng(3)
    crossing.positions[:, 2] = 0.49 + rng.uniform(-0.3, 0.3, len(crossing.positions))
    for sh in ("normal", "wireframe", "normal"):
        got = r.render([crossing], cam, None, sh).copy()
        want = Renderer(40, 30).render([crossing], cam, None, sh)
        np.testing.assert_array_equal(got, want, err_msg=sh)
        assert got.any()


@pytest.mark.parametrize("groups", [1, 3])
def test_depth_only_draw_gives_the_full_rasters_depths(monkeypatch, groups):
    """A shadow map's draw (raster_depth: each triangle set up and drawn at once) against
    the camera's pipeline (set up, binned, drawn) on the same triangles: the same depth at
    every sample and the same covered span per row. Other vertices (a plane's far corners
    behind the near plane) need clipping: the casters' own ranges decide, so the depth-only
    draw still runs."""
    from shading import raster as R
    from shading.visibility import VisibilityBuffer

    rng = np.random.default_rng(4)
    nw = nh = 30
    j = np.tile(np.arange(nw, dtype=float), nh)
    i = np.repeat(np.arange(nh, dtype=float), nw)
    casters = np.stack([j / (nw - 1) - 0.5 + rng.normal(0, 0.01, j.size),
                        0.2 * np.sin(3 * j / nw) * np.cos(5 * i / nh),
                        i / (nh - 1) - 0.5], axis=1)
    far = np.array([[-50.0, -1.0, -50.0], [50.0, -1.0, -50.0], [0.0, -1.0, 60.0]])
    va = np.zeros((casters.shape[0] + 3, 12))
    va[:casters.shape[0], :3] = casters
    va[casters.shape[0]:, :3] = far
    quads = np.array([(r * nw + c, r * nw + c + 1, (r + 1) * nw + c)
                      for r in range(nh - 1) for c in range(nw - 1)]
                     + [((r + 1) * nw + c, r * nw + c + 1, (r + 1) * nw + c + 1)
                        for r in range(nh - 1) for c in range(nw - 1)], np.int32)
    cam = Camera((0.3, 1.2, 0.4), (0.0, 0.0, 0.0), width=97, height=83)
    vp = cam.view_projection()
    runs = np.array([[0, casters.shape[0]]], np.int64)
    calls = []
    real = R.raster_depth
    monkeypatch.setattr(R, "raster_depth", lambda *a: calls.append(1) or real(*a))
    nv = va.shape[0]
    fast, full = VisibilityBuffer(97, 83), VisibilityBuffer(97, 83)
    fast.draw(va, nv, quads, quads.shape[0], vp, groups, depth_only=runs)
    assert calls, "the depth-only draw did not run"
    full.draw(va, nv, quads, quads.shape[0], vp, groups)
    np.testing.assert_array_equal(fast.depth, full.depth)
    np.testing.assert_array_equal(fast.rowlo, full.rowlo)
    np.testing.assert_array_equal(fast.rowhi, full.rowhi)
    assert np.isfinite(fast.depth).sum() > 2000
