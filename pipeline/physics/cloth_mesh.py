"""A cloth of any shape: a mesh file read as the cloth's points and triangles (`cloth.mesh`,
docs/scene-format.md "Mesh cloth").

`load_cloth_mesh(source)` reads the file (OBJ by this module's own reader, every other
format through trimesh), welds its vertex lines by exact position (the order of first
occurrence kept, each uv seam kept per triangle corner), drops unreferenced vertices,
places the points at R (scale * v) + translation as mesh colliders are placed, makes the
winding consistent and refuses what cannot be cloth (no triangles, degenerate triangles,
non-manifold edges, a non-orientable surface, several pieces unless allowed), each with a
one-line `SceneError` starting with the file name. `pinned_points` turns the scene's pin
selections into a pin mask over the welded points.

Imports only numpy, pipeline.scene and, lazily, trimesh (for formats other than OBJ) and
the colliders' Euler matrix (it brings numba), so that a mesh cloth and a mesh collider
given the same placement put the same file at the same place, bit for bit.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.scene import ClothMeshSource, PinSelection, SceneError


@dataclass(frozen=True, eq=False)
class ClothMesh:
    """A mesh cloth as read and checked; every array read-only.

    points      (N, 3) float64: the welded points placed in world coordinates, in the order
                of the file's vertex lines that first give each position (C-contiguous).
    triangles   (T, 3) int64 into points, in the file's face order (polygons fanned from
                their first corner), wound consistently (each shared edge runs opposite in
                its two triangles; per piece, the winding most of the file's faces had).
    corner_uv   (T, 3, 2) float64: each triangle corner's uv: the file's (a uv seam keeps
                its two sides), or, when has_uv is False, the planar projection.
    has_uv      the file gives a uv for every triangle corner.
    file_index  (V,) int64: the point of each vertex line of the file, -1 if no face uses it.
    groups      OBJ `g` / `o` group name (or PLY vertex attribute name) -> sorted unique
                point indices (OBJ: the points of the group's faces; PLY: the vertices whose
                attribute is non-zero).
    pieces      connected pieces (points joined through triangles).
    """

    path: Path
    points: np.ndarray
    triangles: np.ndarray
    corner_uv: np.ndarray
    has_uv: bool
    file_index: np.ndarray
    groups: dict[str, np.ndarray]
    pieces: int


def load_cloth_mesh(source: ClothMeshSource) -> ClothMesh:
    """Read, weld, place and check the mesh of `cloth.mesh` (cached per file, modification
    time and placement). Raises `SceneError` ("<mesh file>: <what is wrong>")."""
    path = Path(source.path)
    try:
        st = os.stat(path)
    except OSError as e:
        raise SceneError(f"{path}: cannot read the cloth mesh: {e.strerror or e}") from None
    return _load(str(path), st.st_mtime_ns, st.st_size, tuple(source.translation),
                 tuple(source.rotation), tuple(source.scale), bool(source.pieces_allowed))


def pinned_points(mesh: ClothMesh, selections: tuple[PinSelection, ...],
                  scene_file: str) -> np.ndarray:
    """(N,) uint8, 1 where a point is pinned by any of `selections` (`Cloth.pin_selections`):
    vertex indices of the file (through the welding), points inside a box (bounds included,
    world coordinates), the points of a group. Keyframes are not looked at here. Raises
    `SceneError` ("<scene file>: <selection key>: ...") for an index out of range or of an
    unused vertex, an unknown group, or a selection that catches no point."""
    pinned = np.zeros(len(mesh.points), dtype=np.uint8)
    name = mesh.path.name
    for sel in selections:
        where = f"{scene_file}: {sel.key}"
        if sel.box is not None:
            lo, hi = np.asarray(sel.box[0], dtype=float), np.asarray(sel.box[1], dtype=float)
            inside = np.all((mesh.points >= lo) & (mesh.points <= hi), axis=1)
            chosen = np.flatnonzero(inside)
            if len(chosen) == 0:
                raise SceneError(
                    f"{where}: the box [{_vec(lo)}, {_vec(hi)}] holds no point of the cloth "
                    f"(its points, as placed, span [{_vec(mesh.points.min(axis=0))}, "
                    f"{_vec(mesh.points.max(axis=0))}])")
        elif sel.group is not None:
            if sel.group not in mesh.groups:
                have = ", ".join(repr(g) for g in mesh.groups) or "none"
                raise SceneError(f"{where}: no group {sel.group!r} in {name} (its groups: "
                                 f"{have})")
            chosen = mesh.groups[sel.group]
        else:
            count = len(mesh.file_index)
            idx = np.asarray(sel.indices, dtype=np.int64)
            for i in idx:
                if not 0 <= i < count:
                    raise SceneError(f"{where}: vertex index {int(i)} is out of range "
                                     f"({name} has {count} vertices: 0 to {count - 1})")
                if mesh.file_index[i] < 0:
                    raise SceneError(f"{where}: vertex {int(i)} of {name} is used by no "
                                     f"face (unused vertices are not part of the cloth)")
            chosen = mesh.file_index[idx]
        if len(chosen) == 0:
            raise SceneError(f"{where}: the selection catches no point of the cloth")
        pinned[chosen] = 1
    return pinned


# --------------------------------------------------------------------------------------
# Reading: file vertex lines, triangles over them, per-corner uv, groups
# --------------------------------------------------------------------------------------

@dataclass
class _Raw:
    vertices: np.ndarray  # (V, 3) float64, one row per vertex line of the file
    triangles: np.ndarray  # (T, 3) int64 into vertices, file face order
    corner_uv: np.ndarray | None  # (T, 3, 2) when every corner has a uv
    face_groups: dict[str, np.ndarray]  # name -> triangle indices (OBJ)
    vertex_groups: dict[str, np.ndarray]  # name -> vertex indices (PLY attributes)


def _read(path: Path) -> _Raw:
    if path.suffix.lower() == ".obj":
        return _read_obj(path)
    return _read_trimesh(path)


def _read_obj(path: Path) -> _Raw:
    """A Wavefront OBJ: v, vt, f (any polygon, fanned from its first corner; negative
    indices relative), g and o. Our own reader because trimesh's OBJ loader splits vertices
    per (v, vt, vn) combination without giving back the vertex line each one came from (pins
    by index name the file's vertex lines), and gives `g`/`o` groups only as separate
    geometries with their faces reordered."""
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as e:
        raise SceneError(f"{path}: cannot read the cloth mesh: {e.strerror or e}") from None
    verts: list[tuple[float, float, float]] = []
    uvs: list[tuple[float, float]] = []
    tris: list[tuple[int, int, int]] = []
    tri_uv: list[tuple[int, int, int]] = []  # vt index per corner, _NO_UV when absent
    face_groups: dict[str, list[int]] = {}
    current: list[str] = []  # the names of the g line in effect
    obj_name: str | None = None
    text = text.replace("\\\r\n", " ").replace("\\\n", " ")
    for number, line in enumerate(text.splitlines(), start=1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        tag = parts[0]
        try:
            if tag == "v":
                verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
            elif tag == "vt":
                uvs.append((float(parts[1]), float(parts[2]) if len(parts) > 2 else 0.0))
            elif tag == "f":
                corners = parts[1:]
                if len(corners) < 3:
                    raise ValueError(f"a face needs at least 3 vertices, got {len(corners)}")
                vi, ti = [], []
                for c in corners:
                    fields = c.split("/")
                    vi.append(_obj_index(fields[0], len(verts)))
                    ti.append(_obj_index(fields[1], len(uvs))
                              if len(fields) > 1 and fields[1] else _NO_UV)
                first = len(tris)
                for k in range(1, len(vi) - 1):
                    tris.append((vi[0], vi[k], vi[k + 1]))
                    tri_uv.append((ti[0], ti[k], ti[k + 1]))
                names = list(current) + ([obj_name] if obj_name is not None else [])
                for name in dict.fromkeys(names):
                    face_groups.setdefault(name, []).extend(range(first, len(tris)))
            elif tag == "g":
                current = parts[1:]
            elif tag == "o":
                obj_name = " ".join(parts[1:]) or None
        except (ValueError, IndexError) as e:
            why = str(e) if isinstance(e, ValueError) and str(e) else "malformed line"
            raise SceneError(f"{path}: cannot read as an OBJ mesh: line {number}: {why}: "
                             f"{line.strip()[:60]!r}") from None
    vertices = np.array(verts, dtype=np.float64).reshape(-1, 3)
    triangles = np.array(tris, dtype=np.int64).reshape(-1, 3)
    _check_indices(path, triangles, len(vertices), "vertex")
    corner_uv = None
    t_idx = np.array(tri_uv, dtype=np.int64).reshape(-1, 3)
    if len(t_idx) and (t_idx != _NO_UV).all():  # a uv at every corner (else: the projection)
        _check_indices(path, t_idx, len(uvs), "texture vertex")
        corner_uv = np.array(uvs, dtype=np.float64).reshape(-1, 2)[t_idx]
    return _Raw(vertices, triangles, corner_uv,
                {k: np.array(v, dtype=np.int64) for k, v in face_groups.items()}, {})


_NO_UV = -(1 << 62)  # a face corner without a vt index


def _obj_index(field: str, count: int) -> int:
    i = int(field)
    if i == 0:
        raise ValueError("index 0 (OBJ indices start at 1)")
    return i - 1 if i > 0 else count + i


def _check_indices(path: Path, triangles: np.ndarray, count: int, what: str) -> None:
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= count):
        bad = triangles[(triangles < 0) | (triangles >= count)][0]
        face = int(np.flatnonzero(((triangles < 0) | (triangles >= count)).any(axis=1))[0])
        raise SceneError(f"{path}: cannot read the cloth mesh: triangle {face} uses {what} "
                         f"{int(bad) + 1} (1-based) of {count}")


_PLY_STANDARD = frozenset({"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha",
                           "r", "g", "b", "a", "s", "t", "u", "v", "texture_u", "texture_v",
                           "texture_s", "texture_t", "quality", "confidence", "intensity"})


def _read_trimesh(path: Path) -> _Raw:
    """Every other format, through trimesh without processing: its vertices are the file's
    (STL: three per facet; PLY: its vertex rows, `fix_texture` off so that seams do not
    reorder them), its faces triangulated by trimesh."""
    import trimesh

    kwargs = {"fix_texture": False} if path.suffix.lower() == ".ply" else {}
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False, **kwargs)
    except Exception as e:  # trimesh raises many kinds for unreadable files
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise SceneError(f"{path}: cannot read the cloth mesh (OBJ, PLY, STL, glTF, OFF, "
                         f"...): {why}") from None
    faces = getattr(mesh, "faces", None)
    if faces is None or not hasattr(mesh, "vertices"):
        raise SceneError(f"{path}: no triangles: a cloth mesh needs faces")
    vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    _check_indices(path, triangles, len(vertices), "vertex")
    corner_uv = None
    uv = getattr(getattr(mesh, "visual", None), "uv", None)
    if uv is not None and len(uv) == len(vertices):
        corner_uv = np.asarray(uv, dtype=np.float64)[:, :2][triangles]
    vertex_groups: dict[str, np.ndarray] = {}
    raw = getattr(mesh, "metadata", {}).get("_ply_raw")
    if raw:
        corner_uv = _ply_face_uv(raw, triangles, corner_uv)
        vertex_groups = _ply_groups(raw, len(vertices))
    return _Raw(vertices, triangles, corner_uv, {}, vertex_groups)


def _ply_face_uv(raw, triangles: np.ndarray, fallback):
    """A PLY's per-corner `texcoord` list (seams kept), when every face is a triangle."""
    data = raw.get("face", {}).get("data")
    try:
        tex = data["texcoord"]
        tex = tex["f1"] if getattr(tex, "dtype", None) is not None and tex.dtype.names else tex
        tex = np.asarray(tex, dtype=np.float64)
    except (KeyError, ValueError, TypeError, IndexError):
        return fallback
    if tex.shape == (len(triangles), 6):
        return tex.reshape(-1, 3, 2)
    return fallback


def _ply_groups(raw, count: int) -> dict[str, np.ndarray]:
    data = raw.get("vertex", {}).get("data")
    names = (list(data.dtype.names or ()) if isinstance(data, np.ndarray)
             else list(data) if isinstance(data, dict) else [])
    groups = {}
    for name in names:
        if name.lower() in _PLY_STANDARD:
            continue
        try:
            values = np.asarray(data[name])
        except (KeyError, ValueError):
            continue
        if values.size == count and values.dtype.kind in "biuf":  # ASCII: (count, 1)
            groups[name] = np.flatnonzero(values.reshape(-1) != 0)
    return groups


# --------------------------------------------------------------------------------------
# Welding, placing, checking
# --------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=8)
def _load(path: str, mtime_ns: int, size: int, translation: tuple, rotation: tuple,
          scale: tuple, pieces_allowed: bool) -> ClothMesh:
    file = Path(path)
    raw = _read(file)
    if len(raw.triangles) == 0:
        raise SceneError(f"{file}: no triangles: a cloth mesh needs faces (the file has "
                         f"{len(raw.vertices)} vertices and no face)")
    if not np.isfinite(raw.vertices[np.unique(raw.triangles)]).all():
        raise SceneError(f"{file}: a vertex has a coordinate that is not a finite number")

    # weld: one point per distinct position among the vertex lines faces use, numbered in
    # the order of the first such line (+ 0.0 makes -0.0 and 0.0 one position)
    count = len(raw.vertices)
    used = np.zeros(count, dtype=bool)
    used[raw.triangles.ravel()] = True
    lines = np.flatnonzero(used)
    positions = raw.vertices[lines] + 0.0
    _, first, inverse = np.unique(positions, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    file_index = np.full(count, -1, dtype=np.int64)
    file_index[lines] = rank[inverse.ravel()]
    first_line = lines[first[order]]  # each point's first vertex line (for messages)
    triangles = file_index[raw.triangles]
    points = _place(np.ascontiguousarray(positions[first[order]]), translation, rotation,
                    scale)

    _check_degenerate(file, points, triangles)
    edges, faces_of_edge = _edges(file, triangles, first_line)
    flip = _orient(file, triangles, edges, faces_of_edge)
    triangles = triangles.copy()
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    pieces = _count_pieces(triangles, len(points))
    if pieces > 1 and not pieces_allowed:
        raise SceneError(f'{file}: {pieces} separate pieces; set cloth.pieces to "allow" to '
                         f"simulate them together")

    has_uv = raw.corner_uv is not None
    if has_uv:
        corner_uv = raw.corner_uv.copy()
        corner_uv[flip] = corner_uv[flip][:, [0, 2, 1]]
    else:
        corner_uv = _planar_uv(points, triangles)[triangles]
    groups = {name: np.unique(triangles[faces]) for name, faces in raw.face_groups.items()}
    for name, verts in raw.vertex_groups.items():
        mapped = file_index[verts]
        groups.setdefault(name, np.unique(mapped[mapped >= 0]))
    arrays = [points, triangles, corner_uv, file_index, *groups.values()]
    for a in arrays:
        a.flags.writeable = False
    return ClothMesh(path=file, points=points, triangles=np.ascontiguousarray(triangles),
                     corner_uv=np.ascontiguousarray(corner_uv), has_uv=has_uv,
                     file_index=file_index, groups=groups, pieces=pieces)


def _place(points: np.ndarray, translation: tuple, rotation: tuple, scale: tuple
           ) -> np.ndarray:
    """R (scale * v) + translation, exactly as pipeline.physics.colliders.mesh places a
    collider: the same matrix, and the arithmetic of trimesh's transform_points (repeated
    here so that reading an OBJ does not import trimesh; a test compares the two)."""
    from pipeline.physics.colliders import euler_matrix

    matrix = np.eye(4)
    matrix[:3, :3] = euler_matrix(rotation) * np.asarray(scale, dtype=float)[None, :]
    matrix[:3, 3] = translation
    if np.abs(matrix - np.eye(4)).max() < 1e-8:  # trimesh's shortcut for the identity
        return np.ascontiguousarray(points.copy(), dtype=np.float64)
    stack = np.column_stack((points, np.ones(len(points))))
    return np.ascontiguousarray(np.dot(matrix, stack.T).T[:, :3], dtype=np.float64)


def _check_degenerate(file: Path, points: np.ndarray, triangles: np.ndarray) -> None:
    """Zero-area triangles: two corners welded into one point, or a height below 1e-12 of
    the longest side (collinear corners)."""
    a, b, c = (points[triangles[:, k]] for k in range(3))
    twice_area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    longest = np.max([np.sum((b - a) ** 2, axis=1), np.sum((c - b) ** 2, axis=1),
                      np.sum((a - c) ** 2, axis=1)], axis=0)
    repeated = ((triangles[:, 0] == triangles[:, 1]) | (triangles[:, 1] == triangles[:, 2])
                | (triangles[:, 0] == triangles[:, 2]))
    bad = repeated | (twice_area <= 1e-12 * longest)
    if bad.any():
        n, first = int(bad.sum()), int(np.flatnonzero(bad)[0])
        raise SceneError(f"{file}: {n} degenerate (zero-area) triangle{'s' * (n != 1)} after "
                         f"welding vertices at the same position; the first is triangle "
                         f"{first} (0-based, polygons fanned into triangles)")


def _edges(file: Path, triangles: np.ndarray, first_line: np.ndarray):
    """The mesh's undirected edges and, per edge, its (face, corner) uses. Refuses an edge
    shared by three or more triangles. Returns (edge id per (face, corner), a (E, 2) array
    of the two uses of every edge, -1 for a boundary edge's second use)."""
    a = triangles.ravel()
    b = triangles[:, [1, 2, 0]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * (int(triangles.max()) + 1) + hi
    uniq, edge_of, counts = np.unique(key, return_inverse=True, return_counts=True)
    edge_of = edge_of.ravel()
    if (counts > 2).any():
        over = np.flatnonzero(counts > 2)
        # the one of them the file reaches first
        uses = np.flatnonzero(np.isin(edge_of, over))
        e = edge_of[uses[0]]
        va, vb = int(first_line[lo[uses[0]]]), int(first_line[hi[uses[0]]])
        raise SceneError(f"{file}: {len(over)} non-manifold edge{'s' * (len(over) != 1)} (three "
                         f"or more triangles on one edge); e.g. the edge between vertices "
                         f"{va} and {vb} (0-based, the file's vertex order) has "
                         f"{int(counts[e])} triangles")
    order = np.argsort(edge_of, kind="stable")
    starts = np.searchsorted(edge_of[order], np.arange(len(uniq)))
    pair = np.full((len(uniq), 2), -1, dtype=np.int64)
    pair[:, 0] = order[starts]
    second = counts == 2
    pair[second, 1] = order[starts[second] + 1]
    return edge_of, pair


def _orient(file: Path, triangles: np.ndarray, edge_of: np.ndarray, pair: np.ndarray
            ) -> np.ndarray:
    """Which triangles to flip so that every interior edge runs opposite in its two
    triangles: breadth first from the first triangle of each edge-connected part; a part
    keeps the winding most of its triangles had in the file (its first triangle's on a tie).
    Refuses a non-orientable surface."""
    t = len(triangles)
    a = triangles.ravel()
    inner = pair[pair[:, 1] >= 0]
    u, v = inner[:, 0], inner[:, 1]  # (face * 3 + corner) uses of each interior edge
    # the same direction in both triangles: their windings disagree
    same = a[u] == a[v]
    fu, fv = u // 3, v // 3
    neighbours: list[list[tuple[int, bool]]] = [[] for _ in range(t)]
    for x, y, s in zip(fu.tolist(), fv.tolist(), same.tolist()):
        neighbours[x].append((y, s))
        neighbours[y].append((x, s))
    flip = np.zeros(t, dtype=bool)
    seen = np.zeros(t, dtype=bool)
    for start in range(t):
        if seen[start]:
            continue
        seen[start] = True
        part, queue = [start], [start]
        while queue:
            f = queue.pop()
            for g, s in neighbours[f]:
                want = flip[f] ^ s
                if not seen[g]:
                    seen[g] = True
                    flip[g] = want
                    part.append(g)
                    queue.append(g)
                elif flip[g] != want:
                    raise SceneError(f"{file}: not orientable (like a Moebius strip): its "
                                     f"triangles cannot all be wound the same way round "
                                     f"(around triangle {f})")
        if 2 * int(flip[part].sum()) > len(part):
            flip[part] = ~flip[part]
    return flip


def _count_pieces(triangles: np.ndarray, n: int) -> int:
    """Connected pieces: points joined through triangles."""
    label = np.arange(n)
    while True:
        m = label[triangles].min(axis=1)
        new = label.copy()
        for k in range(3):
            np.minimum.at(new, triangles[:, k], m)
        while True:  # jump to the representatives' representatives
            nxt = new[new]
            if np.array_equal(nxt, new):
                break
            new = nxt
        if np.array_equal(new, label):
            break
        label = new
    return len(np.unique(label))


def _planar_uv(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N, 2) uv of the points projected onto the plane of their two largest principal
    axes, scaled by the larger extent into [0, 1] (aspect kept). In that plane u runs along
    the world axis most nearly in the plane (x, then y, then z on a tie), and v = n x u
    with n the plane's normal turned to the side the triangles face, so the projection is
    not mirrored seen from the cloth's front."""
    centre = points.mean(axis=0)
    d = points - centre
    _, vectors = np.linalg.eigh(d.T @ d)
    n = vectors[:, 0]  # the smallest principal axis: the plane's normal
    a, b, c = (points[triangles[:, k]] for k in range(3))
    facing = np.cross(b - a, c - a).sum(axis=0)
    side = float(facing @ n)
    if side < 0.0 or (side == 0.0 and n[np.argmax(np.abs(n))] < 0.0):
        n = -n
    axis = np.eye(3)[int(np.argmin(np.abs(n)))]
    u_dir = axis - (axis @ n) * n
    u_dir /= np.linalg.norm(u_dir)
    v_dir = np.cross(n, u_dir)
    uv = np.column_stack([d @ u_dir, d @ v_dir])
    uv -= uv.min(axis=0)
    extent = float(uv.max())
    return uv / extent if extent > 0.0 else uv


def _vec(v) -> str:
    return "[" + ", ".join(f"{float(x):.6g}" for x in v) + "]"
