"""The scene format: a JSON file (or dict) read, checked and filled in as frozen dataclasses.

`load_scene` turns a file or dict into a `Scene`; the dataclasses (pipeline.scene.types)
are the only shape the rest of the pipeline sees, nothing downstream reads raw JSON. The
reference of every key is docs/scene-format.md.

The bottom layer of `pipeline`: imports only the standard library and jsonschema (lazily),
no numba or numpy, so that `import pipeline` stays light.
"""
from __future__ import annotations

from .check import scene_schema
from .load import SceneFile, apply_overrides, load_scene
from .types import (COLLIDER_KEYS, COURSE_CAMERA, INTEGRATORS, MODELS, RENDER_PARAMS, SHADERS, Box,
                    CameraSettings, Cloth, ClothMeshSource, Collider, FemMaterial, Keyframe,
                    LightSettings, MeshCollider, PinSelection, Plane, RenderSettings, Scene,
                    SceneError, SimulationSettings, Sphere, Wind)

__all__ = [
    "INTEGRATORS", "SHADERS", "RENDER_PARAMS", "SceneError", "Cloth", "ClothMeshSource",
    "PinSelection", "Sphere", "Plane", "Box", "MeshCollider", "Keyframe", "Collider", "Wind",
    "FemMaterial", "MODELS", "SimulationSettings", "CameraSettings", "COURSE_CAMERA",
    "LightSettings", "RenderSettings", "COLLIDER_KEYS", "Scene", "SceneFile", "load_scene",
    "apply_overrides", "scene_schema"
]
