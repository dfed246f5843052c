"""Signed distance grid of a triangle mesh: build it, and sample it from numba kernels.

Build (`build_grid`): a regular grid over the mesh's bounding box plus a margin. Nodes
within `band` of the surface get the exact distance to the closest triangle (Ericson,
"Real-Time Collision Detection", 5.1.5), scattered from each triangle to the nodes near it,
signed by the angle-weighted pseudo-normal of the closest feature (vertex, edge or face;
Baerentzen & Aanaes 2005). The other nodes get a chamfer distance propagated from the band
(an upper bound of the true distance, 1-Lipschitz on the grid), signed by ray parity along
x (solid meshes; exact crossing counts with Bridson's tie-breaking) or by the propagated
sign (one-sided meshes). The trilinear interpolation error is measured against exact
distances at the cell centres within `thickness + h` of the surface; the grid is made
finer while it exceeds thickness / 2 and the node budget allows.

Sampling (@njit, inline): `grid_of` reads a grid's header row (HEADER_WIDTH floats, see
`DistanceGrid.header`) into a tuple, `locate` finds a point's cell, `trilinear`
interpolates the distance and its analytic gradient there from the flat float64 values,
`trusted` tells cells where the field is 1-Lipschitz.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clothjit import njit, read_only

HEADER_WIDTH = 10  # offset, origin (3), h, 1/h, nx, ny, nz, h * sqrt(3)
MAX_NODES = 2_000_000
FAR = 1e30  # distance reported outside the grid box
_LAST_CELL = 1.0 + 1e-9  # clamped grid coordinates stay below n - 1: in the last cell
_BAND_CELLS = 3.0  # exact band: thickness + 3 cells
_MARGIN_CELLS = 2.0  # grid box: mesh bounds + thickness + 2 cells


@dataclass(frozen=True)
class DistanceGrid:
    """Signed distances (positive outside) at the nodes origin + h (i, j, k)."""

    values: np.ndarray  # (nz, ny, nx) float64, x fastest
    origin: np.ndarray  # (3,)
    spacing: float
    error: float  # max |trilinear - exact| at cell centres within thickness + h of the surface
    solid: bool

    def header(self, offset: int) -> np.ndarray:
        """The kernels' description of this grid, its values stored at data[offset:]."""
        nz, ny, nx = self.values.shape
        h = self.spacing
        return np.array([offset, *self.origin, h, 1.0 / h, nx, ny, nz, h * math.sqrt(3.0)])

    def evaluate(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated distance (N,) and unit gradient (N, 3) at points (N, 3); FAR and
        a zero gradient outside the grid box."""
        header = self.header(0)[None, :]
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.empty((len(points), 4))
        _evaluate(header, self.values.ravel(), points, out)
        return out[:, 0], out[:, 1:]


def build_grid(vertices: np.ndarray, faces: np.ndarray, *, solid: bool, thickness: float,
               max_nodes: int = MAX_NODES) -> DistanceGrid:
    """The distance grid of a triangle mesh (solid: closed and outward-wound; else the sign
    follows the face orientation). Cell size: half the median edge length, at most 1/16 of
    the largest extent; then made finer while the measured error exceeds thickness / 2 and
    the grid stays within max_nodes."""
    # the grid's kernels take read-only meshes only, so they compile once whoever calls (a
    # caller's writable arrays, or the writable copy of a mesh flipped to wind outward,
    # compiled them again: 3.4 s of CPU in the tests)
    vertices = read_only(np.ascontiguousarray(vertices, dtype=np.float64))
    faces = read_only(np.ascontiguousarray(faces, dtype=np.int64))
    mesh = (vertices, faces, *_pseudo_normals(vertices, faces))
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    edges = np.linalg.norm(vertices[faces] - vertices[np.roll(faces, 1, axis=1)], axis=2)
    h = min(0.5 * float(np.median(edges)), float((high - low).max()) / 16.0)
    if not h > 0.0:
        raise ValueError("the mesh has no extent")
    while _node_count(low, high, h, thickness) > max_nodes:
        h *= 1.05
    target = 0.5 * thickness
    while True:
        grid = _build_at(mesh, low, high, h, solid, thickness)
        if grid.error <= target:
            return grid
        finer = h * max(0.5, 0.9 * target / grid.error)  # the error is O(h) at sharp edges
        while _node_count(low, high, finer, thickness) > max_nodes:
            finer *= 1.05
        if finer > 0.95 * h:
            return grid
        h = finer


def _node_count(low: np.ndarray, high: np.ndarray, h: float, thickness: float) -> int:
    return int(np.prod(_dims(low, high, h, thickness)[1]))


def _dims(low, high, h, thickness) -> tuple[np.ndarray, np.ndarray]:
    """Grid origin and node counts (x, y, z) for cell size h."""
    margin = thickness + _MARGIN_CELLS * h
    counts = np.ceil((high - low + 2 * margin) / h).astype(np.int64) + 1
    return low - margin, counts


def _pseudo_normals(vertices: np.ndarray, faces: np.ndarray):
    """(face normals (F,3), face edges (F,3) -> edge ids for AB BC CA, edge normals (E,3),
    angle-weighted vertex normals (V,3), open-boundary edges (E,) and vertices (V,) bool)."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_n = cross / np.maximum(np.linalg.norm(cross, axis=1), 1e-300)[:, None]
    pairs = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    face_edges = inverse.reshape(-1, 3)
    edge_n = np.zeros((len(unique), 3))
    np.add.at(edge_n, face_edges.ravel(), np.repeat(face_n, 3, axis=0))
    vertex_n = np.zeros_like(vertices)
    for corner in range(3):
        u = tri[:, (corner + 1) % 3] - tri[:, corner]
        w = tri[:, (corner + 2) % 3] - tri[:, corner]
        cos = np.einsum("ij,ij->i", u, w) / np.maximum(
            np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300)
        angle = np.arccos(np.clip(cos, -1.0, 1.0))
        np.add.at(vertex_n, faces[:, corner], angle[:, None] * face_n)
    boundary_edge = np.bincount(face_edges.ravel(), minlength=len(unique)) == 1
    boundary_vertex = np.zeros(len(vertices), dtype=np.bool_)
    boundary_vertex[unique[boundary_edge].ravel()] = True
    return (face_n, np.ascontiguousarray(face_edges, dtype=np.int64), edge_n, vertex_n,
            boundary_edge, boundary_vertex)


def _build_at(mesh, low, high, h, solid, thickness) -> DistanceGrid:
    origin, (nx, ny, nz) = _dims(low, high, h, thickness)
    band = thickness + _BAND_CELLS * h
    values = np.full((nz, ny, nx), np.inf)
    _scatter(*mesh, origin, h, band, values, np.zeros(values.shape, dtype=np.bool_))
    _chamfer(values, band, h)
    if solid:
        counts = np.zeros((nz, ny, nx), dtype=np.int32)
        _ray_crossings(mesh[0], mesh[1], origin, h, counts)
        _sign_from_parity(values, counts, band)
    grid = DistanceGrid(values, origin, h, 0.0, solid)
    near = thickness + h
    centres = np.full((nz - 1, ny - 1, nx - 1), np.inf)
    on_boundary = np.zeros(centres.shape, dtype=np.bool_)
    _scatter(*mesh, origin + 0.5 * h, h, near, centres, on_boundary)
    error = _centre_error(grid.header(0)[None, :], values.ravel(), centres, on_boundary, near,
                          solid)
    return DistanceGrid(values, origin, h, error, solid)


@njit(cache=True, nogil=True, inline="always")
def _closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point of triangle ABC to P and its feature: 0 A, 1 B, 2 C, 3 AB, 4 BC, 5 CA,
    6 the face (Ericson 5.1.5)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az, 0
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz, 1
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz, 3
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz, 2
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz, 5
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz), 4
    denom = 1.0 / (va + vb + vc)
    v, w = vb * denom, vc * denom
    return (ax + v * abx + w * acx, ay + v * aby + w * acy, az + v * abz + w * acz, 6)


@njit(cache=True, nogil=True, inline="always")
def _node_range(vertices, a, b, c, axis, origin, h, reach, n):
    """First and last node index along `axis` within `reach` of triangle abc's extent."""
    low = min(vertices[a, axis], vertices[b, axis], vertices[c, axis]) - reach
    high = max(vertices[a, axis], vertices[b, axis], vertices[c, axis]) + reach
    return (max(0, int(math.ceil((low - origin) / h))),
            min(n - 1, int(math.floor((high - origin) / h))))


@njit(cache=True, nogil=True)
def _scatter(vertices, faces, face_n, face_edges, edge_n, vertex_n, boundary_edge,
             boundary_vertex, origin, h, band, values, on_boundary):
    """values[k, j, i] = signed exact distance of node origin + h (i, j, k) where it is within
    `band` of the mesh (the other nodes keep their value), signed by the closest feature's
    pseudo-normal; on_boundary[k, j, i] = that feature lies on an open boundary."""
    nz, ny, nx = values.shape
    band2 = band * band
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        i0, i1 = _node_range(vertices, a, b, c, 0, origin[0], h, band, nx)
        j0, j1 = _node_range(vertices, a, b, c, 1, origin[1], h, band, ny)
        k0, k1 = _node_range(vertices, a, b, c, 2, origin[2], h, band, nz)
        for k in range(k0, k1 + 1):
            pz = origin[2] + k * h
            for j in range(j0, j1 + 1):
                py = origin[1] + j * h
                for i in range(i0, i1 + 1):
                    px = origin[0] + i * h
                    qx, qy, qz, feature = _closest_on_triangle(
                        px, py, pz, vertices[a, 0], vertices[a, 1], vertices[a, 2],
                        vertices[b, 0], vertices[b, 1], vertices[b, 2],
                        vertices[c, 0], vertices[c, 1], vertices[c, 2])
                    dx, dy, dz = px - qx, py - qy, pz - qz
                    d2 = dx * dx + dy * dy + dz * dz
                    old = values[k, j, i]
                    if d2 > band2 or d2 >= old * old:
                        continue
                    if feature < 3:
                        n = vertex_n[faces[t, feature]]
                        on_boundary[k, j, i] = boundary_vertex[faces[t, feature]]
                    elif feature < 6:
                        n = edge_n[face_edges[t, feature - 3]]
                        on_boundary[k, j, i] = boundary_edge[face_edges[t, feature - 3]]
                    else:
                        n = face_n[t]
                        on_boundary[k, j, i] = False
                    dist = math.sqrt(d2)
                    values[k, j, i] = dist if dx * n[0] + dy * n[1] + dz * n[2] >= 0.0 else -dist


@njit(cache=True, nogil=True)
def _chamfer(values, band, h):
    """Fill the nodes beyond the band (|value| > band) with the 3x3x3 chamfer distance from
    the band (two raster passes); each keeps the sign of the neighbour it came from."""
    nz, ny, nx = values.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                if abs(values[k, j, i]) > band:
                    values[k, j, i] = np.inf
    for sweep in (1, -1):
        for kr in range(nz):
            k = kr if sweep == 1 else nz - 1 - kr
            for jr in range(ny):
                j = jr if sweep == 1 else ny - 1 - jr
                for ir in range(nx):
                    i = ir if sweep == 1 else nx - 1 - ir
                    best = values[k, j, i]
                    if abs(best) <= band:
                        continue
                    for dk in (-1, 0):
                        for dj in (-1, 0, 1):
                            for di in (-1, 0, 1):
                                if dk == 0 and (dj > 0 or (dj == 0 and di >= 0)):
                                    continue  # the 13 neighbours already swept past
                                kk, jj, ii = k + sweep * dk, j + sweep * dj, i + sweep * di
                                if kk < 0 or kk >= nz or jj < 0 or jj >= ny or ii < 0 or ii >= nx:
                                    continue
                                other = values[kk, jj, ii]
                                step = h * math.sqrt(dk * dk + dj * dj + di * di)
                                reach = abs(other) + step
                                if reach < abs(best):
                                    best = reach if other >= 0.0 else -reach
                    values[k, j, i] = best


@njit(cache=True, nogil=True, inline="always")
def _orientation(x1, y1, x2, y2):
    """Twice the signed area of (0, p1, p2) and its sign with a consistent tie-break, so a
    ray through an edge or a vertex crosses exactly one of the triangles sharing it."""
    area = y1 * x2 - x1 * y2
    if area > 0.0:
        return area, 1
    if area < 0.0:
        return area, -1
    if y2 > y1:
        return area, 1
    if y2 < y1:
        return area, -1
    if x1 > x2:
        return area, 1
    if x1 < x2:
        return area, -1
    return area, 0


@njit(cache=True, nogil=True)
def _ray_crossings(vertices, faces, origin, h, counts):
    """counts[k, j, i] += number of mesh crossings of the +x ray through column (j, k) at x
    in ((i - 1) h, i h] (the first node takes every crossing before the grid)."""
    nz, ny, nx = counts.shape
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        ya, yb, yc = vertices[a, 1], vertices[b, 1], vertices[c, 1]
        za, zb, zc = vertices[a, 2], vertices[b, 2], vertices[c, 2]
        j0, j1 = _node_range(vertices, a, b, c, 1, origin[1], h, 0.0, ny)
        k0, k1 = _node_range(vertices, a, b, c, 2, origin[2], h, 0.0, nz)
        for k in range(k0, k1 + 1):
            z = origin[2] + k * h
            for j in range(j0, j1 + 1):
                y = origin[1] + j * h
                wa, sa = _orientation(yb - y, zb - z, yc - y, zc - z)
                if sa == 0:
                    continue
                wb, sb = _orientation(yc - y, zc - z, ya - y, za - z)
                if sb != sa:
                    continue
                wc, sc = _orientation(ya - y, za - z, yb - y, zb - z)
                if sc != sa:
                    continue
                total = wa + wb + wc
                x = (wa * vertices[a, 0] + wb * vertices[b, 0] + wc * vertices[c, 0]) / total
                i = int(math.ceil((x - origin[0]) / h))
                if i < nx:
                    counts[k, j, max(i, 0)] += 1


@njit(cache=True, nogil=True)
def _sign_from_parity(values, counts, band):
    """Nodes beyond the band: negative where an odd number of crossings precede them on x."""
    nz, ny, nx = values.shape
    for k in range(nz):
        for j in range(ny):
            crossings = 0
            for i in range(nx):
                crossings += counts[k, j, i]
                v = abs(values[k, j, i])
                if v > band:
                    values[k, j, i] = -v if crossings % 2 == 1 else v


@njit(cache=True, nogil=True)
def _centre_error(header, data, centres, on_boundary, near, solid):
    """max |trilinear - exact| over the cell centres where the collider leaves points:
    solid, 0 <= exact <= near; one-sided, |exact| <= near in trusted cells whose closest
    feature is not on an open boundary (the boundary is resolved to about a cell)."""
    nz, ny, nx = centres.shape
    grid = grid_of(header, 0)
    error = 0.0
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                exact = centres[k, j, i]
                if not (abs(exact) <= near and (exact >= 0.0 or not solid)):
                    continue
                base = (k * (ny + 1) + j) * (nx + 1) + i
                if not solid and (on_boundary[k, j, i] or not trusted(grid, data, base)):
                    continue
                d = trilinear(grid, data, base, 0.5, 0.5, 0.5)[0]
                error = max(error, abs(d - exact))
    return error


@njit(cache=True, nogil=True, inline="always")
def grid_of(params, c):
    """The grid described by params[c, :HEADER_WIDTH] as a tuple of scalars for the
    samplers below: (offset, ox, oy, oz, 1/h, nx, ny, nz, h, h sqrt(3))."""
    return (int(params[c, 0]), params[c, 1], params[c, 2], params[c, 3], params[c, 5],
            int(params[c, 6]), int(params[c, 7]), params[c, 8], params[c, 4], params[c, 9])


@njit(cache=True, nogil=True, inline="always")
def locate(grid, x, y, z):
    """(index in data of the corner (i, j, k) of the point's cell, fractions tx, ty, tz,
    inside the grid box). Outside, the cell is the nearest one (fractions clamped)."""
    fx = (x - grid[1]) * grid[4]
    fy = (y - grid[2]) * grid[4]
    fz = (z - grid[3]) * grid[4]
    inside = ((fx >= 0.0) & (fy >= 0.0) & (fz >= 0.0)
              & (fx < grid[5] - 1) & (fy < grid[6] - 1) & (fz < grid[7] - 1))
    fx = min(max(0.0, fx), grid[5] - _LAST_CELL)  # max(0.0, NaN) is 0.0
    fy = min(max(0.0, fy), grid[6] - _LAST_CELL)
    fz = min(max(0.0, fz), grid[7] - _LAST_CELL)
    i, j, k = int(fx), int(fy), int(fz)
    return grid[0] + (k * grid[6] + j) * grid[5] + i, fx - i, fy - j, fz - k, inside


@njit(cache=True, nogil=True, inline="always")
def trilinear(grid, data, base, tx, ty, tz):
    """(distance, gradient x, y, z) of the trilinear cell at `base` (from `locate`): the
    analytic gradient of the cell, not normalised (its norm is about 1 near the surface)."""
    sx = grid[5]
    sxy = sx * grid[6]
    c000, c100 = data[base], data[base + 1]
    c010, c110 = data[base + sx], data[base + sx + 1]
    c001, c101 = data[base + sxy], data[base + sxy + 1]
    c011, c111 = data[base + sxy + sx], data[base + sxy + sx + 1]
    sy, sz = 1.0 - ty, 1.0 - tz
    x00 = c000 + tx * (c100 - c000)
    x10 = c010 + tx * (c110 - c010)
    x01 = c001 + tx * (c101 - c001)
    x11 = c011 + tx * (c111 - c011)
    y0 = x00 + ty * (x10 - x00)
    y1 = x01 + ty * (x11 - x01)
    inv_h = grid[4]
    gx = (sy * sz * (c100 - c000) + ty * sz * (c110 - c010)
          + sy * tz * (c101 - c001) + ty * tz * (c111 - c011)) * inv_h
    gy = (sz * (x10 - x00) + tz * (x11 - x01)) * inv_h
    gz = (y1 - y0) * inv_h
    return y0 + tz * (y1 - y0), gx, gy, gz


@njit(cache=True, nogil=True, inline="always")
def trusted(grid, data, base) -> bool:
    """Whether the cell at `base` is 1-Lipschitz along its 12 edges. A one-sided surface's
    sign flips beyond its open boundary; cells straddling that flip (farther than about
    half a cell from the boundary) fail this test, and the kernels ignore them."""
    sx = grid[5]
    sxy = sx * grid[6]
    c000, c100 = data[base], data[base + 1]
    c010, c110 = data[base + sx], data[base + sx + 1]
    c001, c101 = data[base + sxy], data[base + sxy + 1]
    c011, c111 = data[base + sxy + sx], data[base + sxy + sx + 1]
    jump = max(abs(c100 - c000), abs(c110 - c010), abs(c101 - c001), abs(c111 - c011),
               abs(c010 - c000), abs(c110 - c100), abs(c011 - c001), abs(c111 - c101),
               abs(c001 - c000), abs(c101 - c100), abs(c011 - c010), abs(c111 - c110))
    return jump <= grid[8] * (1.0 + 1e-9)


@njit(cache=True, nogil=True)
def _evaluate(header, data, points, out):
    grid = grid_of(header, 0)
    for p in range(points.shape[0]):
        base, tx, ty, tz, inside = locate(grid, points[p, 0], points[p, 1], points[p, 2])
        if not inside:
            out[p, 0], out[p, 1], out[p, 2], out[p, 3] = FAR, 0.0, 0.0, 0.0
        else:
            d, gx, gy, gz = trilinear(grid, data, base, tx, ty, tz)
            scale = 1.0 / max(math.sqrt(gx * gx + gy * gy + gz * gz), 1e-300)
            out[p, 0], out[p, 1], out[p, 2], out[p, 3] = d, gx * scale, gy * scale, gz * scale
