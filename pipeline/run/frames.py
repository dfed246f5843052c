"""Frame assembly: scene + cloth positions -> meshes + camera -> image.

    meshes = scene_meshes(scene, positions, model, time)  # cloth, then colliders in scene order
    cam = default_camera(scene, model.initial_positions, 512, 512, shot)
    img = render_frame(scene, positions, model, time=t, shot=shot)  # (H, W, 3) uint8

`shot` (pipeline.view.framing.Framing) frames the whole shot for a scene with no `camera`;
without it such a scene is drawn with the course camera (a frame on its own).

`model` is the simulator's cloth model (pipeline.physics.model.ClothModel): nw, nh, spring_a,
spring_b, spring_enabled, initial_positions. The cloth mesh's `edges` (drawn by the
wireframe shader) are the enabled springs. Mesh names: "cloth", "sphere_0", "plane_0",
"box_0", "mesh_0", ... (numbered per kind, in scene order). `time` (seconds) places
keyframed colliders.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

import shading
from pipeline.physics.colliders import collider_pose, euler_matrix
from pipeline.physics.colliders.mesh import collider_mesh_arrays
from pipeline.scene import Box, MeshCollider, Plane, Scene, Sphere
from pipeline.view.framing import Framing, default_camera


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


def cloth_seams(model):
    """shading.Seams of a mesh cloth's model, built once per model object."""
    seams = getattr(model, "_render_seams", None)
    if seams is None:
        topo = model.mesh.topology
        seams = shading.cloth_seams(topo.triangles, topo.corner_uv, _cached_edges(model))
        object.__setattr__(model, "_render_seams", seams)
    return seams


BOX_INSET = 2e-3  # metres: a box is drawn this much smaller on every side
_KIND_NAMES = {Sphere: "sphere", Plane: "plane", Box: "box", MeshCollider: "mesh"}


@lru_cache(maxsize=64)
def _collider_mesh(collider, k: int):
    """The mesh of a collider in its rest pose, built once (its arrays are read-only)."""
    c = collider
    if isinstance(c, Sphere):
        m = shading.sphere_mesh(c.origin, c.radius)
    elif isinstance(c, Plane):
        m = shading.plane_mesh(c.point, c.normal)
    elif isinstance(c, Box):  # drawn a little inside, so cloth resting on it shows
        inset = np.maximum(np.asarray(c.half_extents) - BOX_INSET, 0.5 * np.asarray(c.half_extents))
        m = shading.box_mesh(c.center, inset, euler_matrix(c.rotation))
    else:
        m = shading.triangle_mesh(*collider_mesh_arrays(c))
    m.name = f"{_KIND_NAMES[type(c)]}_{k}"
    if c.color is not None:
        m.colour = np.array(c.color, dtype=np.float64)
    m.shader = c.shader
    for arr in (m.positions, m.normals, m.uvs, m.tangents, m.triangles, m.colour, m.edges):
        arr.flags.writeable = False
    return m


def _posed(mesh, collider, time: float):
    """The rest-pose mesh moved to the collider's keyframed pose at `time`."""
    rot, shift = collider_pose(collider, time)
    pivot = np.asarray(collider.pivot, dtype=np.float64)
    return shading.Mesh((mesh.positions - pivot) @ rot.T + pivot + shift, mesh.normals @ rot.T,
                        mesh.uvs, mesh.tangents @ rot.T, mesh.triangles, mesh.colour,
                        mesh.edges, mesh.name, mesh.shader)


def scene_meshes(scene: Scene, positions, model, time: float = 0.0) -> list:
    """[cloth, colliders in scene order] as shading.Mesh objects, keyframed colliders at
    their pose at `time`; the cloth takes the scene's `render.k_d` colour if it gives one. Static collider meshes are built once and shared between frames
    (read-only)."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    colour = scene.render.params.get("k_d", shading.mesh.CLOTH_COLOUR)  # the cloth's k_d
    if model.mesh is not None:
        cloth = shading.seamed_cloth_mesh(pos, cloth_seams(model), colour=colour)
    else:
        cloth = shading.cloth_mesh(pos, model.nw, model.nh, edges=_cached_edges(model),
                                   colour=colour)
    meshes = [cloth]
    counts: dict[type, int] = {}
    for c in scene.colliders:
        k = counts.get(type(c), 0)
        counts[type(c)] = k + 1
        mesh = _collider_mesh(c, k)
        meshes.append(_posed(mesh, c, time) if c.keyframes else mesh)
    return meshes


def render_params(scene: Scene, aa: int | None = None) -> dict:
    """Renderer params from scene.render: shader constants, background, textures, aa,
    shadows and ambient occlusion."""
    rs = scene.render
    p = dict(rs.params)
    p["background"] = tuple(rs.background)
    p["shadows"] = rs.shadows
    p["ambient_occlusion"] = rs.ambient_occlusion
    p["aa"] = int(aa if aa is not None else rs.aa)
    for key in ("texture", "height_map", "cubemap"):
        v = getattr(rs, key)
        if v is not None:
            p[key] = v
    return p


def render_frame(scene: Scene, positions, model, shader: str | None = None,
                 width: int | None = None, height: int | None = None,
                 aa: int | None = None, time: float = 0.0,
                 shot: Framing | None = None) -> np.ndarray:
    """One frame as a new (H, W, 3) uint8 array; None arguments default to scene.render;
    `time` (s) places keyframed colliders; `shot` frames a scene with no camera
    (default_camera)."""
    rs = scene.render
    w = int(width if width is not None else rs.width)
    h = int(height if height is not None else rs.height)
    cam = default_camera(scene, model.initial_positions, w, h, shot)
    meshes = scene_meshes(scene, positions, model, time)
    return shading.render(meshes, cam, scene.light, shader or rs.shader,
                          render_params(scene, aa))
