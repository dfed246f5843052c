"""Regenerate the collider meshes of this folder (y is up; sizes in metres).

    python scenes/meshes/make_meshes.py

torus.obj       major radius 0.3, minor radius 0.1, axis y (4096 triangles).
bowl.obj        a thick hemispherical bowl, watertight: outer radius 0.4, wall 0.05, flat rim
                at y = 0, opening up (concave: its cavity is outside the solid).
icosphere5k.obj an icosphere of radius 1 (5120 triangles).
open_bowl.obj   an open hemispherical shell of radius 0.4, opening up: NOT watertight, for
                one-sided (`"solid": false`) mesh colliders.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
Z_UP_TO_Y_UP = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
ARC = 16  # profile segments of a quarter circle
SECTIONS = 64  # segments around the axis


def _quarter_arc(radius: float) -> np.ndarray:
    """(ARC + 1, 2) points (r, z) from the bottom pole (0, -radius) to the rim (radius, 0)."""
    angle = np.linspace(0.0, np.pi / 2, ARC + 1)
    return np.column_stack([radius * np.sin(angle), -radius * np.cos(angle)])


def torus() -> trimesh.Trimesh:
    return trimesh.creation.torus(0.3, 0.1, major_sections=64, minor_sections=32,
                                  transform=Z_UP_TO_Y_UP)


def bowl(radius: float = 0.4, wall: float = 0.05) -> trimesh.Trimesh:
    outer = _quarter_arc(radius)
    inner = _quarter_arc(radius - wall)[::-1]
    profile = np.vstack([outer, inner, outer[:1]])  # closed: outer arc, rim, inner arc, axis
    return trimesh.creation.revolve(profile, sections=SECTIONS, transform=Z_UP_TO_Y_UP)


def open_bowl(radius: float = 0.4) -> trimesh.Trimesh:
    return trimesh.creation.revolve(_quarter_arc(radius), sections=SECTIONS,
                                    transform=Z_UP_TO_Y_UP)


def icosphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=1.0)


def main() -> None:
    meshes = {"torus": torus(), "bowl": bowl(), "icosphere5k": icosphere(),
              "open_bowl": open_bowl()}
    for name, mesh in meshes.items():
        text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, digits=6)
        (HERE / f"{name}.obj").write_text(text)
        print(f"{name}.obj: {len(mesh.faces)} triangles, watertight={mesh.is_watertight}")


if __name__ == "__main__":
    main()
