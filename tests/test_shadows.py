"""Shadows and ambient occlusion: the renderer's light visibility against an independent
ray caster (tests/shadow_reference.py) and against closed forms.

The checker is validated first on its own (camera rays, exact culling, a sphere's hard
shadow disc and an area light's penumbra against the closed forms); then the renderer's
`light_visibility()` on a random scene (hard shadows), the soft shadow disc, acne on a
flat cloth, a contact shadow, shadows off, and the occlusion factor of a resting sphere.
"""
from __future__ import annotations

import math
import types
from pathlib import Path

import numpy as np
import pytest

import shading
from pipeline.physics.model import build_model
from pipeline.run.frames import render_frame, render_params, scene_meshes
from pipeline.scene import load_scene
from pipeline.view.framing import default_camera
from shading import Camera
from shading.renderer import Renderer
from shading.testing import assert_image_close

import shadow_reference as ref

ROOT = Path(__file__).resolve().parent.parent

# sphere over the plane y = 0, light straight above it (the closed-form disc)
LIGHT_H, SPHERE_H, SPHERE_R = 1.5, 0.75, 0.1
DISC_R = LIGHT_H * math.tan(math.asin(SPHERE_R / (LIGHT_H - SPHERE_H)))
SOFT_RADIUS = 0.05


def light(position, radius=None):
    """A light as the renderer takes it; radius None leaves the attribute out (default)."""
    li = types.SimpleNamespace(position=tuple(float(x) for x in position),
                               intensity=(3.0, 3.0, 3.0))
    if radius is not None:
        li.radius = float(radius)
    return li


def render_visibility(meshes, camera: Camera, lt) -> tuple[np.ndarray, np.ndarray]:
    """(vis, prim), each (H, W), of a diffuse render with shadows (aa = 1)."""
    r = Renderer(camera.width, camera.height)
    r.render(meshes, camera, lt, "diffuse", {"shadows": True})
    shape = (camera.height, camera.width)
    return (r.light_visibility().reshape(shape).copy(),
            r.prim.reshape(shape).copy())


def disc_scene() -> tuple[list, Camera]:
    """Plane, sphere (drawn at its full radius) below the light; a camera straight above,
    higher than the light, off the axis, with a narrow field: plane pixels map linearly
    to the plane and the whole shadow edge shows beside the sphere."""
    meshes = [shading.plane_mesh((0, 0, 0), (0, 1, 0)),
              shading.sphere_mesh((0, SPHERE_H, 0), SPHERE_R, scale=1.0)]
    eye, size = 4.0, 64
    cam = Camera((0.031, eye, -0.047), (0.031, 0.0, -0.047), (0, 0, -1),
                 vfov=2 * math.degrees(math.atan(0.4 / eye)), width=size, height=size)
    return meshes, cam


def pixels_per_metre(cam: Camera) -> float:
    """Scale of the top-down camera on the plane y = 0 (image x is world x)."""
    p = cam.project([[0, 0, 0], [1, 0, 0]])
    return float(p[1, 0] - p[0, 0])


# --- the checker on its own ---------------------------------------------------------

def test_reference_camera_rays_hit_their_pixel_centres():
    cam = Camera((0.3, 1.6, 2.2), (0.0, 0.2, 0.0), width=40, height=30)
    o, d = ref.camera_rays(cam)
    x, y = np.meshgrid(np.arange(40) + 0.5, np.arange(30) + 0.5)
    for t in (0.5, 3.0):
        w = cam.project(o + t * d)
        np.testing.assert_allclose(w[:, 0], x.ravel(), atol=1e-9)
        np.testing.assert_allclose(w[:, 1], y.ravel(), atol=1e-9)
    assert np.all(cam.project(o + d)[:, 2] > cam.project(o)[:, 2])  # away from the eye


def test_reference_culling_gives_brute_force_hits(monkeypatch):
    rng = np.random.default_rng(3)
    tris = rng.uniform(-1, 1, (300, 1, 3)) + rng.normal(0, 0.2, (300, 3, 3))
    o = rng.uniform(-2, 2, (500, 3))
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    skip = rng.integers(0, 300, 500)
    culled = ref.first_hits(o, d, tris, t_max=np.full(500, 2.5), skip=skip)
    monkeypatch.setattr(ref, "CLUSTER", len(tris))  # one cluster: every triangle tested
    brute = ref.first_hits(o, d, tris, t_max=np.full(500, 2.5), skip=skip)
    assert np.sum(brute[1] >= 0) > 50
    np.testing.assert_array_equal(culled[1], brute[1])
    np.testing.assert_array_equal(culled[0], brute[0])
    assert np.all(culled[1] != skip)


def test_reference_sphere_disc_matches_closed_form():
    meshes, cam = disc_scene()
    hits = ref.trace_camera(meshes, cam)
    cls = ref.shadow_classes(meshes, cam, (0, LIGHT_H, 0), hits).ravel()
    plane = (hits.tri >= 0) & (hits.tri < len(meshes[0].triangles))
    r = np.hypot(hits.points[:, 0], hits.points[:, 2])
    px = 1.0 / pixels_per_metre(cam)
    shadowed, lit = r[plane & (cls == ref.SHADOWED)], r[plane & (cls == ref.LIT)]
    assert np.all(cls[plane] != ref.FACES_AWAY)
    # pixel centres are classified exactly, up to the sphere's tessellation (< 0.1 px)
    assert shadowed.max() < DISC_R + 0.1 * px and lit.min() > DISC_R - 0.1 * px
    assert shadowed.max() > DISC_R - px and lit.min() < DISC_R + px  # the edge is seen
    assert np.sum(shadowed > DISC_R - 3 * px) > 50


def disc_penumbra() -> float:
    """The closed-form penumbra width w on the plane (metres): w = 2 radius (d_r - d_b) / d_b,
    d_b the depth of the sphere's silhouette seen from the light, d_r the plane's."""
    dist = LIGHT_H - SPHERE_H
    d_b = dist - SPHERE_R ** 2 / dist
    return 2 * SOFT_RADIUS * (LIGHT_H - d_b) / d_b


def test_reference_area_light_penumbra_matches_closed_form():
    meshes, _ = disc_scene()
    w = disc_penumbra()

    def vis(f):
        return ref.area_light_visibility((DISC_R + f * w / 2, 0, 0), meshes, (0, LIGHT_H, 0),
                                         SOFT_RADIUS)

    # the physical penumbra spans R -+ w/2, half lit at R
    assert vis(-1.05) == 0.0 and vis(1.05) == 1.0
    assert 0.0 < vis(-0.9) < 0.1 and 0.9 < vis(0.9) < 1.0
    assert vis(0.0) == pytest.approx(0.5, abs=0.06)


# --- the renderer against the checker -------------------------------------------------

def crumpled_cloth(rng, centre, size, n=12) -> shading.Mesh:
    """An n x n cloth of side `size` around `centre`, crumpled by smooth noise."""
    a = np.linspace(-size / 2, size / 2, n)
    x, z = np.meshgrid(a, a)
    y = (0.06 * np.sin(7 * x + rng.uniform(0, 6)) * np.cos(5 * z + rng.uniform(0, 6))
         + rng.normal(0, 0.01, x.shape))
    pos = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1) + centre
    return shading.cloth_mesh(pos, n, n)


def random_scene(seed: int) -> tuple[list, Camera, tuple]:
    """A plane, two spheres and two turned boxes around a crumpled cloth that hangs above
    them (each at a jittered place on a ring, so each is seen); a light above."""
    rng = np.random.default_rng(seed)
    meshes = [shading.plane_mesh((0, 0, 0), (0, 1, 0))]
    ring = rng.uniform(0, 2 * np.pi) + np.arange(4) * np.pi / 2 + rng.uniform(-0.3, 0.3, 4)
    spots = 0.45 * np.stack([np.cos(ring), np.sin(ring)], axis=1)
    for x, z in spots[:2]:
        rad = rng.uniform(0.1, 0.18)
        meshes.append(shading.sphere_mesh((x, rng.uniform(rad, 0.4), z), rad, segments=24))
    for x, z in spots[2:]:
        h = rng.uniform(0.06, 0.14, 3)
        ang = rng.uniform(0, np.pi)
        rot = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
        meshes.append(shading.box_mesh((x, rng.uniform(h[1], 0.3), z), h, rot))
    meshes.append(crumpled_cloth(rng, (rng.uniform(-0.1, 0.1), 0.55, rng.uniform(-0.1, 0.1)),
                                 0.4))
    lp = (rng.uniform(-0.5, 0.5), rng.uniform(1.6, 2.2), rng.uniform(-0.5, 0.5))
    cam = Camera((0.35, 1.5, 1.75), (0.0, 0.15, 0.0), width=160, height=120)
    return meshes, cam, lp


@pytest.mark.parametrize("among", [False, True])
def test_hard_shadows_agree_with_ray_casting(among):
    """The light above the scene (one view fitted to the casters) and among them, under the
    hanging cloth (a cube of six views)."""
    meshes, cam, lp = random_scene(11)
    if among:
        lp = (0.0, 0.45, 0.0)
    assert sum(len(m.triangles) for m in meshes) <= 3000
    hits = ref.trace_camera(meshes, cam)
    cls = ref.shadow_classes(meshes, cam, lp, hits)
    r = Renderer(cam.width, cam.height)
    r.render(meshes, cam, light(lp, 0.0), "diffuse", {"shadows": True})
    assert r.shadow_map.views.shape[0] == (6 if among else 1)
    vis = r.light_visibility().reshape(cam.height, cam.width)
    prim = r.prim.reshape(cam.height, cam.width)
    assert np.mean(prim.ravel() == hits.tri) > 0.999  # same pixels, same triangle ids
    # where the interpolated normal (as the shader turns it) faces away from the light,
    # the renderer's visibility is unspecified: a class of its own, so its border is
    # skipped too
    n = ref.smooth_normals(meshes, hits)
    o, _ = ref.camera_rays(cam)
    n *= np.where(np.einsum("rj,rj->r", n, o - hits.points) < 0, -1.0, 1.0)[:, None]
    away = (hits.tri >= 0) & (np.einsum("rj,rj->r", n, np.asarray(lp) - hits.points) <= 0)
    cls = np.where(away.reshape(cls.shape), ref.FACES_AWAY + 1, cls)
    pad = np.pad(cls, 1, constant_values=-9)  # the image border is an edge too
    h, w = cls.shape
    uniform = np.ones(cls.shape, bool)
    for dy in range(3):
        for dx in range(3):
            uniform &= pad[dy:dy + h, dx:dx + w] == cls
    checked = (uniform & ((cls == ref.SHADOWED) | (cls == ref.LIT))
               & (prim == hits.tri.reshape(h, w)))
    agree = (vis[checked] > 0.5) == (cls[checked] == ref.LIT)
    print(f"hard shadows: {agree.mean():.4%} of {checked.sum()} pixels agree "
          f"({np.sum(cls[checked] == ref.SHADOWED)} shadowed)")
    assert checked.sum() > 8000 and np.sum(cls[checked] == ref.SHADOWED) > 500
    assert agree.mean() >= 0.99


@pytest.mark.parametrize("size", [(157, 118), (1003, 1001)])
def test_every_covered_sample_gets_its_visibility(size):
    """Images whose sides are not multiples of the look-ups' cells (4 samples a side, 8 from
    shadow.LARGE_FRAME samples on): every covered sample is written, the same values again
    over a buffer of NaN."""
    meshes, _, lp = random_scene(11)
    cam = Camera((0.35, 1.5, 1.75), (0.0, 0.15, 0.0), width=size[0], height=size[1])
    r = Renderer(cam.width, cam.height)
    r.render(meshes, cam, light(lp), "diffuse", {"shadows": True})
    first = r.light_visibility()
    r.vis[:] = np.nan
    r.render(meshes, cam, light(lp), "diffuse", {"shadows": True})
    covered = r.prim >= 0
    assert np.all(np.isfinite(first[covered]))
    np.testing.assert_array_equal(r.light_visibility()[covered], first[covered])


def crossing(s: np.ndarray, v: np.ndarray, level: float) -> float:
    """Where v (rising with s, sorted by s) last crosses `level`, linearly interpolated."""
    k = np.nonzero(v < level)[0][-1]
    return float(s[k] + (level - v[k]) * (s[k + 1] - s[k]) / (v[k + 1] - v[k]))


def test_soft_shadow_disc_matches_closed_form():
    meshes, cam = disc_scene()
    vis, prim = render_visibility(meshes, cam, light((0, LIGHT_H, 0), SOFT_RADIUS))
    k = pixels_per_metre(cam)
    cx, cy = cam.project([[0, 0, 0]])[0, :2]  # below the sphere's centre, along the light
    w = disc_penumbra()  # a box filter over it: a linear ramp, 10 to 90 % over 0.8 w
    plane = (prim >= 0) & (prim < len(meshes[0].triangles))
    row, col = int(cy), int(cx)
    centres = np.arange(cam.width) + 0.5
    profiles = {  # (offset along the line from the centre, across it, vis), outwards
        "right": (centres - cx, row + 0.5 - cy, vis[row], plane[row]),
        "left": (cx - centres, row + 0.5 - cy, vis[row], plane[row]),
        "down": (centres - cy, col + 0.5 - cx, vis[:, col], plane[:, col]),
        "up": (cy - centres, col + 0.5 - cx, vis[:, col], plane[:, col]),
    }
    r50 = {}
    for name, (s, off, v, ok) in profiles.items():
        sel = ok & (s > 0)
        order = np.argsort(s[sel])
        radial = np.hypot(s[sel][order], off)
        prof = v[sel][order]
        assert prof[0] < 0.1 and prof[-1] > 0.9, f"{name}: the penumbra is not all seen"
        r10, r50[name], r90 = (crossing(radial, prof, lv) for lv in (0.1, 0.5, 0.9))
        print(f"{name}: r50 {r50[name]:.2f} px (R {DISC_R * k:.2f}), 10-90 % "
              f"{r90 - r10:.2f} px (0.8 w {0.8 * w * k:.2f})")
        assert abs(r50[name] - DISC_R * k) <= 1.0, name
        assert abs((r90 - r10) - 0.8 * w * k) <= 1.0, name
    assert 0.8 * w * k > 4  # the penumbra spans several pixels
    assert abs(r50["right"] - r50["left"]) / 2 <= 1.0  # centre, x
    assert abs(r50["down"] - r50["up"]) / 2 <= 1.0  # centre, y


def flat_cloth(n=16) -> shading.Mesh:
    a = np.linspace(-0.5, 0.5, n)
    x, z = np.meshgrid(a, a)
    return shading.cloth_mesh(np.stack([x.ravel(), np.full(x.size, 0.3), z.ravel()], 1), n, n)


@pytest.mark.parametrize("radius", [None, 0.0])
@pytest.mark.parametrize("angle", [0.0, 75.0])
def test_no_acne_on_a_flat_cloth(radius, angle):
    cloth = flat_cloth()
    a = math.radians(angle)
    lp = (2.0 * math.sin(a) + 0.05, 0.3 + 2.0 * math.cos(a), 0.03)  # angle from the normal
    cam = Camera((0.2, 1.5, 1.4), (0.0, 0.3, 0.0), width=96, height=72)
    vis, prim = render_visibility([cloth], cam, light(lp, radius))
    covered = prim >= 0
    assert covered.sum() > 2000
    assert np.all(vis[covered] == 1.0), f"{np.sum(vis[covered] < 1)} pixels of acne"


def fold_scene() -> tuple[list, Camera, tuple, float, float]:
    """A box on the floor with a cloth bent 90 degrees over its top +x edge (horizontal
    part on the top, vertical part hanging down the +x side to the floor, both GAP off the
    box), lit at 45 degrees from the -x side. In front of the box the floor is shadowed
    from the cloth's foot (x = fold_x) to the shadow of the fold line (x = x_shadow);
    returns (meshes, camera, light position, fold_x, x_shadow)."""
    gap, half = 0.002, (0.3, 0.25, 0.3)
    fold_x, fold_y = half[0] + gap, 2 * half[1] + gap
    # arc length from the fold line (a grid column): -0.3 on the top, 0.5 down the side
    a = np.concatenate([np.linspace(-0.3, 0.0, 7), np.linspace(0.0, fold_y - gap, 11)[1:]])
    A, Z = np.meshgrid(a, np.linspace(-0.35, 0.35, 8))
    pos = np.stack([np.where(A < 0, fold_x + A, fold_x), np.where(A < 0, fold_y, fold_y - A), Z],
                   axis=-1).reshape(-1, 3)
    cloth = shading.cloth_mesh(pos, len(a), 8)
    box = shading.box_mesh((0, half[1], 0), half, np.eye(3))
    lp = (fold_x - 1.5, fold_y + 1.5, 0.0)
    s = lp[1] / (lp[1] - fold_y)  # the light's ray through the fold line meets the floor
    cam = Camera((2.0, 1.3, 0.3), (0.6, 0.0, 0.0), width=120, height=90)
    return ([shading.plane_mesh((0, 0, 0), (0, 1, 0)), box, cloth], cam, lp, fold_x,
            lp[0] + s * (fold_x - lp[0]))


def test_contact_shadow_starts_at_the_fold_line():
    meshes, cam, lp, fold_x, x_shadow = fold_scene()
    hits = ref.trace_camera(meshes, cam)
    cls = ref.shadow_classes(meshes, cam, lp, hits)
    vis, prim = render_visibility(meshes, cam, light(lp, 0.0))
    h, w = cls.shape
    p = hits.points.reshape(h, w, 3)
    # floor in front of the cloth's foot, |z| < 0.3: away from the shadow's sides (at
    # |z| >= 0.35), so its only edge is the fold line's shadow x = x_shadow
    checked = ((prim >= 0) & (prim < len(meshes[0].triangles)) & (prim == hits.tri.reshape(h, w))
               & (p[..., 0] > fold_x) & (np.abs(p[..., 2]) < 0.3))
    line = cam.project(np.stack([np.full(400, x_shadow), np.zeros(400),
                                 np.linspace(-0.6, 0.6, 400)], axis=1))
    order = np.argsort(line[:, 0])
    y_line = np.interp(np.arange(w) + 0.5, line[order, 0], line[order, 1])
    dist = (np.arange(h)[:, None] + 0.5 - y_line[None])[checked]  # rows; < 0: in shadow
    assert np.sum(dist < -10) > 500 and np.sum(dist > 10) > 500  # both sides are seen
    assert np.sum(checked & (p[..., 0] < fold_x + 0.02)) > 30  # and the foot
    # the checker is exact on pixel centres; the renderer may be off by a pixel at the
    # edge, but leaves no lit floor between the foot and the fold line's shadow
    exact = np.abs(dist) > 0.05
    np.testing.assert_array_equal((cls[checked] == ref.SHADOWED)[exact], dist[exact] < 0)
    far = np.abs(dist) > 1.0
    wrong = (vis[checked] < 0.5)[far] != (dist[far] < 0)
    print(f"contact: {wrong.sum()} of {far.sum()} floor pixels off "
          f"({np.sum(wrong & (dist[far] < 0))} lit in the shadow)")
    assert not wrong.any()


def test_shadows_off_is_the_old_image():
    scene = load_scene(ROOT / "scenes" / "sphere.json", ["camera=course"])
    model = build_model(scene)
    pos = model.initial_positions
    cam = default_camera(scene, pos, 256, 256, None)
    meshes = scene_meshes(scene, pos, model)
    params = dict(render_params(scene, 1), shadows=False)
    off = shading.render(meshes, cam, scene.light, "diffuse", params)
    default = render_frame(scene, pos, model, shader="diffuse", width=256, height=256, aa=1)
    assert off.tobytes() == default.tobytes()
    assert_image_close(off, ROOT / "tests" / "golden" / "sphere_f0_diffuse.png")
    # and on a scene of this file, where shadows on would change it
    meshes, cam, lp = random_scene(11)
    r = Renderer(cam.width, cam.height)
    a = r.render(meshes, cam, light(lp, 0.0), "diffuse").copy()
    b = r.render(meshes, cam, light(lp, 0.0), "diffuse", {"shadows": False}).copy()
    c = r.render(meshes, cam, light(lp, 0.0), "diffuse", {"shadows": True}).copy()
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_looks_independent_of_thread_count():
    """Shadows, occlusion and both: the same image on 1, 2, 3 and 7 threads (with both,
    the occlusion runs on one thread beside the shadow map drawn on the others; the map's
    bands are shared out among those); the map and the occlusion are not trivial."""
    meshes, cam, lp = random_scene(5)
    for look in ({"shadows": True}, {"ambient_occlusion": True},
                 {"shadows": True, "ambient_occlusion": True}):
        imgs = []
        for threads in (1, 2, 3, 7):
            r = Renderer(cam.width, cam.height, 2)
            r.threads = threads
            imgs.append(r.render(meshes, cam, light(lp), "phong", look).copy())
        for img in imgs[1:]:
            np.testing.assert_array_equal(img, imgs[0], err_msg=str(look))
        if "shadows" in look:
            vis = r.light_visibility()[r.prim >= 0]
            assert (vis == 0).mean() > 0.05 and (vis == 1).mean() > 0.3
            assert np.isfinite(r.shadow_map.depth).sum() > 20000
        if "ambient_occlusion" in look:
            assert (r.occlusion < 0.9).mean() > 0.01


def test_renderers_on_several_threads_at_once():
    """Renderers with both looks on 3 threads each, drawing at once from 3 threads (their
    shadow maps beside their occlusion, each map on the shared pool): every image that of
    the same render alone."""
    import threading

    meshes, cam, lp = random_scene(5)
    look = {"shadows": True, "ambient_occlusion": True}
    alone = Renderer(cam.width, cam.height)
    alone.threads = 1
    want = alone.render(meshes, cam, light(lp), "phong", look).copy()
    got, errors = [], []

    def draw():
        try:
            r = Renderer(cam.width, cam.height)
            r.threads = 3
            for _ in range(4):
                got.append(r.render(meshes, cam, light(lp), "phong", look).copy())
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=draw, daemon=True) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not any(t.is_alive() for t in threads), "the renderers held each other up"
    assert not errors, errors
    assert len(got) == 12
    for img in got:
        np.testing.assert_array_equal(img, want)


@pytest.mark.parametrize("size", [(160, 120), (800, 750)])
def test_ambient_occlusion_darkens_contact_only_and_scales_the_ambient_term(size):
    """A sphere resting on a plane: the occlusion factor is 1 on the open plane far from
    the sphere and below 1 at the contact ring; with the light off (I = 0) and no
    specular, each pixel is exactly k_a I_a times its factor (the ambient term alone).
    Cells of 4 and of 6 pixels (occlusion.cell_step)."""
    rho = 0.2
    meshes = [shading.sphere_mesh((0.0, rho, 0.0), rho, scale=1.0),
              shading.plane_mesh((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))]
    cam = Camera(eye=(0.0, 1.2, 1.6), target=(0.0, 0.1, 0.0), width=size[0], height=size[1])
    r = Renderer(cam.width, cam.height)
    dark = types.SimpleNamespace(position=(0.0, 2.0, 0.0), intensity=(0.0, 0.0, 0.0))
    img = r.render(meshes, cam, dark, "phong", {"ambient_occlusion": True, "k_s": 0.0,
                                                  "background": (0.0, 0.0, 0.0)})
    occ = r.occlusion.reshape(cam.height, cam.width)
    expected = np.floor(255.0 * 0.1 * occ.astype(np.float64) + 0.5)
    covered = r.prim.reshape(cam.height, cam.width) >= 0
    np.testing.assert_array_equal(img[..., 0][covered], expected[covered])
    # the contact ring (a point just outside the sphere's foot) and the open plane
    (cx, cy), = cam.project([[0.0, 0.0, rho * 0.6]])[:, :2].astype(int)
    (fx, fy), = cam.project([[0.45, 0.0, 0.5]])[:, :2].astype(int)
    assert occ[cy, cx] < 0.9, occ[cy, cx]
    assert occ[fy, fx] == 1.0


def test_a_mesh_with_its_own_shader_is_drawn_by_it():
    """Meshes of two shaders in one frame (aa = 1): every pixel of the cloth drawn with
    its own shader (toon) is that of a toon frame, every other pixel that of a phong
    frame; with shadows too (the cloth's shadow falls on the phong meshes)."""
    meshes, cam, lp = random_scene(3)
    for look in ({}, {"shadows": True}):
        r = Renderer(cam.width, cam.height)
        plain = [r.render(meshes, cam, light(lp), s, look).copy() for s in ("phong", "toon")]
        own = meshes[-1]
        mixed_meshes = meshes[:-1] + [shading.Mesh(own.positions, own.normals, own.uvs,
                                                   own.tangents, own.triangles, own.colour,
                                                   own.edges, own.name, shader="toon")]
        mixed = r.render(mixed_meshes, cam, light(lp), "phong", look)
        obj = np.full(cam.width * cam.height, -1)
        hit = r.prim >= 0
        first = sum(len(m.triangles) for m in meshes[:-1])
        obj[hit] = np.where(r.prim[hit] >= first, 1, 0)
        toon = (obj == 1).reshape(cam.height, cam.width)
        assert toon.any() and (~toon).any()
        np.testing.assert_array_equal(mixed[toon], plain[1][toon])
        np.testing.assert_array_equal(mixed[~toon], plain[0][~toon])
