"""A cloth from a mesh file (`cloth.mesh`): the scene keys, reading and welding the file,
its refusals, pins, placement, formats, and the shipped meshes (scenes/meshes)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from pipeline.physics.cloth_mesh import load_cloth_mesh, pinned_points
from pipeline.scene import ClothMeshSource, PinSelection, SceneError, load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
MESHES = SCENES / "meshes"


# --------------------------------------------------------------------------------------
# Writing small test meshes
# --------------------------------------------------------------------------------------

def obj_text(v, faces, vt=None, face_uv=None, groups=None) -> str:
    """An indexed OBJ: `faces` lists of 0-based vertex indices (any polygon), `face_uv` the
    same shape into vt, `groups` a name per face (a `g` line where it changes)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v]
    lines += [f"vt {u!r} {w!r}" for u, w in (vt or [])]
    group = None
    for k, f in enumerate(faces):
        if groups is not None and groups[k] != group:
            group = groups[k]
            lines.append(f"g {group}")
        if face_uv is None:
            lines.append("f " + " ".join(str(i + 1) for i in f))
        else:
            lines.append("f " + " ".join(f"{i + 1}/{t + 1}" for i, t in zip(f, face_uv[k])))
    return "\n".join(lines) + "\n"


def soup_text(v, faces, vt=None, face_uv=None, groups=None) -> str:
    """The same mesh as an exporter's triangle soup: every face its own vertex lines (and
    its own vt lines)."""
    sv = [v[i] for f in faces for i in f]
    sf, n = [], 0
    for f in faces:
        sf.append(list(range(n, n + len(f))))
        n += len(f)
    svt = [vt[t] for fu in face_uv for t in fu] if face_uv is not None else None
    return obj_text(sv, sf, svt, sf if face_uv is not None else None, groups)


def write(tmp_path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def load(path, **placement) -> "object":
    return load_cloth_mesh(ClothMeshSource(path=Path(path), **placement))


def refusal(path, **placement) -> str:
    with pytest.raises(SceneError) as info:
        load(path, **placement)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    return msg


def band(n: int = 8, rows: int = 3):
    """An open cylinder band about y (n around, rows rings) with a uv seam at angle 0:
    positions indexed by first use, uvs per corner (u wraps from 1 to 0 at the seam)."""
    pos, idx = [], {}
    vt, vt_idx = [], {}
    faces, face_uv = [], []

    def p(i, r):
        key = (i % n, r)
        if key not in idx:
            a = 2 * math.pi * (i % n) / n
            idx[key] = len(pos)
            pos.append((0.5 * math.cos(a), 0.25 * r, -0.5 * math.sin(a)))
        return idx[key]

    def t(i, r):
        key = (i, r)  # i == n: the seam's u = 1 side
        if key not in vt_idx:
            vt_idx[key] = len(vt)
            vt.append((i / n, r / (rows - 1)))
        return vt_idx[key]

    for r in range(rows - 1):
        for i in range(n):
            for f in (((i, r), (i + 1, r), (i + 1, r + 1)), ((i, r), (i + 1, r + 1), (i, r + 1))):
                faces.append([p(*c) for c in f])
                face_uv.append([t(*c) for c in f])
    return pos, faces, vt, face_uv


def grid(nx: int = 4, ny: int = 3, h: float = 0.1):
    """A flat (nx x ny points) grid in the x-z plane, y = 1, as quads."""
    v = [(h * j, 1.0, h * i) for i in range(ny) for j in range(nx)]
    quads = [[i * nx + j, (i + 1) * nx + j, (i + 1) * nx + j + 1, i * nx + j + 1]
             for i in range(ny - 1) for j in range(nx - 1)]
    return v, quads


def disc(n: int = 12):
    """A centre and a ring of n points in the plane y = 0, fan triangles facing +y, then a
    second ring of n points: a small disc, consistently wound."""
    v = [(0.0, 0.0, 0.0)]
    v += [(math.cos(2 * math.pi * i / n), 0.0, -math.sin(2 * math.pi * i / n)) for i in range(n)]
    v += [(2 * math.cos(2 * math.pi * (i + 0.5) / n), 0.0,
           -2 * math.sin(2 * math.pi * (i + 0.5) / n)) for i in range(n)]
    faces = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
    for i in range(n):
        a, b = 1 + i, 1 + (i + 1) % n
        c = 1 + n + i
        faces.append([a, c, b])
        faces.append([b, c, 1 + n + (i + 1) % n])
    return v, faces


def cyclic(t: np.ndarray) -> np.ndarray:
    """Triangles turned to start at their smallest index (same winding)."""
    k = np.argmin(t, axis=1)
    return np.stack([t[np.arange(len(t)), (k + i) % 3] for i in range(3)], axis=1)


def normals(mesh) -> np.ndarray:
    p, t = mesh.points, mesh.triangles
    return np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])


def assert_same_cloth(a, b):
    for name in ("points", "triangles", "corner_uv"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name
    assert a.has_uv == b.has_uv and a.pieces == b.pieces
    assert a.groups.keys() == b.groups.keys()
    for g in a.groups:
        assert np.array_equal(a.groups[g], b.groups[g])


# --------------------------------------------------------------------------------------
# Reading and welding
# --------------------------------------------------------------------------------------

def test_welded_soup_is_the_indexed_mesh_bit_for_bit(tmp_path):
    v, faces, vt, fuv = band()
    groups = ["low" if k < len(faces) // 2 else "high" for k in range(len(faces))]
    indexed = load(write(tmp_path, "indexed.obj", obj_text(v, faces, vt, fuv, groups)))
    soup = load(write(tmp_path, "soup.obj", soup_text(v, faces, vt, fuv, groups)))
    assert_same_cloth(indexed, soup)
    assert indexed.has_uv and indexed.pieces == 1 and len(indexed.points) == len(v)
    assert np.array_equal(indexed.file_index, np.arange(len(v)))
    assert len(soup.file_index) == 3 * len(faces)
    assert np.array_equal(soup.points[soup.file_index], np.array(v)[np.ravel(faces)])
    # the seam is kept: a triangle across it has u = 1 at its wrapped corners, not 0
    seam_faces = [k for k, f in enumerate(fuv) if any(vt[t][0] == 1.0 for t in f)]
    assert seam_faces and (indexed.corner_uv[seam_faces, :, 0].max(axis=1) == 1.0).all()
    # an STL of the same triangles (a soup without uvs) welds to the same points
    stl = tmp_path / "band.stl"
    trimesh.Trimesh(np.array(v), np.array(faces), process=False).export(stl)
    from_stl = load(stl)
    assert np.array_equal(from_stl.triangles, indexed.triangles)
    assert np.allclose(from_stl.points, indexed.points, atol=1e-7)  # STL holds float32
    assert not from_stl.has_uv


def test_the_arrays_are_read_only_and_cached(tmp_path):
    v, faces = disc()
    path = write(tmp_path, "disc.obj", obj_text(v, faces))
    mesh = load(path)
    assert load(path) is mesh
    assert mesh.points.flags.c_contiguous and mesh.points.dtype == np.float64
    assert mesh.triangles.dtype == np.int64 and mesh.file_index.dtype == np.int64
    assert mesh.corner_uv.shape == (len(faces), 3, 2)
    for a in (mesh.points, mesh.triangles, mesh.corner_uv, mesh.file_index):
        assert not a.flags.writeable
    assert load(path, translation=(0.0, 1.0, 0.0)) is not mesh


def test_quads_and_polygons_are_fanned_from_their_first_corner(tmp_path):
    v, quads = grid(3, 2)
    v = v + [(0.3, 1.0, 0.0), (0.35, 1.0, 0.05), (0.3, 1.0, 0.1)]
    pentagon = [2, 5, 8, 7, 6]  # wound as the quads
    mesh = load(write(tmp_path, "quads.obj", obj_text(v, quads + [pentagon])))
    assert mesh.triangles.tolist() == [[0, 3, 4], [0, 4, 1], [1, 4, 5], [1, 5, 2],
                                       [2, 5, 8], [2, 8, 7], [2, 7, 6]]


def test_negative_obj_indices_and_comments(tmp_path):
    text = ("# a comment\nv 0 0 0\nv 1 0 0\nv 0 1 0  # the third\no sheet\n"
            "f -3 -2 -1\n")
    mesh = load(write(tmp_path, "neg.obj", text))
    assert mesh.triangles.tolist() == [[0, 1, 2]] and list(mesh.groups) == ["sheet"]


def test_unreferenced_vertices_are_dropped(tmp_path):
    v, faces = disc(6)
    v = [(9.0, 9.0, 9.0)] + v  # vertex 0: used by no face
    faces = [[i + 1 for i in f] for f in faces]
    mesh = load(write(tmp_path, "unused.obj", obj_text(v, faces)))
    assert len(mesh.points) == len(v) - 1 and mesh.file_index[0] == -1
    assert np.array_equal(mesh.file_index[1:], np.arange(len(v) - 1))
    assert not (mesh.points == 9.0).all(axis=1).any()
    with pytest.raises(SceneError, match=r"^s.json: cloth.pinned\[0\]: vertex 0 of unused.obj "
                                         r"is used by no face"):
        pinned_points(mesh, (PinSelection("cloth.pinned[0]", indices=(0,)),), "s.json")


def test_winding_is_made_consistent(tmp_path):
    v, faces = disc()
    good = load(write(tmp_path, "good.obj", obj_text(v, faces)))
    assert (normals(good)[:, 1] > 0).all()
    # every other face turned in the file: the first face's winding wins the tie
    half = [f if k % 2 == 0 else f[::-1] for k, f in enumerate(faces)]
    fixed = load(write(tmp_path, "half.obj", obj_text(v, half)))
    assert np.array_equal(cyclic(fixed.triangles), cyclic(good.triangles))
    assert np.array_equal(fixed.triangles[::2], good.triangles[::2])  # kept as written
    # most faces turned: the majority's winding is kept
    most = [f[::-1] if k % 3 else f for k, f in enumerate(faces)]
    turned = load(write(tmp_path, "most.obj", obj_text(v, most)))
    assert (normals(turned)[:, 1] < 0).all()
    # uv corners follow their vertices when a face is turned
    vt = [(x / 4 + 0.5, -z / 4 + 0.5) for x, _, z in v]
    with_uv = load(write(tmp_path, "half_uv.obj", obj_text(v, half, vt, half)))
    assert np.array_equal(with_uv.triangles, fixed.triangles)
    assert np.array_equal(with_uv.corner_uv, np.array(vt)[fixed.triangles])


def test_placement_matches_a_hand_computed_point(tmp_path):
    v, faces = disc(6)
    path = write(tmp_path, "disc.obj", obj_text(v, faces))
    mesh = load(path, translation=(1.0, 2.0, 3.0), rotation=(0.0, 0.0, 90.0),
                scale=(2.0, 3.0, 4.0))
    # file vertex 1 = (1, 0, 0): scaled (2, 0, 0), turned 90 degrees about z (0, 2, 0)
    assert np.allclose(mesh.points[mesh.file_index[1]], (1.0, 4.0, 3.0), atol=1e-12)
    # vertex 2 = (cos 60, 0, -sin 60): scaled (1, 0, -4 sin 60), about z (0, 1, ...)
    assert np.allclose(mesh.points[mesh.file_index[2]],
                       (1.0, 3.0, 3.0 - 4 * math.sin(math.pi / 3)), atol=1e-12)
    rx = load(path, rotation=(90.0, 0.0, 0.0))  # about x: z -> -y ... (0, 0, -1) -> (0, 1, 0)
    assert np.allclose(rx.points[rx.file_index[1]], (1.0, 0.0, 0.0), atol=1e-12)
    assert np.allclose(rx.points[rx.file_index[2]], (0.5, math.sin(math.pi / 3), 0.0),
                       atol=1e-12)


def test_placement_is_the_mesh_colliders(tmp_path):
    from pipeline.physics.colliders.mesh import _mesh

    v, faces = disc(6)
    path = write(tmp_path, "disc.obj", obj_text(v, faces))
    place = dict(translation=(0.1, 0.2, 0.3), rotation=(10.0, 20.0, 30.0), scale=(1.5, 0.5, 2.0))
    mesh = load(path, **place)
    vertices, _ = _mesh(str(path), 0, place["translation"], place["rotation"], place["scale"])
    assert mesh.points.tobytes() == np.ascontiguousarray(vertices).tobytes()


def test_planar_uv_when_the_file_has_none(tmp_path):
    v, quads = grid(5, 3, 0.25)  # 1.0 x 0.5 in the x-z plane
    mesh = load(write(tmp_path, "plain.obj", obj_text(v, quads)))
    assert not mesh.has_uv
    uv = mesh.corner_uv.reshape(-1, 2)
    assert uv.min() == 0.0 and np.isclose(uv.max(), 1.0)
    assert np.isclose(np.ptp(uv[:, 0]), 1.0) and np.isclose(np.ptp(uv[:, 1]), 0.5)  # aspect
    # u along x; (u, v, normal) right-handed: not mirrored seen from the front
    corner = mesh.corner_uv[mesh.triangles == mesh.file_index[4]][0]
    assert np.allclose(corner, (1.0, uv[:, 1].max()) if corner[1] > 0 else (1.0, 0.0))
    n = normals(mesh).sum(axis=0)
    p, t, c = mesh.points, mesh.triangles[0], mesh.corner_uv[0]
    du, dv = c[1] - c[0], c[2] - c[0]
    e1, e2 = p[t[1]] - p[t[0]], p[t[2]] - p[t[0]]
    det = du[0] * dv[1] - du[1] * dv[0]
    tangent = (e1 * dv[1] - e2 * du[1]) / det
    bitangent = (e2 * du[0] - e1 * dv[0]) / det
    assert np.cross(tangent, bitangent) @ n > 0


# --------------------------------------------------------------------------------------
# Refusals
# --------------------------------------------------------------------------------------

def test_no_triangles(tmp_path):
    path = write(tmp_path, "points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    assert refusal(path) == (f"{path}: no triangles: a cloth mesh needs faces (the file has "
                             f"3 vertices and no face)")


def test_non_manifold_edge(tmp_path):
    v = [(0, 0, 0), (1, 0, 0), (0.5, 1, 0), (0.5, -1, 0), (0.5, 0, 1)]
    faces = [[0, 1, 2], [1, 0, 3], [0, 1, 4]]
    msg = refusal(write(tmp_path, "fin.obj", obj_text(v, faces)))
    assert msg.endswith(": 1 non-manifold edge (three or more triangles on one edge); e.g. "
                        "the edge between vertices 0 and 1 (0-based, the file's vertex order) "
                        "has 3 triangles"), msg


def test_degenerate_triangles_after_welding(tmp_path):
    v, faces = disc(6)
    # a soup whose triangle 2 has two corners at the same position: zero area once welded
    soup = soup_text(v, faces)
    lines = soup.splitlines()
    lines[7] = lines[6]  # triangle 2's second vertex line := its first
    msg = refusal(write(tmp_path, "pinch.obj", "\n".join(lines) + "\n"))
    assert msg.endswith(": 1 degenerate (zero-area) triangle after welding vertices at the "
                        "same position; the first is triangle 2 (0-based, polygons fanned into "
                        "triangles)"), msg
    # collinear corners
    v2 = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0)]
    msg = refusal(write(tmp_path, "flat.obj", obj_text(v2, [[0, 1, 3], [0, 2, 1]])))
    assert ": 1 degenerate (zero-area) triangle after welding" in msg and "triangle 1 " in msg


def test_separate_pieces_are_refused_unless_allowed(tmp_path):
    v, faces = disc(6)
    copies = v + [(x + 5.0, y, z) for x, y, z in v] + [(x, y + 3.0, z) for x, y, z in v]
    faces3 = [[i + k * len(v) for i in f] for k in range(3) for f in faces]
    path = write(tmp_path, "three.obj", obj_text(copies, faces3))
    assert refusal(path) == (f'{path}: 3 separate pieces; set cloth.pieces to "allow" to '
                             f"simulate them together")
    assert load(path, pieces_allowed=True).pieces == 3


def test_moebius_strip_is_not_orientable(tmp_path):
    n = 24
    v, faces = [], []
    for i in range(n):
        a = 2 * math.pi * i / n
        for s in (-0.2, 0.2):
            r = 1 + s * math.cos(a / 2)
            v.append((r * math.cos(a), s * math.sin(a / 2), r * math.sin(a)))
    for i in range(n):
        a0, a1 = 2 * i, 2 * i + 1
        if i < n - 1:
            b0, b1 = 2 * i + 2, 2 * i + 3
        else:  # the half twist: the strip's edges swap
            b0, b1 = 1, 0
        faces += [[a0, b0, b1], [a0, b1, a1]]
    msg = refusal(write(tmp_path, "moebius.obj", obj_text(v, faces)))
    assert ": not orientable (like a Moebius strip)" in msg, msg
    # the same strip without the twist loads
    v2 = [(math.cos(2 * math.pi * i / n) * (1 + s), s, math.sin(2 * math.pi * i / n) * (1 + s))
          for i in range(n) for s in (-0.2, 0.2)]
    faces2 = faces[:-2] + [[2 * n - 2, 0, 1], [2 * n - 2, 1, 2 * n - 1]]
    assert load(write(tmp_path, "ring.obj", obj_text(v2, faces2))).pieces == 1


@pytest.mark.parametrize("name, content, expected", [
    ("garbage.ply", b"\x00\x01 not a mesh", "cannot read the cloth mesh (OBJ, PLY, STL"),
    ("bad.obj", b"v 0 0 zero\n", "cannot read as an OBJ mesh: line 1: "),
    ("index0.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
     "cannot read as an OBJ mesh: line 4: index 0 (OBJ indices start at 1)"),
    ("short.obj", b"v 0 0 0\nv 1 0 0\nf 1 2\n",
     "cannot read as an OBJ mesh: line 3: a face needs at least 3 vertices, got 2"),
    ("far.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n",
     "cannot read the cloth mesh: triangle 0 uses vertex 7 (1-based) of 3"),
    ("far_uv.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/2\n",
     "cannot read the cloth mesh: triangle 0 uses texture vertex 2 (1-based) of 1"),
    ("nan.obj", b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
     "a vertex has a coordinate that is not a finite number"),
])
def test_unreadable_files(tmp_path, name, content, expected):
    path = tmp_path / name
    path.write_bytes(content)
    msg = refusal(path)
    assert expected in msg, msg


def test_missing_file(tmp_path):
    assert refusal(tmp_path / "nope.obj").endswith("cannot read the cloth mesh: No such file or "
                                                   "directory")


# --------------------------------------------------------------------------------------
# Pins
# --------------------------------------------------------------------------------------

def test_pins_by_index_box_and_group(tmp_path):
    v, quads = grid(4, 3)  # points at x = 0, 0.1, 0.2, 0.3; z = 0, 0.1, 0.2; y = 1
    groups = ["left" if k % 3 == 0 else "rest" for k in range(len(quads))]
    # a soup: file vertex indices are per corner, mapped through the welding
    text = soup_text(v, quads, groups=groups)
    mesh = load(write(tmp_path, "g.obj", text), translation=(0.0, 1.0, 0.0))
    file_v = [v[i] for q in quads for i in q]
    by_index = pinned_points(mesh, (PinSelection("cloth.pinned[0]", indices=(0, 5)),), "s.json")
    assert by_index.dtype == np.uint8 and by_index.shape == (len(mesh.points),)
    assert {tuple(mesh.points[k]) for k in np.flatnonzero(by_index)} == {
        (file_v[0][0], 2.0, file_v[0][2]), (file_v[5][0], 2.0, file_v[5][2])}
    box = PinSelection("cloth.pinned", box=((-1.0, 2.0, -1.0), (0.1, 2.0, 0.0)))
    pts = mesh.points[pinned_points(mesh, (box,), "s.json") == 1]
    assert sorted(map(tuple, pts.round(12))) == [(0.0, 2.0, 0.0), (0.1, 2.0, 0.0)]  # bounds in
    left = pinned_points(mesh, (PinSelection("cloth.pinned", group="left"),), "s.json")
    assert set(np.flatnonzero(left)) == set(mesh.groups["left"])
    assert np.allclose(mesh.points[left == 1][:, 0].max(), 0.1)
    both = pinned_points(mesh, (box, PinSelection("k", indices=(0,))), "s.json")
    assert both.sum() == 2  # the same point twice is pinned once


@pytest.mark.parametrize("selection, expected", [
    (PinSelection("cloth.pinned[3]", indices=(0, 24)),
     "s.json: cloth.pinned[3]: vertex index 24 is out of range (g.obj has 24 vertices: 0 to 23)"),
    (PinSelection("cloth.pinned[1]", group="hem"),
     "s.json: cloth.pinned[1]: no group 'hem' in g.obj (its groups: 'left', 'rest')"),
    (PinSelection("cloth.pinned", box=((5.0, 5.0, 5.0), (6.0, 6.0, 6.0))),
     "s.json: cloth.pinned: the box [[5, 5, 5], [6, 6, 6]] holds no point of the cloth (its "
     "points, as placed, span [[0, 1, 0], [0.3, 1, 0.2]])"),
])
def test_pin_errors_name_the_scene_file_and_key(tmp_path, selection, expected):
    v, quads = grid(4, 3)
    groups = ["left" if k % 3 == 0 else "rest" for k in range(len(quads))]
    mesh = load(write(tmp_path, "g.obj", soup_text(v, quads, groups=groups)))
    with pytest.raises(SceneError) as info:
        pinned_points(mesh, (PinSelection("ok", indices=(1,)), selection), "s.json")
    assert str(info.value) == expected


def test_a_file_without_groups_says_so(tmp_path):
    v, faces = disc(6)
    mesh = load(write(tmp_path, "d.obj", obj_text(v, faces)))
    with pytest.raises(SceneError, match=r"no group 'a' in d.obj \(its groups: none\)"):
        pinned_points(mesh, (PinSelection("cloth.pinned", group="a"),), "s.json")


# --------------------------------------------------------------------------------------
# Other formats
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("ext", ["ply", "off", "stl", "glb"])
def test_other_formats_load(tmp_path, ext):
    v, faces = disc()
    reference = load(write(tmp_path, "disc.obj", obj_text(v, faces)))
    path = tmp_path / f"disc.{ext}"
    trimesh.Trimesh(np.array(v), np.array(faces), process=False).export(path)
    mesh = load(path)
    assert np.array_equal(mesh.triangles, reference.triangles)
    assert np.allclose(mesh.points, reference.points, atol=1e-6)
    if ext in ("ply", "off"):  # indexed formats keep the file's vertex order
        assert np.array_equal(mesh.file_index, np.arange(len(v)))


def test_ply_uv_and_vertex_attribute_groups(tmp_path):
    v, faces = disc(6)
    m = trimesh.Trimesh(np.array(v), np.array(faces), process=False)
    uv = np.array([(x / 4 + 0.5, -z / 4 + 0.5) for x, _, z in v])
    m.visual = trimesh.visual.TextureVisuals(uv=uv)
    m.vertex_attributes["rim"] = (np.arange(len(v)) > 6).astype(np.float32)
    path = tmp_path / "disc.ply"
    path.write_bytes(m.export(file_type="ply", include_attributes=True))
    mesh = load(path)
    assert mesh.has_uv and np.allclose(mesh.corner_uv, uv[mesh.triangles])
    assert np.array_equal(mesh.groups["rim"], mesh.file_index[7:])


# --------------------------------------------------------------------------------------
# The scene keys
# --------------------------------------------------------------------------------------

def mesh_scene(tmp_path, **cloth) -> Path:
    v, faces = disc()
    write(tmp_path, "disc.obj", obj_text(v, faces, groups=["all"] * len(faces)))
    body = {"mesh": "disc.obj", "thickness": 0.004, "damping": 0.2, "density": 150, "ks": 5000}
    body.update(cloth)
    body = {k: v for k, v in body.items() if v is not None}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"cloth": body}))
    return path


def scene_error(path) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    return msg[len(str(path)) + 2:]


def test_a_mesh_cloth_scene_loads(tmp_path):
    hand = {"box": [[-1, 0, -1], [1, 0.5, 1]],
            "keyframes": [{"time": 0}, {"time": 1, "translation": [0, 1, 0]}]}
    path = mesh_scene(tmp_path, translation=[0, 0.2, 0], rotation=[0, 90, 0], scale=[1, 2, 1],
                      pieces="allow", pinned=[3, hand, {"group": "all"}, 5, {"indices": [1, 2]}])
    s = load_scene(path)
    c = s.cloth
    assert c.mesh == ClothMeshSource(path=tmp_path / "disc.obj", translation=(0.0, 0.2, 0.0),
                                     rotation=(0.0, 90.0, 0.0), scale=(1.0, 2.0, 1.0),
                                     pieces_allowed=True)
    assert (c.width, c.height, c.num_width_points, c.num_height_points, c.orientation) == (
        0.0, 0.0, 0, 0, 0)
    assert c.pinned == () and c.enable_structural and c.enable_shearing and c.enable_bending
    assert [p.key for p in c.pin_selections] == [
        "cloth.pinned[0]", "cloth.pinned[1]", "cloth.pinned[2]", "cloth.pinned[3]",
        "cloth.pinned[4]"]
    p0, p1, p2, p3, p4 = c.pin_selections
    assert p0 == PinSelection("cloth.pinned[0]", indices=(3,))
    assert p1.box == ((-1.0, 0.0, -1.0), (1.0, 0.5, 1.0)) and len(p1.keyframes) == 2
    assert p1.keyframes[1].translation == (0.0, 1.0, 0.0) and p1.indices == ()
    assert p2.group == "all" and p2.box is None and p3.indices == (5,) and p4.indices == (1, 2)
    assert s.self_collision  # "auto": on for a mesh cloth
    mesh = load_cloth_mesh(c.mesh)
    assert pinned_points(mesh, c.pin_selections, str(path)).sum() > 0


def test_defaults_of_a_mesh_cloth(tmp_path):
    c = load_scene(mesh_scene(tmp_path, enable_shearing=False)).cloth
    assert c.mesh == ClothMeshSource(path=tmp_path / "disc.obj")
    assert c.enable_structural and not c.enable_shearing and c.enable_bending
    assert c.pin_selections == ()
    one = load_scene(mesh_scene(tmp_path, pinned={"group": "all"}, scale=2)).cloth
    assert one.pin_selections == (PinSelection("cloth.pinned", group="all"),)
    assert one.mesh.scale == (2.0, 2.0, 2.0)


def test_an_image_mass_map_is_allowed_on_a_mesh(tmp_path):
    hem = SCENES / "maps" / "hem.png"
    c = load_scene(mesh_scene(tmp_path, mass_map=str(hem), mass_map_range=[1, 3])).cloth
    assert c.mass_map == hem and c.mass_map_range == (1.0, 3.0)


@pytest.mark.parametrize("key, value", [("width", 1), ("height", 1), ("num_width_points", 10),
                                        ("num_height_points", 10), ("orientation", 0)])
def test_grid_keys_are_refused_with_a_mesh(tmp_path, key, value):
    assert scene_error(mesh_scene(tmp_path, **{key: value})) == (
        f"cloth.{key}: not allowed together with cloth.mesh (a mesh cloth takes its size and "
        f"shape from the file; place it with translation, rotation and scale)")


@pytest.mark.parametrize("key, value", [("translation", [0, 0, 0]), ("rotation", [0, 0, 0]),
                                        ("scale", 1), ("pieces", "allow")])
def test_placement_keys_are_refused_without_a_mesh(tmp_path, key, value):
    d = json.loads((SCENES / "pinned2.json").read_text())
    d["cloth"][key] = value
    path = tmp_path / "grid.json"
    path.write_text(json.dumps(d))
    assert scene_error(path).startswith(f"cloth.{key}: only allowed together with cloth.mesh")


@pytest.mark.parametrize("cloth, expected", [
    ({"mass_map": [[1, 2], [3, 4]]},
     "cloth.mass_map: a list of rows is for a grid cloth only: expected an image path for a "
     "mesh cloth (sampled by the mesh's uv)"),
    ({"ks": None}, "cloth.ks: missing required key (expected a number >= 0)"),
    ({"pinned": [[0, 1]]}, "cloth.pinned[0]: expected a vertex index (an integer >= 0) or a pin "
                           "object"),
    ({"pinned": [-1]}, "cloth.pinned[0]: expected a vertex index (an integer >= 0)"),
    ({"pinned": {"box": [[0, 0, 0]]}}, "cloth.pinned.box: expected a pair of points [lo, hi]"),
    ({"pinned": [{"bx": [0]}]}, "unknown key 'bx' in cloth.pinned[0] (did you mean 'box'?"),
    ({"pinned": [{"box": [[0, 0, 0], [1, 1, 1]], "group": "all"}]},
     "cloth.pinned[0]: expected exactly one of indices, box, group, got box and group"),
    ({"pinned": [{"keyframes": [{"time": 0}]}]},
     "cloth.pinned[0]: expected exactly one of indices, box, group, got none of them"),
    ({"pinned": {"box": [[0, 1, 0], [1, 0, 1]]}},
     "cloth.pinned.box: expected [lo, hi] with lo <= hi in every axis, got [[0, 1, 0], [1, 0, "
     "1]] (y: 1 > 0)"),
    ({"pinned": {"indices": []}}, "cloth.pinned.indices: expected a non-empty list of vertex"),
    ({"pinned": {"group": "a", "keyframes": [{"time": 1}, {"time": 0.5}]}},
     "cloth.pinned.keyframes[1].time: keyframes out of order"),
    ({"pieces": "maybe"}, 'cloth.pieces: expected "refuse" or "allow", got "maybe"'),
    ({"scale": [1, 0, 1]}, "cloth.scale[1]: expected a number > 0, got 0"),
    ({"scale": -1}, "cloth.scale: expected a number > 0 or a list of 3 numbers > 0, got -1"),
    ({"mesh": "nope.obj"}, "cloth.mesh: mesh file '"),
    ({"mesh": ""}, "cloth.mesh: expected a file path (a non-empty string)"),
])
def test_bad_mesh_cloth_keys(tmp_path, cloth, expected):
    msg = scene_error(mesh_scene(tmp_path, **cloth))
    assert msg.startswith(expected), msg


def test_an_unreadable_cloth_mesh_fails_at_load_with_status_2(tmp_path, capsys):
    from pipeline.cli import main

    (tmp_path / "disc.obj").write_bytes(b"\x00\x01garbage")
    bad = mesh_scene(tmp_path)
    (tmp_path / "disc.obj").write_bytes(b"v 0 0 0\n")  # no faces
    assert scene_error(bad).startswith("cloth.mesh: expected a triangle mesh, got no faces")
    (tmp_path / "disc.obj").unlink()
    out = tmp_path / "c.gif"
    code = main([str(bad), "--out", str(out), "--frames", "1"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"render: {bad}: cloth.mesh: mesh file '")
    assert "not found" in err and len(err.strip().splitlines()) == 1 and not out.exists()


def test_grid_pins_stay_pairs(tmp_path):
    d = json.loads((SCENES / "pinned2.json").read_text())
    d["cloth"]["pinned"] = [3]
    path = tmp_path / "grid.json"
    path.write_text(json.dumps(d))
    assert scene_error(path).startswith("cloth.pinned[0]: expected a pair of integers")
    d["cloth"]["pinned"] = {"box": [[0, 0, 0], [1, 1, 1]]}
    path.write_text(json.dumps(d))
    assert scene_error(path).startswith("cloth.pinned: expected a list of [x_index, y_index]")
    del d["cloth"]["enable_bending"]
    d["cloth"]["pinned"] = []
    path.write_text(json.dumps(d))
    assert scene_error(path).startswith("cloth.enable_bending: missing required key")


GRID_SCENES = sorted(p for p in SCENES.glob("*.json")
                     if "mesh" not in json.loads(p.read_text())["cloth"])


@pytest.mark.parametrize("path", GRID_SCENES, ids=lambda p: p.name)
def test_the_grid_scenes_load_as_before(path):
    raw = json.loads(path.read_text())["cloth"]
    c = load_scene(path).cloth
    assert c.mesh is None and c.pin_selections == ()
    assert (c.width, c.height, c.num_width_points, c.num_height_points, c.orientation) == (
        raw["width"], raw["height"], raw["num_width_points"], raw["num_height_points"],
        raw["orientation"])
    assert c.pinned == tuple(tuple(p) for p in raw.get("pinned", ()))
    assert (c.enable_structural, c.enable_shearing, c.enable_bending) == (
        raw["enable_structural"], raw["enable_shearing"], raw["enable_bending"])


# --------------------------------------------------------------------------------------
# The shipped meshes
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, points", [("tablecloth", (1500, 2500)),
                                          ("flag_swallowtail", (1500, 2500)),
                                          ("skirt", (1500, 2500)), ("tshirt", (2000, 3500))])
def test_the_scene_meshes_are_cloth(name, points):
    mesh = load(MESHES / f"{name}.obj")
    assert mesh.pieces == 1 and mesh.has_uv
    assert points[0] <= len(mesh.points) <= points[1]
    assert (mesh.file_index >= 0).all()  # no stray vertex
    t = mesh.triangles
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert uses.max() == 2 and (uses == 1).any()  # manifold, with a boundary (open)


def test_the_scene_meshes_shapes():
    table = load(MESHES / "tablecloth.obj")
    assert np.allclose(table.points[:, 1], 0.0) and (normals(table)[:, 1] > 0).all()
    assert np.isclose(np.linalg.norm(table.points, axis=1).max(), 0.75)
    flag = load(MESHES / "flag_swallowtail.obj")
    assert np.allclose(flag.corner_uv, flag.points[flag.triangles][..., :2] / (1.2, 0.8),
                       atol=2e-6)
    assert np.isclose(flag.points[:, 0].max(), 1.2) and np.isclose(flag.points[:, 1].max(), 0.8)
    assert flag.points[flag.groups["hoist"], 0].min() == 0.0
    skirt = load(MESHES / "skirt.obj")
    r = np.hypot(skirt.points[:, 0], skirt.points[:, 2])
    assert np.isclose(r[skirt.points[:, 1] == 0].max(), 0.16) and np.isclose(r.max(), 0.35)
    u = skirt.corner_uv[..., 0]
    assert (np.ptp(u, axis=1) < 0.1).all()  # the seam: no triangle's u runs across 0..1
    assert u.min() == 0.0 and 1.0 <= u.max() < 1.02  # u = 1 (+ half a step) across it


@pytest.mark.parametrize("name", ["round_table", "torso"])
def test_the_scene_colliders_are_closed(name):
    mesh = trimesh.load(MESHES / f"{name}.obj", force="mesh")
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0


def test_the_tshirt_fits_around_the_torso():
    shirt = load(MESHES / "tshirt.obj")
    torso = trimesh.load(MESHES / "torso.obj", force="mesh")
    # every shirt point outside the torso: rays to +x and -x cross it an even number of times
    lo, hi = torso.bounds
    inside = np.zeros(len(shirt.points), dtype=bool)
    tri = torso.triangles
    for p_index, p in enumerate(shirt.points):
        if not ((p >= lo) & (p <= hi)).all():
            continue
        inside[p_index] = _crossings(tri, p) % 2 == 1
    assert not inside.any()


def _crossings(tri: np.ndarray, p: np.ndarray) -> int:
    """Crossings of the ray p + t (1, 1e-3, 2e-3), t > 0, with the triangles (Moller-Trumbore)."""
    d = np.array([1.0, 1e-3, 2e-3])
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    h = np.cross(d, e2)
    a = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(a) > 1e-15
    f = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
    s = p - tri[:, 0]
    u = f * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = f * (q @ d)
    t = f * np.einsum("ij,ij->i", e2, q)
    return int((ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)).sum())
