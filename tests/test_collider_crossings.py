"""The independent cloth-collider crossing checker of issue 43 (benchmarks/collider_crossings.py)
on hand-built cases with closed-form answers. Plain numpy: nothing is compiled."""
from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.scene import Box, Keyframe, MeshCollider, Plane, Sphere


def _load_checker():
    """benchmarks/collider_crossings.py by its path: benchmarks/ on sys.path would shadow
    packages (its distributed.py the Dask one)."""
    spec = importlib.util.spec_from_file_location(
        "collider_crossings",
        Path(__file__).resolve().parents[1] / "benchmarks" / "collider_crossings.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["collider_crossings"] = module
    spec.loader.exec_module(module)
    return module


CC = _load_checker()
NO_EDGES = np.zeros((0, 2), dtype=np.int64)


def check(points, edges, colliders, t=0.0, pinned=None):
    return CC.collider_violations(np.asarray(points, float).reshape(-1, 3),
                                  np.asarray(edges, np.int64).reshape(-1, 2), colliders, t,
                                  pinned)


def segments(*pairs):
    """Points and edges of separate segments ((p, q), ...)."""
    pts = np.array([x for pq in pairs for x in pq], float)
    return pts, np.arange(len(pts)).reshape(-1, 2)


def write_mesh(mesh, path: Path) -> Path:
    mesh.export(path)
    return path


# --- sphere ---------------------------------------------------------------------------------
UNIT = Sphere(origin=(0.0, 0.0, 0.0), radius=1.0, friction=0.3)


def test_sphere_points_inside_outside_on():
    c45 = math.sqrt(0.5)
    pts = [(0.5, 0, 0), (1.5, 0, 0), (1, 0, 0), (0, -1, 0), (0.6, 0.8, 0), (c45, c45, 0),
           (1 - 2e-9, 0, 0), (0, 0, 0)]
    v = check(pts, NO_EDGES, [UNIT])
    assert v["inside_idx"].tolist() == [0, 6, 7]  # on the surface: not inside
    assert v["inside"] == 3 and v["edges"] == 0 and v["below"] == 0


def test_sphere_chord_through_and_missing():
    pts, edges = segments(((-2, 0.5, 0), (2, 0.5, 0)),  # through, both ends outside
                          ((-2, 1.5, 0), (2, 1.5, 0)),  # misses
                          ((-2, 1, 0), (2, 1, 0)),  # tangent: touches, no interior
                          ((0, 0, 0.5), (0, 0, 3)),  # one end inside
                          ((0.8, 0.8, 0), (0.9, 0.7, 0.2)))  # ends outside, nearest at an end
    v = check(pts, edges, [UNIT])
    assert v["edges_idx"].tolist() == [0, 3]
    assert v["chords_idx"].tolist() == [0]  # edge 3 has an end inside
    assert v["inside_idx"].tolist() == [6]
    per = v["colliders"][0]
    assert per["kind"] == "sphere" and per["edges"].tolist() == [0, 3]


def test_keyframed_sphere_inside_at_one_time_only():
    moving = Sphere(origin=(0.0, 0.0, 0.0), radius=0.5, friction=0.3,
                    keyframes=(Keyframe(time=0.0), Keyframe(time=1.0, translation=(2, 0, 0))))
    pts, edges = segments(((1.0, 0.0, 0.0), (1.0, 2.0, 0.0)), ((2.0, -1.0, 0.0), (2.0, 1.0, 0.0)))
    at = {t: check(pts, edges, [moving], t) for t in (0.0, 0.5, 1.0, 7.0)}
    assert at[0.0]["inside"] == 0 and at[0.0]["edges"] == 0
    assert at[0.5]["inside_idx"].tolist() == [0] and at[0.5]["edges_idx"].tolist() == [0]
    assert at[1.0]["inside"] == 0 and at[1.0]["chords_idx"].tolist() == [1]
    assert at[7.0]["chords_idx"].tolist() == [1]  # held after the last key
    # pins: a pinned point is never inside; an edge with both ends pinned is left out
    v = check(pts, edges, [moving], 0.5, pinned=np.array([0]))
    assert v["inside"] == 0 and v["edges_idx"].tolist() == [0]
    v = check(pts, edges, [moving], 0.5, pinned=np.array([True, True, False, False]))
    assert v["inside"] == 0 and v["edges"] == 0


# --- box ------------------------------------------------------------------------------------
CUBE = Box(center=(0.0, 0.0, 0.0), half_extents=(1.0, 1.0, 2.0), friction=0.3)


@pytest.mark.parametrize("a, b, d, cuts", [
    (0.2, 0.2, 0.1, True), (0.2, 0.2, 0.3, False),  # d^2 = 0.01 < ab = 0.04; 0.09 > 0.04
    (0.1, 0.4, 0.19, True), (0.1, 0.4, 0.21, False),  # ab = 0.04: d^2 0.0361 and 0.0441
])
def test_box_corner_cut(a, b, d, cuts):
    """In the cross-section z = 0.3 about the corner (1, 1), a segment from (-a, d) to
    (d, -b) (corner coordinates) meets the box (u < 0 and v < 0) iff d^2 < ab."""
    p, q = (1 - a, 1 + d, 0.3), (1 + d, 1 - b, 0.3)
    v = check([p, q], [[0, 1]], [CUBE])
    assert v["inside"] == 0
    assert v["edges"] == int(cuts) and v["chords"] == int(cuts)
    v = check([q, p], [[0, 1]], [CUBE])  # either direction
    assert v["edges"] == int(cuts)


def test_box_segments_along_a_face():
    pts, edges = segments(((-2, 1 + 1e-12, 0), (2, 1 + 1e-12, 0)),  # just outside, parallel
                          ((-2, 1.0, 0), (2, 1.0, 0)),  # in the face's plane: touching
                          ((-2, 1 - 1e-12, 0), (2, 1 - 1e-12, 0)),  # just inside
                          ((0.5, 0.5, 2.0), (0.5, 0.5, 5.0)),  # from a face outwards
                          ((0.2, 0.3, -3), (0.2, 0.3, 3)))  # through, along z
    v = check(pts, edges, [CUBE])
    assert v["edges_idx"].tolist() == [2, 4]
    assert v["inside"] == 0


def test_box_points():
    pts = [(0.9, -0.9, 1.9), (1.0, 0.0, 0.0), (0, 0, 2.0), (0, 0, -2.1), (0, 0, 0)]
    assert check(pts, NO_EDGES, [CUBE])["inside_idx"].tolist() == [0, 4]


def test_rotated_box():
    """Turned 45 degrees about z: its corner along +x at sqrt(2), its face at x = y = 1/sqrt 2
    ... along the diagonal."""
    box = Box(center=(0.0, 0.0, 0.0), half_extents=(1.0, 1.0, 1.0), friction=0.3,
              rotation=(0.0, 0.0, 45.0))
    pts = [(1.3, 0, 0), (1.5, 0, 0), (0.75, 0.75, 0), (0.7, 0.7, 0)]
    assert check(pts, NO_EDGES, [box])["inside_idx"].tolist() == [0, 3]
    pts, edges = segments(((1.3, -0.5, 0), (1.3, 0.5, 0)),  # cuts the corner at x = sqrt 2
                          ((1.5, -0.5, 0), (1.5, 0.5, 0)),  # beyond it
                          ((0.75, 0.75, 0), (2, 2, 0)))  # outside along the diagonal
    v = check(pts, edges, [box])
    assert v["edges_idx"].tolist() == [0] and v["chords_idx"].tolist() == [0]


def test_keyframed_box_turns_about_its_center():
    box = Box(center=(1.0, 0.0, 0.0), half_extents=(1.0, 1.0, 1.0), friction=0.3,
              keyframes=(Keyframe(time=0.0), Keyframe(time=1.0, rotation=(0.0, 0.0, 90.0))))
    p = [(2.3, 0.0, 0.0), (1.0, 1.3, 0.0)]  # past the +x face at rest, inside at 45 degrees
    assert check(p, NO_EDGES, [box], 0.0)["inside"] == 0
    assert check(p, NO_EDGES, [box], 0.5)["inside_idx"].tolist() == [0, 1]
    assert check(p, NO_EDGES, [box], 1.0)["inside"] == 0


# --- plane ----------------------------------------------------------------------------------
def test_plane_below_and_edges_across():
    floor = Plane(point=(0.0, 0.5, 0.0), normal=(0.0, 2.0, 0.0), friction=0.3)
    pts, edges = segments(((0, 0.4, 0), (0, 0.6, 0)),  # across
                          ((1, 0.5, 0), (2, 0.5, 0)),  # in the plane
                          ((1, 0.5, 1), (1, 0.3, 1)),  # one end on it, one below
                          ((3, 0.7, 0), (3, 0.9, 0)))  # above
    v = check(pts, edges, [floor])
    assert v["below_idx"].tolist() == [0, 5] and v["below"] == 2
    assert v["edges_idx"].tolist() == [0]
    assert v["inside"] == 0 and v["chords"] == 0


# --- meshes ---------------------------------------------------------------------------------
def test_one_sided_square(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    square = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                             [[0, 1, 2], [0, 2, 3]], process=False)
    sheet = MeshCollider(path=write_mesh(square, tmp_path / "square.obj"), friction=0.3,
                         solid=False)
    pts, edges = segments(((0.3, -0.2, -1), (0.3, -0.2, 1)),  # through a triangle
                          ((0.5, 0.5, -1), (0.4, 0.4, 1)),  # through the shared diagonal
                          ((1.5, 0.0, -1), (1.5, 0.0, 1)),  # round the rim
                          ((0.9, 0.0, -0.1), (1.3, 0.0, 0.1)),  # from under the sheet to
                          # beyond its rim (at z = 0, x = 1.1): round it
                          ((0, 0, 0.1), (0.5, 0.5, 0.2)),  # above, not crossing
                          ((1.0, 0.2, -1), (1.0, 0.2, 1)))  # exactly through the rim: counted
    v = check(pts, edges, [sheet])
    assert v["edges_idx"].tolist() == [0, 1, 5]
    assert v["inside"] == 0 and v["chords"] == 0
    # placed and keyframed: raised by 1 m at t = 1, the first segment then passes under it
    moved = MeshCollider(path=sheet.path, friction=0.3, solid=False, translation=(0, 0, 0.5),
                         keyframes=(Keyframe(time=0.0), Keyframe(time=1.0,
                                                                 translation=(0, 0, 1.0))))
    assert check(pts, edges, [moved], 0.0)["edges_idx"].tolist() == [0, 1, 5]
    assert check(pts, edges, [moved], 1.0)["edges"] == 0


def test_closed_box_mesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    cube = MeshCollider(path=write_mesh(trimesh.creation.box(extents=(2, 2, 2)),
                                        tmp_path / "cube.obj"),
                        friction=0.3, translation=(0.0, 1.0, 0.0))  # spans y in [0, 2]
    pts = [(0.2, 1.3, 0.1), (1.5, 1.0, 0.0), (1.0, 1.2, 0.3), (0.0, 2.0, 0.0), (0.99, 0.01, -0.99),
           (0.0, -0.5, 0.0)]
    v = check(pts, NO_EDGES, [cube])
    assert v["inside_idx"].tolist() == [0, 4]  # 2 and 3 on faces: not inside
    pts, edges = segments(((-2, 1.5, 0.5), (2, 1.5, 0.5)),  # a chord through it
                          ((-2, 2.5, 0.5), (2, 2.5, 0.5)),  # above
                          ((0, 1.0, 0), (0, 1.0, 3)),  # from inside out
                          ((0.5, 0.5, 0.5), (0.2, 0.2, 0.2)),  # wholly inside
                          ((-2, 1.0, 1.0), (2, 1.0, 1.0)),  # along a face, through edges
                          ((-2, 1.0, 0.0), (2, 1.0, 0.0)),  # through shared triangle edges
                          ((0, 3, 2), (2, 1, 0)))  # grazing the corner (1, 2, 1)
    v = check(pts, edges, [cube])
    assert v["edges_idx"].tolist() == [0, 2, 3, 5]
    assert v["chords_idx"].tolist() == [0, 5]
    assert v["inside_idx"].tolist() == [4, 6, 7]


def test_closed_icosphere_against_the_sphere(tmp_path):
    """An icosphere of radius 1 lies between its inscribed sphere (the faces' distance) and
    the unit sphere: points clear of that shell agree with the closed form."""
    trimesh = pytest.importorskip("trimesh")
    ico = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    inner = float(np.min(np.abs(np.einsum("ij,ij->i", ico.face_normals,
                                          ico.triangles_center))))
    ball = MeshCollider(path=write_mesh(ico, tmp_path / "ball.obj"), friction=0.3,
                        translation=(0.5, 0.0, 0.0), rotation=(10.0, 20.0, 30.0))
    rng = np.random.default_rng(7)
    pts = rng.uniform(-1.5, 1.5, (3000, 3))
    r = np.linalg.norm(pts, axis=1)
    clear = (r < inner - 1e-6) | (r > 1.0 + 1e-6)
    got = np.zeros(len(pts), bool)
    got[check(pts + (0.5, 0, 0), NO_EDGES, [ball])["inside_idx"]] = True
    assert np.array_equal(got[clear], r[clear] < inner)
    # chords at heights h: through while h < inner, clear when h > 1
    pts, edges = segments(((-0.2, -2, 0.3), (0.7, 2, 0.8)), ((-2, 1.01, 0), (2, 1.01, 0.1)))
    v = check(pts + (0.5, 0, 0), edges, [ball])
    assert v["edges_idx"].tolist() == [0] and v["chords_idx"].tolist() == [0]


# --- several colliders, layouts -------------------------------------------------------------
def test_totals_over_colliders_and_layouts():
    floor = Plane(point=(0.0, -3.0, 0.0), normal=(0.0, 1.0, 0.0), friction=0.3)
    pts, edges = segments(((0.5, 0, 0), (3, 0, 0)),  # sphere: an end inside
                          ((5, -2, 0), (5, -4, 0)),  # across the floor
                          ((-5, 0.5, 0.5), (5, 0.5, 0.5)))  # through both the sphere and box
    box = Box(center=(3.0, 0.5, 0.5), half_extents=(0.2, 0.2, 0.2), friction=0.3)
    v = check(pts, edges, [UNIT, floor, box])
    assert (v["inside"], v["edges"], v["chords"], v["below"]) == (1, 3, 1, 1)
    assert [c["edges"].tolist() for c in v["colliders"]] == [[0, 2], [1], [2]]
    assert [c["kind"] for c in v["colliders"]] == ["sphere", "plane", "box"]
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        CC.collider_violations(pts.T, edges, [UNIT], 0.0)
    with pytest.raises(ValueError, match="finite"):
        CC.collider_violations(np.full((2, 3), np.nan), NO_EDGES, [UNIT], 0.0)


def test_pose_matches_the_documented_convention():
    """R (p - pivot) + pivot + T with T and the Euler angles (R = Rz Ry Rx) interpolated."""
    obj = Box(center=(1.0, 2.0, 3.0), half_extents=(1, 1, 1), friction=0.3,
              keyframes=(Keyframe(time=1.0), Keyframe(time=3.0, translation=(2, 0, 0),
                                                      rotation=(0.0, 0.0, 90.0))))
    rot, trans = CC.pose(obj, 2.0)
    c = math.sqrt(0.5)
    assert np.allclose(rot, [[c, -c, 0], [c, c, 0], [0, 0, 1]]) and np.allclose(trans, [1, 0, 0])
    assert np.allclose(CC.pose(obj, 0.0)[0], np.eye(3)) and np.allclose(CC.pose(obj, 9.0)[1],
                                                                          [2, 0, 0])
    rx = CC.euler((90.0, 0.0, 0.0))
    ry = CC.euler((0.0, 90.0, 0.0))
    assert np.allclose(CC.euler((90.0, 90.0, 0.0)), ry @ rx)
