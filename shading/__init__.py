"""shading: meshes, camera, a numba software rasteriser and shaders (SPEC 3-5).

    import shading
    cam = shading.Camera(eye=(0.5, 0.5, 2.3), target=(0.5, 0.5, 0.5), width=256, height=256)
    meshes = [shading.cloth_mesh(pos, nw, nh, edges), shading.sphere_mesh(o, r)]
    img = shading.render(meshes, cam, light=None, shader="phong", params={"aa": 2})

`shading.SHADERS` lists the shader names; `shading.TextureError` is raised for a missing
or unreadable texture (path in the message).
"""
from .camera import Camera
from .mesh import (Mesh, box_mesh, cloth_mesh, normals_tangents, plane_mesh, sphere_mesh,
                   triangle_mesh)
from .renderer import Renderer, get_renderer, render
from .shaders import REGISTRY, SHADERS, Shader, get_shader
from .textures import TextureError, load_cubemap, load_texture

__all__ = ["Camera", "Mesh", "cloth_mesh", "sphere_mesh", "plane_mesh", "box_mesh",
           "triangle_mesh", "normals_tangents",
           "Renderer", "get_renderer", "render", "SHADERS", "REGISTRY", "Shader",
           "get_shader", "TextureError", "load_texture", "load_cubemap"]
