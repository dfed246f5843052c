"""Frame assembly: scene + cloth positions -> meshes + camera -> image.

    meshes = scene_meshes(scene, positions, model)   # cloth, then colliders in scene order
    cam = default_camera(scene, model.initial_positions, 512, 512)
    img = render_frame(scene, positions, model)      # (H, W, 3) uint8, defaults from scene.render

`model` is the simulator's cloth model (pipeline.model.ClothModel): nw, nh, spring_a,
spring_b, spring_enabled, initial_positions. The cloth mesh's `edges` (drawn by the
wireframe shader) are the enabled springs. Mesh names: "cloth", "sphere_0", "plane_0", ...
(numbered per kind, in scene order).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

import shading
from shading import Camera

from .scene import CameraSettings, Plane, Scene, Sphere


def _edges(model) -> np.ndarray:
    en = np.asarray(model.spring_enabled, dtype=bool)
    a = np.asarray(model.spring_a, dtype=np.int32)[en]
    b = np.asarray(model.spring_b, dtype=np.int32)[en]
    return np.ascontiguousarray(np.stack([a, b], axis=1))


def _cached_edges(model) -> np.ndarray:
    # springs never change during a run: compute once per model object
    e = getattr(model, "_render_edges", None)
    if e is None:
        e = _edges(model)
        try:
            object.__setattr__(model, "_render_edges", e)
        except (AttributeError, TypeError):
            pass
    return e


@lru_cache(maxsize=64)
def _collider_mesh(kind: str, a: tuple, b, k: int):
    """The mesh of a static collider, built once (its arrays are read-only)."""
    m = shading.sphere_mesh(a, b) if kind == "sphere" else shading.plane_mesh(a, b)
    m.name = f"{kind}_{k}"
    for arr in (m.positions, m.normals, m.uvs, m.tangents, m.triangles, m.colour, m.edges):
        arr.flags.writeable = False
    return m


def _key(v):
    return tuple(float(x) for x in np.asarray(v, dtype=np.float64).ravel())


def scene_meshes(scene: Scene, positions, model) -> list:
    """[cloth, colliders in scene order] as shading.Mesh objects. Collider meshes do not
    change during a run: they are built once and shared between frames (read-only)."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    cloth = shading.cloth_mesh(pos, model.nw, model.nh, edges=_cached_edges(model))
    meshes = [cloth]
    counts = {}
    for c in scene.colliders:
        if isinstance(c, Sphere):
            kind, a, b = "sphere", _key(c.origin), float(c.radius)
        elif isinstance(c, Plane):
            kind, a, b = "plane", _key(c.point), _key(c.normal)
        else:  # a collider kind the renderer does not know how to draw
            continue
        k = counts.get(kind, 0)
        counts[kind] = k + 1
        meshes.append(_collider_mesh(kind, a, b, k))
    return meshes


def default_camera(scene: Scene, initial_positions, width: int, height: int) -> Camera:
    """The scene's camera, or the SPEC 4 default from the initial cloth positions."""
    cs: CameraSettings | None = scene.camera
    if cs is not None:
        return Camera(tuple(cs.position), tuple(cs.target), tuple(cs.up), float(cs.vfov),
                      width=width, height=height)
    return Camera.default_for_cloth(initial_positions, scene.cloth.width, scene.cloth.height,
                                    width=width, height=height)


def render_params(scene: Scene, aa: int | None = None) -> dict:
    """Renderer params from scene.render: shader constants, background, textures, aa."""
    rs = scene.render
    p = dict(rs.params)
    p["background"] = tuple(rs.background)
    p["aa"] = int(aa if aa is not None else rs.aa)
    for key in ("texture", "height_map", "cubemap"):
        v = getattr(rs, key)
        if v is not None:
            p[key] = v
    return p


def render_frame(scene: Scene, positions, model, shader: str | None = None,
                 width: int | None = None, height: int | None = None,
                 aa: int | None = None) -> np.ndarray:
    """One frame as a new (H, W, 3) uint8 array; None arguments default to scene.render."""
    rs = scene.render
    w = int(width if width is not None else rs.width)
    h = int(height if height is not None else rs.height)
    cam = default_camera(scene, model.initial_positions, w, h)
    meshes = scene_meshes(scene, positions, model)
    return shading.render(meshes, cam, scene.light, shader or rs.shader,
                          render_params(scene, aa))
