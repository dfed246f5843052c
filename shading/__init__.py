"""shading: meshes, camera, a numba software rasteriser and shaders (SPEC 3-5).

    import shading
    cam = shading.Camera(eye=(0.5, 0.5, 2.3), target=(0.5, 0.5, 0.5), width=256, height=256)
    meshes = [shading.cloth_mesh(pos, nw, nh, edges), shading.sphere_mesh(o, r)]
    img = shading.render(meshes, cam, light=None, shader="phong", params={"aa": 2})

`shading.SHADERS` lists the shader names; `shading.TextureError` is raised for a missing
or unreadable texture (path in the message). `import shading` is light: the camera is
numpy only, and the modules that import numba load on first use of their names.

Imports only clothjit (the numba helpers), never the simulator (pipeline); inside, the
rasteriser knows nothing of lighting (pyproject.toml's import-linter contracts).
"""
from __future__ import annotations

from importlib import import_module
from typing import Any

from .camera import Camera

_LAZY = {
    "Mesh": "mesh", "box_mesh": "mesh", "cloth_mesh": "mesh", "normals_tangents": "mesh",
    "plane_mesh": "mesh", "sphere_mesh": "mesh", "triangle_mesh": "mesh", "Seams": "mesh",
    "cloth_seams": "mesh", "seamed_cloth_mesh": "mesh",
    "Renderer": "renderer", "get_renderer": "renderer", "render": "renderer",
    "REGISTRY": "shaders", "SHADERS": "shaders", "Shader": "shaders", "get_shader": "shaders",
    "TextureError": "textures", "load_texture": "textures", "load_cubemap": "textures",
}

_SUBMODULES = {"lighting", "mesh", "raster", "renderer", "shade", "shaders", "testing",
               "textures"}

__all__ = ["Camera", *_LAZY]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        if name not in _SUBMODULES:
            raise AttributeError(f"module 'shading' has no attribute {name!r}")
        return import_module(f".{name}", __name__)  # sets the attribute itself
    value = getattr(import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this hook
    return value
