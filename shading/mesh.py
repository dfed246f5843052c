"""Render meshes (SPEC section 3): the cloth grid, sphere and plane colliders.

A `Mesh` is plain arrays. Normals are area weighted (normalised sum of the unnormalised
triangle cross products), tangents the summed per-triangle dP/du made orthogonal to the
normal (Gram-Schmidt) and normalised. Both are computed by one numba kernel, fast enough
to be rebuilt every frame for the cloth.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from clothjit import njit, read_only

CLOTH_COLOUR = (1.0, 1.0, 1.0)
SPHERE_COLOUR = (1.0, 1.0, 1.0)
PLANE_COLOUR = (0.7, 0.7, 0.7)
SPHERE_SCALE = 0.92  # a sphere collider is drawn at 0.92 of its radius
SPHERE_SEGMENTS = 40  # 40 x 40 latitude / longitude cells
PLANE_HALF_SIDE = 2.0
PLANE_CELLS = 8  # the 4 x 4 square is an 8 x 8 grid (nicer wireframe, same shading)
PLANE_UV_REPEAT = 4.0  # uv spans [0, 4]: one texture tile per metre, as on the 1 m cloth


@dataclass(eq=False)
class Mesh:
    """One drawable object. All arrays C-contiguous.

    positions (V,3) float64, normals (V,3) float64 unit, uvs (V,2) float64,
    tangents (V,3) float64 unit, triangles (T,3) int32, colour k_d (3,) float64,
    edges (E,2) int32 or None: the lines the wireframe shader draws, shader: the name of
    a shader of its own (drawing triangles), None: the frame's.
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    tangents: np.ndarray
    triangles: np.ndarray
    colour: np.ndarray = field(default_factory=lambda: np.ones(3))
    edges: np.ndarray | None = None
    name: str = ""
    shader: str | None = None

    def __post_init__(self):
        self.positions = np.ascontiguousarray(self.positions, dtype=np.float64)
        self.normals = np.ascontiguousarray(self.normals, dtype=np.float64)
        self.uvs = np.ascontiguousarray(self.uvs, dtype=np.float64)
        self.tangents = np.ascontiguousarray(self.tangents, dtype=np.float64)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int32)
        self.colour = np.ascontiguousarray(np.broadcast_to(
            np.asarray(self.colour, dtype=np.float64), (3,)))
        if self.edges is not None:
            self.edges = np.ascontiguousarray(self.edges, dtype=np.int32).reshape(-1, 2)


@njit(cache=True, error_model="numpy")
def _normals_tangents(pos, uv, tris, weld_n, weld_t, nrm, tan):
    """Area-weighted vertex normals and Gram-Schmidt tangents, written into nrm, tan.

    weld_n / weld_t map each vertex to the vertex whose sums it shares (seam and pole
    duplicates of the sphere are welded); empty arrays mean the identity (the cloth).
    """
    nv = pos.shape[0]
    welded_n = weld_n.shape[0] > 0
    welded_t = weld_t.shape[0] > 0
    accn = np.zeros((nv, 3))
    acct = np.zeros((nv, 3))
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        e1x = pos[b, 0] - pos[a, 0]
        e1y = pos[b, 1] - pos[a, 1]
        e1z = pos[b, 2] - pos[a, 2]
        e2x = pos[c, 0] - pos[a, 0]
        e2y = pos[c, 1] - pos[a, 1]
        e2z = pos[c, 2] - pos[a, 2]
        cx = e1y * e2z - e1z * e2y
        cy = e1z * e2x - e1x * e2z
        cz = e1x * e2y - e1y * e2x
        du1 = uv[b, 0] - uv[a, 0]
        dv1 = uv[b, 1] - uv[a, 1]
        du2 = uv[c, 0] - uv[a, 0]
        dv2 = uv[c, 1] - uv[a, 1]
        r = du1 * dv2 - du2 * dv1
        tx = 0.0
        ty = 0.0
        tz = 0.0
        if r != 0.0:
            tx = (e1x * dv2 - e2x * dv1) / r
            ty = (e1y * dv2 - e2y * dv1) / r
            tz = (e1z * dv2 - e2z * dv1) / r
        for k in range(3):
            v = tris[t, k]
            wn = weld_n[v] if welded_n else v
            accn[wn, 0] += cx
            accn[wn, 1] += cy
            accn[wn, 2] += cz
            wt = weld_t[v] if welded_t else v
            acct[wt, 0] += tx
            acct[wt, 1] += ty
            acct[wt, 2] += tz
    for v in range(nv):
        wn = weld_n[v] if welded_n else v
        nx = accn[wn, 0]
        ny = accn[wn, 1]
        nz = accn[wn, 2]
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 0.0:
            nx /= ln
            ny /= ln
            nz /= ln
        else:
            nx = 0.0
            ny = 0.0
            nz = 1.0
        wt = weld_t[v] if welded_t else v
        tx = acct[wt, 0]
        ty = acct[wt, 1]
        tz = acct[wt, 2]
        d = tx * nx + ty * ny + tz * nz
        tx -= d * nx
        ty -= d * ny
        tz -= d * nz
        lt = np.sqrt(tx * tx + ty * ty + tz * tz)
        if lt > 1e-300:
            tx /= lt
            ty /= lt
            tz /= lt
        else:  # no usable dP/du: any unit vector orthogonal to n
            if abs(nx) < 0.9:
                tx, ty, tz = 0.0, nz, -ny  # n x (1,0,0) up to sign
            else:
                tx, ty, tz = -nz, 0.0, nx
            lt = np.sqrt(tx * tx + ty * ty + tz * tz)
            tx /= lt
            ty /= lt
            tz /= lt
        nrm[v, 0] = nx
        nrm[v, 1] = ny
        nrm[v, 2] = nz
        tan[v, 0] = tx
        tan[v, 1] = ty
        tan[v, 2] = tz


_NO_WELD = np.zeros(0, np.int64)


def normals_tangents(positions, uvs, triangles, weld_n=None, weld_t=None):
    """(normals, tangents) of a triangle mesh per SPEC section 3."""
    positions = read_only(np.ascontiguousarray(positions, dtype=np.float64))
    uvs = read_only(np.ascontiguousarray(uvs, dtype=np.float64))
    triangles = read_only(np.ascontiguousarray(triangles, dtype=np.int32))
    nv = positions.shape[0]
    weld_n = read_only(_NO_WELD if weld_n is None
                       else np.ascontiguousarray(weld_n, dtype=np.int64))
    weld_t = read_only(_NO_WELD if weld_t is None
                       else np.ascontiguousarray(weld_t, dtype=np.int64))
    nrm = np.empty((nv, 3))
    tan = np.empty((nv, 3))
    _normals_tangents(positions, uvs, triangles, weld_n, weld_t, nrm, tan)
    return nrm, tan


@lru_cache(maxsize=16)
def cloth_topology(nw: int, nh: int):
    """(triangles (T,3) int32, uvs (N,2)) of an nw x nh grid; read-only, cached."""
    i, j = np.meshgrid(np.arange(nh - 1), np.arange(nw - 1), indexing="ij")
    a = (i * nw + j).ravel()
    b = a + 1
    c = a + nw
    d = c + 1
    tris = np.empty((a.size * 2, 3), dtype=np.int32)
    tris[0::2] = np.stack([a, c, b], axis=1)  # (A, C, B)
    tris[1::2] = np.stack([b, c, d], axis=1)  # (B, C, D)
    ii, jj = np.meshgrid(np.arange(nh), np.arange(nw), indexing="ij")
    uvs = np.stack([jj.ravel() / max(nw - 1, 1), ii.ravel() / max(nh - 1, 1)], axis=1)
    tris.flags.writeable = False
    uvs.flags.writeable = False
    return tris, uvs


def cloth_mesh(positions, nw: int, nh: int, edges=None, colour=CLOTH_COLOUR) -> Mesh:
    """The cloth grid (row-major points, row i, column j) as a Mesh.

    edges: optional (E,2) point-index pairs drawn by the wireframe shader (the enabled
    springs). Triangles and uvs are shared between calls with the same grid size.
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64).reshape(nw * nh, 3)
    tris, uvs = cloth_topology(int(nw), int(nh))
    nrm, tan = normals_tangents(positions, uvs, tris)
    return Mesh(positions, nrm, uvs, tan, tris, np.asarray(colour, dtype=np.float64),
                edges, "cloth")


@dataclass(frozen=True, eq=False)
class Seams:
    """How a cloth given as triangles with a uv per corner is drawn: one render vertex per
    distinct (point, uv), so uv seams stay sharp while the normals are welded across them
    (SPEC section 3). Arrays read-only."""

    triangles: np.ndarray  # (T, 3) int32 render vertices
    point: np.ndarray  # (V,) int64: the cloth point of each render vertex
    uvs: np.ndarray  # (V, 2) float64
    weld: np.ndarray  # (V,) int64: the render vertex whose normal sums it shares
    edges: np.ndarray | None  # (E, 2) int32 wireframe lines between render vertices


def cloth_seams(triangles, corner_uv, edges=None) -> Seams:
    """The Seams of a cloth of `triangles` (T, 3) points with `corner_uv` (T, 3, 2); `edges`
    (E, 2) point pairs for the wireframe, drawn between each point's first render vertex."""
    tris = np.asarray(triangles, dtype=np.int64)
    corners = np.concatenate([tris.reshape(-1, 1).astype(np.float64),
                              np.asarray(corner_uv, dtype=np.float64).reshape(-1, 2)], axis=1)
    _, first, inverse = np.unique(corners, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # render vertices in order of first corner
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vertex = rank[inverse.reshape(-1)]
    point = tris.reshape(-1)[first[order]]
    uvs = corners[first[order], 1:]
    first_of_point = np.full(int(tris.max()) + 1, -1, dtype=np.int64)
    first_of_point[point[::-1]] = np.arange(len(point))[::-1]
    weld = first_of_point[point]
    lines = None if edges is None else first_of_point[np.asarray(edges)].astype(np.int32)
    out = Seams(vertex.reshape(-1, 3).astype(np.int32), point, uvs, weld, lines)
    for arr in (out.triangles, out.point, out.uvs, out.weld) + (() if lines is None else (lines,)):
        arr.flags.writeable = False
    return out


def seamed_cloth_mesh(positions, seams: Seams, colour=CLOTH_COLOUR) -> Mesh:
    """A cloth of points at `positions` (N, 3) drawn through its Seams."""
    pos = np.ascontiguousarray(np.asarray(positions, dtype=np.float64)[seams.point])
    nrm, tan = normals_tangents(pos, seams.uvs, seams.triangles, weld_n=seams.weld)
    return Mesh(pos, nrm, seams.uvs, tan, seams.triangles, np.asarray(colour, dtype=np.float64),
                seams.edges, "cloth")


@lru_cache(maxsize=4)
def _unit_sphere(n: int):
    th = np.linspace(0.0, np.pi, n + 1)  # from the +y pole down
    ph = np.linspace(0.0, 2.0 * np.pi, n + 1)
    T, PH = np.meshgrid(th, ph, indexing="ij")
    # longitude runs clockwise seen from +y so that u grows with the outward tangent
    # and the triangle order below gives outward normals
    dirs = np.stack([np.sin(T) * np.sin(PH), np.cos(T), np.sin(T) * np.cos(PH)], axis=-1)
    dirs = dirs.reshape(-1, 3)
    dirs[np.abs(dirs) < 1e-15] = 0.0
    I, J = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    uvs = np.stack([J.ravel() / n, I.ravel() / n], axis=1)
    tris = []
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j
            b, c = a + 1, a + n + 1
            d = c + 1
            if i != 0:
                tris.append((a, c, b))
            if i != n - 1:
                tris.append((b, c, d))
    tris = np.array(tris, dtype=np.int32)
    # weld the seam (j = n onto j = 0) for normals and tangents, the poles for normals
    weld_t = (I * (n + 1) + np.where(J == n, 0, J)).ravel()
    weld_n = weld_t.copy()
    weld_n[I.ravel() == 0] = 0
    weld_n[I.ravel() == n] = n * (n + 1)
    edges = []
    for i in range(1, n):  # latitude rings
        for j in range(n):
            edges.append((i * (n + 1) + j, i * (n + 1) + j + 1))
    for j in range(n):  # meridians
        for i in range(n):
            edges.append((i * (n + 1) + j, (i + 1) * (n + 1) + j))
    edges = np.array(edges, dtype=np.int32)
    for a in (dirs, uvs, tris, weld_n, weld_t, edges):
        a.flags.writeable = False
    return dirs, uvs, tris, weld_n, weld_t, edges


def sphere_mesh(origin, radius, colour=SPHERE_COLOUR, scale=SPHERE_SCALE,
                segments=SPHERE_SEGMENTS) -> Mesh:
    """A sphere collider as a segments x segments latitude/longitude mesh at scale*radius."""
    dirs, uvs, tris, weld_n, weld_t, edges = _unit_sphere(int(segments))
    pos = np.asarray(origin, dtype=np.float64) + dirs * (float(radius) * scale)
    nrm, tan = normals_tangents(pos, uvs, tris, weld_n, weld_t)
    return Mesh(pos, nrm, uvs, tan, tris, np.asarray(colour, dtype=np.float64),
                edges, "sphere")


def plane_mesh(point, normal, colour=PLANE_COLOUR, half_side=PLANE_HALF_SIDE,
               cells=PLANE_CELLS) -> Mesh:
    """A plane collider as a square of half-side 2 around `point`, facing `normal`."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    # e_v x e_u = n, as on the cloth (x, z) grid, so the (A, C, B) order faces +n
    e_u = np.cross(n, helper)
    e_u /= np.linalg.norm(e_u)
    e_v = np.cross(e_u, n)
    k = int(cells)
    s = np.linspace(-half_side, half_side, k + 1)
    I, J = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    pos = (np.asarray(point, dtype=np.float64) + s[J.ravel()][:, None] * e_u
           + s[I.ravel()][:, None] * e_v)
    tris, uvs = cloth_topology(k + 1, k + 1)
    uvs = uvs * PLANE_UV_REPEAT
    nrm, tan = normals_tangents(pos, uvs, tris)
    edges = []
    for i in range(k + 1):
        for j in range(k):
            edges.append((i * (k + 1) + j, i * (k + 1) + j + 1))
            edges.append((j * (k + 1) + i, (j + 1) * (k + 1) + i))
    return Mesh(pos, nrm, uvs, tan, tris, np.asarray(colour, dtype=np.float64),
                np.array(edges, dtype=np.int32), "plane")


def box_mesh(center, half_extents, rotation, colour=SPHERE_COLOUR, cells=4) -> Mesh:
    """An oriented box (rotation: 3x3 matrix, box axes as columns) as six faces of
    cells x cells quads each, with their own vertices so the edges stay sharp."""
    rot = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
    h = np.asarray(half_extents, dtype=np.float64)
    tris, uvs = cloth_topology(cells + 1, cells + 1)
    s = np.linspace(-1.0, 1.0, cells + 1)
    I, J = np.meshgrid(np.arange(cells + 1), np.arange(cells + 1), indexing="ij")
    a, b = s[J.ravel()], s[I.ravel()]
    positions, all_uvs, triangles, edges = [], [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            # face axes u (columns), v (rows) with v x u = the outward normal: then the
            # (A, C, B) triangles face outwards, as on the plane mesh
            u_axis, v_axis = (axis + 2) % 3, (axis + 1) % 3
            if sign < 0:
                u_axis, v_axis = v_axis, u_axis
            local = np.zeros((a.size, 3))
            local[:, axis] = sign
            local[:, u_axis] = a
            local[:, v_axis] = b
            base = len(positions) * a.size
            positions.append(local * h)
            all_uvs.append(uvs)
            triangles.append(tris + base)
            ring = [0, cells, (cells + 1) * (cells + 1) - 1, cells * (cells + 1)]
            edges.extend((base + ring[k], base + ring[(k + 1) % 4]) for k in range(4))
    pos = np.concatenate(positions) @ rot.T + np.asarray(center, dtype=np.float64)
    uv = np.concatenate(all_uvs)
    tri = np.concatenate(triangles).astype(np.int32)
    nrm, tan = normals_tangents(pos, uv, tri)
    return Mesh(pos, nrm, uv, tan, tri, np.asarray(colour, dtype=np.float64),
                np.array(edges, dtype=np.int32), "box")


def triangle_mesh(vertices, faces, colour=SPHERE_COLOUR, name="mesh") -> Mesh:
    """A triangle mesh (a mesh collider) with smooth area-weighted normals; uvs are a planar
    projection (x + z, y), enough for the texture-based shaders."""
    pos = np.ascontiguousarray(vertices, dtype=np.float64)
    tri = np.ascontiguousarray(faces, dtype=np.int32)
    uv = np.stack([pos[:, 0] + pos[:, 2], pos[:, 1]], axis=1)
    nrm, tan = normals_tangents(pos, uv, tri)
    edges = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]),
                              axis=1), axis=0)
    return Mesh(pos, nrm, uv, tan, tri, np.asarray(colour, dtype=np.float64), edges, name)
