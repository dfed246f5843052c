"""Mesh colliders in the simulator: concave meshes hold the cloth with no point inside, at
every frame, checked by an inside test that shares nothing with the collider (the
generalized winding number of the mesh file's triangles, in numpy)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from conftest import cloth_dict, scene_dict
from pipeline import Simulation, simulate

MESHES = Path(__file__).resolve().parents[1] / "scenes" / "meshes"


def winding_numbers(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Sum of the signed solid angles of the triangles seen from each point / 4 pi (Van
    Oosterom and Strackee 1983): 1 inside a closed outward-wound mesh, 0 outside."""
    out = np.zeros(len(points))
    tri = vertices[faces]  # (T, 3, 3)
    for start in range(0, len(points), 256):
        p = points[start:start + 256, None, None, :]
        r = tri[None] - p  # (P, T, 3, 3)
        a, b, c = r[..., 0, :], r[..., 1, :], r[..., 2, :]
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ptk,ptk->pt", a, b) * lc
               + np.einsum("ptk,ptk->pt", b, c) * la + np.einsum("ptk,ptk->pt", c, a) * lb)
        out[start:start + 256] = 2.0 * np.arctan2(det, den).sum(axis=1) / (4.0 * np.pi)
    return out


def placed(name: str, scale: float, translation) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.load(MESHES / name, force="mesh")
    return np.asarray(mesh.vertices) * scale + np.asarray(translation), np.asarray(mesh.faces)


def test_winding_number_tells_inside_from_outside():
    v, f = placed("torus.obj", 1.0, (0.0, 0.0, 0.0))  # major radius 0.3, tube 0.1, axis y
    points = np.array([[0.3, 0.0, 0.0], [0.0, 0.0, -0.25], [0.0, 0.0, 0.0], [0.3, 0.12, 0.0]])
    w = winding_numbers(points, v, f)
    np.testing.assert_allclose(w, [1.0, 1.0, 0.0, 0.0], atol=1e-6)  # the hole is outside


@pytest.mark.parametrize("name, scale, translation", [
    ("torus.obj", 0.35, (0.5, 0.3, 0.5)),
    ("bowl.obj", 0.4, (0.5, 0.2, 0.5)),
])
def test_cloth_on_a_concave_mesh_never_has_a_point_inside(name, scale, translation):
    thickness = 0.004
    cloth = cloth_dict(20, 20, width=1.0, height=1.0, orientation=0, damping=0.2, density=1.0,
                       ks=800.0, thickness=0.01)
    d = scene_dict(cloth, frames_per_sec=60, steps_per_frame=30)
    d["mesh"] = {"path": str(MESHES / name), "scale": scale, "translation": list(translation),
                 "friction": 0.3, "thickness": thickness}
    frames = simulate(d, 90)
    v, f = placed(name, scale, translation)
    low, high = v.min(axis=0) - 0.01, v.max(axis=0) + 0.01
    touched = 0
    for positions in frames:
        near = np.all((positions > low) & (positions < high), axis=1)
        if near.any():
            w = winding_numbers(positions[near], v, f)
            assert np.all(w < 0.5), f"{int(np.sum(w >= 0.5))} points inside {name}"
            touched += 1
    assert touched > 30  # the cloth did reach the mesh
    final = frames[-1]
    assert final[:, 1].min() < translation[1] + 0.05  # it drapes down around / into it


def test_icosphere_mesh_holds_the_cloth_like_the_analytic_sphere():
    """The sphere scene with its sphere replaced by a 5120-triangle icosphere: the cloth
    rests at the sphere's radius plus the mesh thickness, within the faceting error."""
    origin, radius, thickness = np.array([0.5, 0.2, 0.5]), 0.2, 0.003
    cloth = cloth_dict(30, 30, width=1.0, height=1.0, orientation=0, damping=0.2,
                       density=150.0, ks=5000.0, thickness=0.0095)
    d = scene_dict(cloth, frames_per_sec=90, steps_per_frame=30)
    d["mesh"] = {"path": str(MESHES / "icosphere5k.obj"), "scale": radius,
                 "translation": origin.tolist(), "friction": 0.3, "thickness": thickness}
    sim = Simulation(d)
    sim.advance(90)
    dist = np.linalg.norm(sim.positions - origin, axis=1)
    v, _ = placed("icosphere5k.obj", radius, origin)
    inscribed = radius * np.cos(np.arcsin(1.0 / 32))  # facets span ~1/32 rad at 5120 faces
    assert dist.min() > inscribed + thickness - 5e-4
    resting = dist < radius + thickness + 1e-3  # the points lying on the sphere
    assert resting.sum() > 50
    # faceting: the icosphere's flat faces dip at most r (1 - cos(edge angle / 2)) ~ 1e-4
    assert dist[resting].min() > radius + thickness - 5e-4
