"""Robust mesh colliders (`simulation.contact` "robust"): the mesh counterpart of
pipeline.physics.collider_contact, on the mesh's own triangles rather than its distance
grid's level set (which the course's pass, run before, keeps).

Each mesh is worked in its rest frame, the point's path the straight line from its
start-of-step position under the start pose to its position under the end pose (as
collider_contact). Its triangles sit in a uniform grid of cells about a triangle in size,
built once per scene (MeshContact); every query gathers the triangles of the cells a box
overlaps, each once. The mesh's distance grid (pipeline.physics.sdf) gives each point a
clearance, a radius free of the surface (_clearance): a path or an edge within such balls
needs no query (most of them: a resting cloth's points move less than theirs in a step).
1. Paths: a free point whose path crosses a triangle (a solid: enters through it from
   outside; a one-sided mesh: from either side) stops there and keeps the rest of its
   motion along the triangle's plane, SURFACE_GAP off it on the side it came from, under the
   collider's friction rule (last + (1 - friction) (target - last)). The new straight path
   is checked again (sliding into a concave crease hits the next triangle): PATH_ROUNDS at
   most, then the point stops SURFACE_GAP short of the first hit along its path.
   On a solid, a point then inside (its clearance's side, else ray parity) goes to its
   nearest surface point, SURFACE_GAP outside.
2. Edges: a cloth edge through a triangle (its ends strictly on opposite sides of the
   plane, its line through the closed triangle) is moved out. Through a solid: its point
   midway between its first and last crossings goes SURFACE_GAP beyond that point's nearest
   surface point, its ends sharing the move by inverse mass (as collider_contact's
   triangles). Through a one-sided mesh: the least of these moves that leaves it through
   no triangle: over the rim (across the line of the open edge of a triangle it passes
   through, then of the next if need be), or its free ends back where they started the
   step (clear there). Each edge's move is made at once, edge by edge in order
   (Gauss-Seidel: the edges round a mesh corner push their shared point different ways,
   whose mean can cancel), in rounds until no edge crosses (FACE_ROUNDS at most). An edge
   held there by pins, or with no clear move, is not kept.
   Pushed points' paths are clipped again (ALTERNATIONS of both at most); whatever is left
   crossing is counted as not kept (stats), as a pinned point inside a solid mesh.
Each kind (solid, one-sided) has its stages compiled as kernels of their own, only for a
scene with that kind (_kernel_of): the pass's first use compiles in about 9.5 s of CPU.
Ties: a path or an edge through a shared edge or corner of two triangles meets both (closed
triangles, exact orientation signs: no gap between triangles); a point exactly on a
triangle's plane is on neither side (as benchmarks/collider_crossings.py counts it).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from types import FunctionType
from typing import NamedTuple

import numpy as np
from numba.core import types

from clothjit import KernelPointer, njit

from . import sdf
from .ccd import _cross, _dot, _sub, orient, point_triangle_distance
from .collider_contact import (FACE_PUSHES, FACE_ROUNDS, MIN_FREE_WEIGHT, MOVED_OUT, NOT_KEPT,
                               PATH_STOPS, PIN_POINT, PIN_STEP, SURFACE_GAP, _rest, _rotate,
                               _world)

PATH_ROUNDS = 4  # slides of a path along triangles before it stops at its first hit
ALTERNATIONS = 2  # edge rounds and path clipping in turn
RIM_STEPS = 3  # rim sides an edge is taken over in one move
MAX_CELLS = 1 << 18  # of one mesh's grid of triangles
# MeshContact.grid columns: cell origin (3), cell side, its inverse, cells along x, y, z,
# the mesh's first cell in cell_start, solid (1 or 0), friction
_ORIGIN, _CELL, _INV, _NX, _FIRST, _SOLID, _FRICTION = 0, 3, 4, 5, 8, 9, 10
GRID_WIDTH = 11


class MeshContact(NamedTuple):
    """The scene's mesh colliders' triangles for the robust pass, in their rest frames."""

    row: np.ndarray  # (C,) int64: collider c's row in `grid`, -1 for other kinds
    grid: np.ndarray  # (M, GRID_WIDTH) float64, see the columns above
    corners: np.ndarray  # (F, 9) float64: each triangle's corners a, b, c
    planes: np.ndarray  # (F, 4) float64: unit normal (outward on a solid) and n . a
    rims: np.ndarray  # (F,) int64: bit j set when the edge from corner j to j + 1 is open
    cell_start: np.ndarray  # (cells + 1,) int64: cell g's triangles are
    cell_faces: np.ndarray  # cell_faces[cell_start[g]:cell_start[g + 1]] (int64)
    found: np.ndarray  # (2F,) int64 scratch: the triangles a query gathered (two at once)
    seen: np.ndarray  # (F,) int64 scratch: the last query that gathered each triangle
    query: np.ndarray  # (1,) int64 scratch: queries so far
    clear: np.ndarray  # (N,) float64 scratch: each cloth point's clearance (_clearance)


def pack_meshes(colliders: Sequence[object], points: int) -> MeshContact:
    """The MeshContact of a scene's colliders for a cloth of `points` points (no rows when
    it has no mesh collider)."""
    from .colliders import mesh

    parts, row = [], np.full(len(colliders), -1, np.int64)
    for c, obj in enumerate(colliders):
        if type(obj) is mesh.SCENE_TYPE:
            row[c] = len(parts)
            vertices, faces = mesh.collider_mesh_arrays(obj)
            parts.append((vertices, faces, bool(obj.solid), float(obj.friction)))
    if not parts:
        return _packed(row, np.zeros((0, GRID_WIDTH)), np.zeros((0, 9)), np.zeros(0, np.int64),
                       np.zeros(1, np.int64), np.zeros(0, np.int64), points)
    grids, corners, rims, start, cells, total = [], [], [], [np.zeros(1, np.int64)], [], 0
    for vertices, faces, solid, friction in parts:
        tri = vertices[faces]  # (F, 3, 3)
        if solid and np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() < 0:
            tri = tri[:, ::-1]  # wound inward: outward normals
        head, counts, faces_by_cell = _cells(tri)
        head[_FIRST], head[_SOLID], head[_FRICTION] = total, float(solid), friction
        offset = sum(len(t) for t in corners)
        grids.append(head)
        corners.append(tri.reshape(-1, 9))
        rims.append(np.zeros(len(faces), np.int64) if solid else _open_edges(faces))
        start.append(start[-1][-1] + np.cumsum(counts))
        cells.append(faces_by_cell + offset)
        total += len(counts)
    return _packed(row, np.array(grids), np.concatenate(corners), np.concatenate(rims),
                   np.concatenate(start), np.concatenate(cells), points)


def _open_edges(faces: np.ndarray) -> np.ndarray:
    """(F,) bit j set where the edge from corner j to j + 1 of a face is in no other face."""
    pairs = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2), axis=2).reshape(-1, 2)
    _, inverse, counts = np.unique(pairs, axis=0, return_inverse=True, return_counts=True)
    single = (counts[inverse.ravel()] == 1).reshape(-1, 3)
    return (single * (1 << np.arange(3))).sum(axis=1).astype(np.int64)


def _packed(row, grid, corners, rims, cell_start, cell_faces, points) -> MeshContact:
    a, b, c = corners[:, 0:3], corners[:, 3:6], corners[:, 6:9]
    n = np.cross(b - a, c - a)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    planes = np.concatenate([n, np.einsum("ij,ij->i", n, a)[:, None]], axis=1)
    f = len(corners)
    return MeshContact(row, np.ascontiguousarray(grid, np.float64),
                       np.ascontiguousarray(corners, np.float64), np.ascontiguousarray(planes),
                       np.ascontiguousarray(rims, np.int64),
                       np.ascontiguousarray(cell_start, np.int64),
                       np.ascontiguousarray(cell_faces, np.int64), np.zeros(2 * f, np.int64),
                       np.full(f, -1, np.int64), np.zeros(1, np.int64), np.zeros(points))


def _cells(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grid row without its first cell, solid and friction; triangles per cell; the
    triangles cell by cell, ascending in each) of triangles `tri` (F, 3, 3): cells of the
    triangles' mean largest side (larger if there would be more than MAX_CELLS), over their
    bounding box; each triangle in every cell its box overlaps."""
    low, high = tri.min(axis=1), tri.max(axis=1)
    origin, extent = low.min(axis=0), high.max(axis=0) - low.min(axis=0)
    cell = max(float((high - low).max(axis=1).mean()), 1e-9)
    while np.prod(np.floor(extent / cell) + 1) > MAX_CELLS:
        cell *= 1.25
    n = (np.floor(extent / cell) + 1).astype(np.int64)
    inv = 1.0 / cell  # the cells of _index to the bit: a query meets every triangle it can
    lo = np.clip(np.floor((low - origin) * inv).astype(np.int64), 0, n - 1)
    hi = np.clip(np.floor((high - origin) * inv).astype(np.int64), 0, n - 1)
    size = hi - lo + 1
    counts = size.prod(axis=1)
    face = np.repeat(np.arange(len(tri)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    sx, sy = size[face, 0], size[face, 1]
    ix = lo[face, 0] + local % sx
    iy = lo[face, 1] + (local // sx) % sy
    iz = lo[face, 2] + local // (sx * sy)
    cell_id = (iz * n[1] + iy) * n[0] + ix
    order = np.argsort(cell_id, kind="stable")
    head = np.zeros(GRID_WIDTH)
    head[_ORIGIN:_ORIGIN + 3], head[_CELL], head[_INV] = origin, cell, inv
    head[_NX:_NX + 3] = n
    return head, np.bincount(cell_id, minlength=int(n.prod())), face[order]


# --- queries -------------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _index(g, r, a, v):
    """The cell index along axis a of coordinate v, -1 or n beyond the grid."""
    n = g[r, _NX + a]
    f = min(max((v - g[r, _ORIGIN + a]) * g[r, _INV], -1.0), n)
    return math.floor(f)


@njit(cache=True, nogil=True, error_model="numpy")
def _gather(m, r, lo, hi):
    """Fill m.found with the triangles of mesh row r in the cells the box lo-hi overlaps,
    each once; returns how many."""
    g = m.grid
    nx, ny = int(g[r, _NX]), int(g[r, _NX + 1])
    i0, j0, k0 = _index(g, r, 0, lo[0]), _index(g, r, 1, lo[1]), _index(g, r, 2, lo[2])
    i1, j1, k1 = _index(g, r, 0, hi[0]), _index(g, r, 1, hi[1]), _index(g, r, 2, hi[2])
    if (i1 < 0 or j1 < 0 or k1 < 0 or i0 >= nx or j0 >= ny or k0 >= g[r, _NX + 2]):
        return 0
    i0, j0, k0 = max(i0, 0), max(j0, 0), max(k0, 0)
    i1, j1, k1 = min(i1, nx - 1), min(j1, ny - 1), min(k1, int(g[r, _NX + 2]) - 1)
    m.query[0] += 1
    stamp = m.query[0]
    first = int(g[r, _FIRST])
    count = 0
    for k in range(k0, k1 + 1):
        for j in range(j0, j1 + 1):
            cell = first + (k * ny + j) * nx
            for s in range(m.cell_start[cell + i0], m.cell_start[cell + i1 + 1]):
                f = m.cell_faces[s]
                if m.seen[f] != stamp:
                    m.seen[f] = stamp
                    m.found[count] = f
                    count += 1
    return count


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _corner(m, f, j):
    return m.corners[f, 3 * j], m.corners[f, 3 * j + 1], m.corners[f, 3 * j + 2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _height(m, f, p):
    """p's signed distance to triangle f's plane."""
    pl = m.planes
    return pl[f, 0] * p[0] + pl[f, 1] * p[1] + pl[f, 2] * p[2] - pl[f, 3]


@njit(cache=True, nogil=True, error_model="numpy")
def _line_through(m, f, p, q):
    """Whether the line p-q passes through the closed triangle f (its three orientations
    not of both signs, not all zero)."""
    a, b, c = _corner(m, f, 0), _corner(m, f, 1), _corner(m, f, 2)
    u, v, w = orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)
    if u == 0.0 and v == 0.0 and w == 0.0:
        return False
    return not ((u > 0.0 or v > 0.0 or w > 0.0) and (u < 0.0 or v < 0.0 or w < 0.0))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _turn(v, axis):
    """v's coordinates from axis `axis` on, cyclically (a right-handed turn of the axes)."""
    if axis == 0:
        return v
    if axis == 1:
        return v[1], v[2], v[0]
    return v[2], v[0], v[1]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _box(p, q, pad):
    return ((min(p[0], q[0]) - pad, min(p[1], q[1]) - pad, min(p[2], q[2]) - pad),
            (max(p[0], q[0]) + pad, max(p[1], q[1]) + pad, max(p[2], q[2]) + pad))


@njit(cache=True, nogil=True, error_model="numpy")
def _clearance(params, data, k, q):
    """(c, side): no surface of mesh collider k within c >= 0 of q, and when c > 0, q on
    `side` of it (+1 outside a solid, -1 inside). From its distance grid: a node N of q's
    cell whose distance v exceeds |q - N| (|v| is exact within the grid's band, thickness + 3
    cells, and beyond it an upper bound of a distance larger than the band: so taken at most
    3 cells); outside the grid's box, the distance to the box."""
    grid = sdf.grid_of(params, k)
    base, tx, ty, tz, in_box = sdf.locate(grid, q[0], q[1], q[2])
    h = grid[8]
    if not in_box:
        gx = max(grid[1] - q[0], q[0] - grid[1] - h * (grid[5] - 1), 0.0)
        gy = max(grid[2] - q[1], q[1] - grid[2] - h * (grid[6] - 1), 0.0)
        gz = max(grid[3] - q[2], q[2] - grid[3] - h * (grid[7] - 1), 0.0)
        return math.sqrt(gx * gx + gy * gy + gz * gz), 1.0
    nx, nxy = grid[5], grid[5] * grid[6]
    best, side = 0.0, 1.0
    for corner in range(8):
        i, j, l = corner & 1, (corner >> 1) & 1, corner >> 2
        v = data[base + i + j * nx + l * nxy]
        c = min(abs(v), 3.0 * h) - h * math.sqrt((tx - i) ** 2 + (ty - j) ** 2 + (tz - l) ** 2)
        if c > best:
            best, side = c, (1.0 if v > 0.0 else -1.0)
    return best, side


# --- stage 1: paths ------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def _first_hit(m, r, s, e, solid):
    """(u, normal towards the side s is on) of the first triangle the path s -> e meets
    (entering a solid from outside, or crossing a one-sided mesh), u in (0, 1]; u = -1 when
    it meets none."""
    lo, hi = _box(s, e, 0.0)
    best, nx, ny, nz = 2.0, 0.0, 0.0, 0.0
    for i in range(_gather(m, r, lo, hi)):
        f = m.found[i]
        d0, d1 = _height(m, f, s), _height(m, f, e)
        if not ((d0 > 0.0 and d1 <= 0.0) or (not solid and d0 < 0.0 and d1 >= 0.0)):
            continue
        u = d0 / (d0 - d1)
        if u >= best or not _line_through(m, f, s, e):
            continue
        side = 1.0 if d0 > 0.0 else -1.0
        best, nx, ny, nz = u, side * m.planes[f, 0], side * m.planes[f, 1], side * m.planes[f, 2]
    if best > 1.0:
        return -1.0, 0.0, 0.0, 0.0
    return best, nx, ny, nz


@njit(cache=True, nogil=True, error_model="numpy")
def _clip(m, r, s, e, keep, solid):
    """(end, stopped): the end of the path s -> e once clipped at the mesh and slid along
    it (stage 1), the straight path from s to it meeting no triangle."""
    q = e
    for _ in range(PATH_ROUNDS + 1):
        u, nx, ny, nz = _first_hit(m, r, s, q, solid)
        if u < 0.0:
            return q, q != e
        hx, hy, hz = s[0] + u * (q[0] - s[0]), s[1] + u * (q[1] - s[1]), s[2] + u * (q[2] - s[2])
        rx, ry, rz = q[0] - hx, q[1] - hy, q[2] - hz
        along = rx * nx + ry * ny + rz * nz
        tx = hx + rx + (SURFACE_GAP - along) * nx
        ty = hy + ry + (SURFACE_GAP - along) * ny
        tz = hz + rz + (SURFACE_GAP - along) * nz
        last = q
        q = (s[0] + keep * (tx - s[0]), s[1] + keep * (ty - s[1]), s[2] + keep * (tz - s[2]))
    # still meeting a triangle after its slides: stop short of the first hit of the last path
    length = math.sqrt((last[0] - s[0]) ** 2 + (last[1] - s[1]) ** 2 + (last[2] - s[2]) ** 2)
    back = max(u - SURFACE_GAP / length, 0.0)
    return (s[0] + back * (last[0] - s[0]), s[1] + back * (last[1] - s[1]),
            s[2] + back * (last[2] - s[2])), True


@njit(cache=True, nogil=True, error_model="numpy")
def _out_of_solid(m, r, q, params, data, k):
    """(inside, q moved out): whether q is inside solid mesh row r (collider k), by its
    clearance where the distance grid proves its side, else by ray parity along the axis
    direction with the fewest cells to the triangle grid's edge (sdf's tie-break at edges
    and corners); if so, q moved to its nearest surface point, SURFACE_GAP outside (the
    triangles searched within the grid's corner value plus the cell's diagonal: exact near
    the surface, an upper bound beyond)."""
    clear, side = _clearance(params, data, k, q)
    if clear > 0.0 and side > 0.0:
        return False, q
    g = m.grid
    axis, sign, room = 0, 1.0, math.inf
    for a in range(3):
        low = g[r, _ORIGIN + a]
        v = _turn(q, a)[0]
        if low + g[r, _NX + a] * g[r, _CELL] - v < room:
            axis, sign, room = a, 1.0, low + g[r, _NX + a] * g[r, _CELL] - v
        if v - low < room:
            axis, sign, room = a, -1.0, v - low
    far = _turn(q, axis)[0] + sign * (max(room, 0.0) + g[r, _CELL])
    lo, hi = _box(q, (far if axis == 0 else q[0], far if axis == 1 else q[1],
                      far if axis == 2 else q[2]), 0.0)
    u = _turn(q, axis)  # the ray's axis first
    crossings = 0
    for i in range(_gather(m, r, lo, hi)):
        f = m.found[i]
        ta, tb, tc = (_turn(_corner(m, f, 0), axis), _turn(_corner(m, f, 1), axis),
                      _turn(_corner(m, f, 2), axis))
        wa, sa = sdf._orientation(tb[1] - u[1], tb[2] - u[2], tc[1] - u[1], tc[2] - u[2])
        if sa == 0:
            continue
        wb, sb = sdf._orientation(tc[1] - u[1], tc[2] - u[2], ta[1] - u[1], ta[2] - u[2])
        if sb != sa:
            continue
        wc, sc = sdf._orientation(ta[1] - u[1], ta[2] - u[2], tb[1] - u[1], tb[2] - u[2])
        if sc != sa:
            continue
        at = (wa * ta[0] + wb * tb[0] + wc * tc[0]) / (wa + wb + wc)
        if sign * (at - u[0]) > 0.0:
            crossings += 1
    if crossings % 2 == 0 and not (clear > 0.0 and side < 0.0):
        return False, q
    grid = sdf.grid_of(params, k)
    base = sdf.locate(grid, q[0], q[1], q[2])[0]
    d, nx, ny, nz, cx, cy, cz = _nearest(m, r, q, abs(data[base]) + grid[9] + SURFACE_GAP)
    if d == math.inf:
        return True, q
    return True, (cx + SURFACE_GAP * nx, cy + SURFACE_GAP * ny, cz + SURFACE_GAP * nz)


@njit(cache=True, nogil=True, error_model="numpy")
def _nearest(m, r, q, reach):
    """(distance, unit direction from q, closest point) of mesh row r's nearest surface
    point to q among the triangles within `reach` (distance inf when none)."""
    lo, hi = _box(q, q, reach)
    best, f_best, cx, cy, cz = math.inf, -1, q[0], q[1], q[2]
    for i in range(_gather(m, r, lo, hi)):
        f = m.found[i]
        a, b, c = _corner(m, f, 0), _corner(m, f, 1), _corner(m, f, 2)
        d, u, v, w = point_triangle_distance(q, a, b, c)
        if d < best:
            best, f_best = d, f
            cx, cy, cz = (u * a[0] + v * b[0] + w * c[0], u * a[1] + v * b[1] + w * c[1],
                          u * a[2] + v * b[2] + w * c[2])
    if best > 0.0 and f_best >= 0:
        nx, ny, nz = (cx - q[0]) / best, (cy - q[1]) / best, (cz - q[2]) / best
    else:  # on the surface: out along the triangle's normal
        nx, ny, nz = m.planes[f_best, 0], m.planes[f_best, 1], m.planes[f_best, 2]
    return best, nx, ny, nz, cx, cy, cz


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _stays(m, r, q, params, data, k):
    """A one-sided mesh's `out_of_solid` (_paths): no inside."""
    return False, q


def _paths(x, x0, m, r, inv_mass, stats, params, data, frame, k):
    """Stage 1 for mesh row r (collider k) on every free point: (points moved, a pinned
    point inside the solid or -1). The source of the kinds' kernels (_kernel_of), in which
    `out_of_solid` is _out_of_solid or _stays."""
    solid = m.grid[r, _SOLID] != 0.0
    keep = 1.0 - m.grid[r, _FRICTION]
    moved, pin = 0, -1
    for p in range(x.shape[1]):
        e = _rest(frame, k, 1, x, p)
        if inv_mass[p] == 0.0:  # pins are not moved: one inside is counted
            if pin < 0 and out_of_solid(m, r, e, params, data, k)[0]:  # noqa: F821
                pin = p
            continue
        s = _rest(frame, k, 0, x0, p)
        clear, side = _clearance(params, data, k, e)
        if clear > _length(_sub(e, s)) and (side > 0.0 or not solid):  # no surface near
            continue
        q, stopped = _clip(m, r, s, e, keep, solid)
        inside, q = out_of_solid(m, r, q, params, data, k)  # noqa: F821 (_kernel_of's)
        if inside:
            stats[MOVED_OUT] += 1.0
        if stopped:
            stats[PATH_STOPS] += 1.0
        if stopped or inside:
            x[0, p], x[1, p], x[2, p] = _world(frame, k, q[0], q[1], q[2])
            moved += 1
    return moved, pin


# --- stage 2: edges ------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _crosses(m, f, p, q):
    """(crosses, heights of p and q): whether the segment p-q passes through triangle f."""
    dp, dq = _height(m, f, p), _height(m, f, q)
    if not ((dp > 0.0 and dq < 0.0) or (dp < 0.0 and dq > 0.0)):
        return False, dp, dq
    return _line_through(m, f, p, q), dp, dq


@njit(cache=True, nogil=True, error_model="numpy")
def _crossed(m, r, p, q):
    """A triangle of mesh row r that the segment p-q passes through, or -1."""
    lo, hi = _box(p, q, 0.0)
    for i in range(_gather(m, r, lo, hi)):
        if _crosses(m, m.found[i], p, q)[0]:
            return m.found[i]
    return -1


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _moved(p, v):
    return p[0] + v[0], p[1] + v[1], p[2] + v[2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _length(v):
    return math.sqrt(_dot(v, v))


@njit(cache=True, nogil=True, error_model="numpy")
def _over_rim(m, f, p, q, free_p, free_q):
    """(found, move of p, move of q): the least move of the segment p-q across the line of
    one of triangle f's open edges (a, b), to SURFACE_GAP beyond it: orient(p, q, a, b)
    changes sign. Both ends free: a translation along (b - a) x (q - p), in which it is
    linear; one free: that end along its gradient (linear in either end alone)."""
    best, vp, vq = math.inf, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    for j in range(3):
        if not (m.rims[f] >> j) & 1:
            continue
        a, b = _corner(m, f, j), _corner(m, f, (j + 1) % 3)
        if free_p and free_q:  # d/dv orient(p + v, q + v, a, b) = -((b - a) x (q - p))
            g = _cross(_sub(q, p), _sub(b, a))
        elif free_q:
            g = _cross(_sub(a, p), _sub(b, p))
        elif free_p:
            g = _cross(_sub(b, q), _sub(a, q))
        else:
            continue
        size = _length(g)
        if size == 0.0:
            continue
        o = orient(p, q, a, b)
        push = abs(o) / size + SURFACE_GAP
        if push < best:
            k = (-push if o > 0.0 else push) / size
            v = (k * g[0], k * g[1], k * g[2])
            best = push
            vp = v if free_p else (0.0, 0.0, 0.0)
            vq = v if free_q else (0.0, 0.0, 0.0)
    return best < math.inf, vp, vq


@njit(cache=True, nogil=True, error_model="numpy")
def _round_rim(m, r, f, p, q, free_p, free_q):
    """(found, move of p, move of q) taking the segment p-q, through one-sided triangle f,
    over the rim: across f's open edge, then across the open edge of any triangle it then
    passes through (a rim polygon's next side), RIM_STEPS at most, to pass through none."""
    vp, vq = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    for _ in range(RIM_STEPS):
        found, dp, dq = _over_rim(m, f, _moved(p, vp), _moved(q, vq), free_p, free_q)
        if not found:
            return False, vp, vq
        vp, vq = _moved(vp, dp), _moved(vq, dq)
        f = _crossed(m, r, _moved(p, vp), _moved(q, vq))
        if f < 0:
            return True, vp, vq
    return False, vp, vq


@njit(cache=True, nogil=True, error_model="numpy")
def _sheet_push(m, r, p, q, p0, q0, inv_p, inv_q):
    """(state, move of p, move of q) of the segment p-q (p0-q0 at the step's start) through
    one-sided mesh row r: state 0 through none, 1 through some and moved by the least of
    these moves that leaves it through none (the largest end move), 2 no such move:
    - per triangle it passes through, over the rim (_round_rim: caught on it);
    - its free ends back to where they started (the segment was clear there)."""
    free_p, free_q = inv_p > 0.0, inv_q > 0.0
    lo, hi = _box(p, q, 0.0)
    crossing = m.seen.shape[0]  # the triangles it passes through, listed after the first F
    count = 0  # entries of m.found (the queries below fill those)
    for i in range(_gather(m, r, lo, hi)):
        f = m.found[i]
        if _crosses(m, f, p, q)[0]:
            m.found[crossing + count] = f
            count += 1
    none = (0.0, 0.0, 0.0)
    if count == 0:
        return 0, none, none
    best, vp, vq = math.inf, none, none
    for i in range(count):
        found, cp, cq = _round_rim(m, r, m.found[crossing + i], p, q, free_p, free_q)
        size = max(_length(cp), _length(cq))
        if found and size < best:
            best, vp, vq = size, cp, cq
    back_p = _sub(p0, p) if free_p else none
    back_q = _sub(q0, q) if free_q else none
    size = max(_length(back_p), _length(back_q))
    if size < best and _crossed(m, r, _moved(p, back_p), _moved(q, back_q)) < 0:
        best, vp, vq = size, back_p, back_q
    return (1 if best < math.inf else 2), vp, vq


@njit(cache=True, nogil=True, error_model="numpy")
def _solid_push(m, r, p, q, p0, q0, inv_p, inv_q):
    """(state, move of p, move of q) of the segment p-q through solid mesh row r: state 0
    through none; 1 its point midway between its first and last crossings (or between its
    crossing and its end inside) moved out to SURFACE_GAP beyond that point's nearest
    surface point, the ends sharing the move by inverse mass (as collider_contact's
    triangles); 2 held there by pins. (p0, q0: unused, as _sheet_push takes them.)"""
    lo, hi = _box(p, q, 0.0)
    first, last, p_in = 2.0, -1.0, False
    for i in range(_gather(m, r, lo, hi)):
        f = m.found[i]
        crosses, dp, dq = _crosses(m, f, p, q)
        if crosses:
            u = dp / (dp - dq)
            if u < first:
                first, p_in = u, dp < 0.0
            last = max(last, u)
    none = (0.0, 0.0, 0.0)
    if last < 0.0:
        return 0, none, none
    if first == last:  # one crossing: an end is inside
        last = 0.0 if p_in else 1.0
    mid = 0.5 * (first + last)
    wp, wq = (1.0 - mid) * inv_p, mid * inv_q
    free = (1.0 - mid if inv_p > 0.0 else 0.0) + (mid if inv_q > 0.0 else 0.0)
    if free < MIN_FREE_WEIGHT:
        return 2, none, none
    c = (p[0] + mid * (q[0] - p[0]), p[1] + mid * (q[1] - p[1]), p[2] + mid * (q[2] - p[2]))
    reach = 0.5 * abs(last - first) * _length(_sub(q, p)) + SURFACE_GAP
    d, nx, ny, nz, _, _, _ = _nearest(m, r, c, reach)
    move = (min(d, reach) + SURFACE_GAP) / ((1.0 - mid) * wp + mid * wq)
    return 1, (move * wp * nx, move * wp * ny, move * wp * nz), \
        (move * wq * nx, move * wq * ny, move * wq * nz)


def _edges(x, x0, m, r, edges, inv_mass, stats, params, data, key_count, pivot, pose, k, apply,
           n):
    """Round n of stage 2 for mesh row r (collider k): (edges through it that can move,
    edges through it that pins hold there), moving the first out when `apply`, each at once
    (Gauss-Seidel). Round 0 looks at every edge outside its ends' clearance balls; a
    later round only at those with an end moved in the round before or in this one (the
    others are as round 0 left them; m.clear marks a point moved in round n with -(n + 1)).
    The source of the kinds' kernels (_kernel_of), in which `push` is _solid_push or
    _sheet_push."""
    frame = (key_count, pivot, pose)
    clear = m.clear
    for p in range(x.shape[1] if n == 0 else 0):
        clear[p] = _clearance(params, data, k, _rest(frame, k, 1, x, p))[0]
    through = stuck = 0
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        if n > 0 and min(clear[i], clear[j]) > -n:
            continue
        p, q = _rest(frame, k, 1, x, i), _rest(frame, k, 1, x, j)
        if clear[i] + clear[j] > _length(_sub(q, p)):  # two balls free of the surface
            continue
        state, vp, vq = push(m, r, p, q, _rest(frame, k, 0, x0, i),  # noqa: F821 (_kernel_of's)
                             _rest(frame, k, 0, x0, j), inv_mass[i], inv_mass[j])
        if state == 0:
            continue
        if state == 2:
            stuck += 1
            continue
        through += 1
        if not apply:
            continue
        clear[i] = clear[j] = -(n + 1.0)
        for point, v in ((i, vp), (j, vq)):
            if frame[0][k] != 0:  # the move back to the world (rotation only)
                v = _rotate(frame[2], k, v[0], v[1], v[2])
            x[0, point] += v[0]
            x[1, point] += v[1]
            x[2, point] += v[2]
        stats[FACE_PUSHES] += 1.0
    return through, stuck


def _stage(x, x0, m, r, edges, inv_mass, stats, params, data, key_count, pivot, pose, k, mode):
    """Mode 0: stage 1 (_paths); 2 n + 1: round n of stage 2 (_edges); 2 n + 2: round n
    looking only. The source of solid_stage and sheet_stage (_kernel_of), in which `paths`
    and `edges_round` are the kind's."""
    if mode == 0:
        return paths(x, x0, m, r, inv_mass, stats, params, data,  # noqa: F821 (as above)
                     (key_count, pivot, pose), k)
    return edges_round(x, x0, m, r, edges, inv_mass, stats, params, data,  # noqa: F821
                       key_count, pivot, pose, k, mode % 2 == 1, (mode - 1) // 2)


def _kernel_of(source, name: str, pointer: bool = False, **kinds):
    """The kernel `name`: `source` with the globals `kinds` (a kind of mesh's functions), as
    colliders._sweep_of: each kind's stages are compiled on their own, only for a scene
    with that kind (solid meshes' inside test and response, 3-4 s of the pass's 11 compiled,
    are not compiled for a one-sided mesh, nor its rim response for a solid one). Without
    numba's reference counts (`_nrt=False`: nothing here allocates), as collider_contact's
    passes: numba counted the pose arrays of every inlined _rest, 40 % of the bowl's pass."""
    function = FunctionType(source.__code__, {**globals(), **kinds}, name)
    function.__qualname__ = name  # its own cache file
    function.__doc__ = source.__doc__
    return njit(cache=True, nogil=True, error_model="numpy", _nrt=False, pointer=pointer)(function)


solid_stage = _kernel_of(_stage, "solid_stage", True,
                         paths=_kernel_of(_paths, "solid_paths", out_of_solid=_out_of_solid),
                         edges_round=_kernel_of(_edges, "solid_edges", push=_solid_push))
sheet_stage = _kernel_of(_stage, "sheet_stage", True,
                         paths=_kernel_of(_paths, "sheet_paths", out_of_solid=_stays),
                         edges_round=_kernel_of(_edges, "sheet_edges", push=_sheet_push))
STAGE_RETURN = types.UniTuple(types.int64, 2)


def mesh_pointers(meshes: MeshContact, edges: np.ndarray, inv_mass: np.ndarray,
                  stats: np.ndarray) -> tuple[KernelPointer, KernelPointer, KernelPointer]:
    """(mesh_colliders, solid_stage, sheet_stage) as pointers for these arrays, each absent
    (never compiled) where the scene has no such mesh."""
    field = types.float64[:, ::1]
    solid = meshes.grid[:, _SOLID] != 0.0
    table = (field, types.float64[::1], types.int64[::1], field, types.float64[:, :, ::1],
             types.int64)  # params, data, key_count, pivot, pose, k
    state = (field, field, meshes)  # x, x0, m
    stages = [KernelPointer(kernel, state + (types.int64, edges, inv_mass, stats) + table
                            + (types.int64,), STAGE_RETURN, present=bool(kind))
              for kernel, kind in ((solid_stage, solid.any()), (sheet_stage, (~solid).any()))]
    return (KernelPointer(mesh_colliders, state + (edges, inv_mass, stats) + table
                          + tuple(stages), types.int64, present=bool(len(solid))), *stages)


@njit(cache=True, nogil=True, error_model="numpy", pointer=True)
def mesh_colliders(x, x0, m, edges, inv_mass, stats, params, data, key_count, pivot, pose, k,
                   solid_stage, sheet_stage):
    """Stages 1 and 2 for mesh collider k on the step from x0 to x (3, N), in place (the
    collider table's arrays, not the table: see collider_contact.robust_colliders); returns
    the number of points and edges moved; `solid_stage`, `sheet_stage`: the kinds' stages
    (pointers: mesh_pointers). Called through a pointer (RobustContact.mesh_pass),
    compiled only for scenes with a mesh collider."""
    r = m.row[k]
    stage = solid_stage if m.grid[r, _SOLID] != 0.0 else sheet_stage
    moved, pin = stage(x, x0, m, r, edges, inv_mass, stats, params, data, key_count, pivot,
                       pose, k, 0)
    left = 0
    for turn in range(ALTERNATIONS + 1):  # edge rounds, then paths again if they pushed
        pushed = held = 0
        for n in range(FACE_ROUNDS + 1):  # the last round (and turn) only looks
            apply = n < FACE_ROUNDS and turn < ALTERNATIONS
            through, stuck = stage(x, x0, m, r, edges, inv_mass, stats, params, data,
                                   key_count, pivot, pose, k, 2 * n + (1 if apply else 2))
            held = stuck if n == 0 else held  # round 0's pinned ones: not looked at again
            left = through + stuck + held
            if through == 0 or not apply:
                break
            pushed += through
        if pushed == 0 or turn == ALTERNATIONS:
            break
        again = stage(x, x0, m, r, edges, inv_mass, stats, params, data, key_count, pivot,
                      pose, k, 0)[0]
        moved += pushed + again
        if again == 0:
            break
    if left > 0:
        stats[NOT_KEPT] += 1.0
    if pin >= 0:
        stats[NOT_KEPT] += 1.0
        if stats[PIN_POINT] < 0.0:
            stats[PIN_STEP], stats[PIN_POINT] = stats[6], float(pin)
    return moved
