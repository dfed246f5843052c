"""A cloth given as a triangle mesh (`cloth.mesh`): its springs, finite elements and the
incidence that gathers their forces on the points, as flat arrays for
pipeline.physics.mesh_forces. Data only; the file is read by pipeline.physics.cloth_mesh.

Classic model (SPEC section 2): structural springs on the mesh's edges, bending springs
(k = 0.2 ks) between the two vertices opposite each interior edge, no shearing springs (a
triangle mesh has no cell diagonals). Each spring is created by its later point, as the
grid's springs are; the list holds the structural springs by (later point, earlier point),
then the bending springs in the same order. Provot's limit walks the structural ones.

FEM: the grid's energies (pipeline.physics.fem) per triangle of the mesh, each triangle's
rest metric in its own plane with the u axis along the file's uv direction dP/du (the warp)
and v orthogonal to it in that plane (the weft), and discrete-shells bending about each
interior edge's rest dihedral angle, so a curved garment rests in its own shape.

Every element writes its vertices' forces to its own rows of a buffer; each point then sums
its rows in a fixed order (`start`, `slot`: a compressed incidence list), so results do not
depend on the number of threads.

The FEM's forces run over blocks of BLOCK elements of one kind (`element_blocks`): a block
holds its corners' points, its constants and rows for its corners' positions (gathered from
the points, then overwritten by the corners' forces) as rows of BLOCK consecutive values in
flat arrays. BLOCK is a literal, so every row of a block lies a constant distance from the
others: LLVM vectorises the element arithmetic over a block without run-time overlap tests,
which it gives up on beyond a handful of rows. The blocks are cut into PARTS parts of
consecutive blocks of each kind; a point whose rows all lie in one part (most points of a
mesh whose points are numbered along its surface) is summed by that part's task right
after its blocks, while its rows are still in the core's cache, the others after every
part. Any part sums a point's rows in incidence order.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

BENDING_FACTOR = 0.2  # k = 0.2 * ks for bending springs, as the grid's
BLOCK = 64  # elements per block (see the module docstring)
PARTS = 16  # tasks of the element pass (see the module docstring)
# rows per block: a triangle's 3 corners x 3 axes, its constants R^-1 (00, 01, 10, 11) and
# rest area; a hinge's 4 corners x 3 axes, its factor and rest angle
TRIANGLE_ROWS, TRIANGLE_CONSTANTS, HINGE_ROWS, HINGE_CONSTANTS = 9, 5, 12, 2


class MeshSprings(NamedTuple):
    """The classic springs of a mesh cloth (System.springs for a mesh)."""

    a: np.ndarray  # (S,) int64: the spring's later point, which creates it
    b: np.ndarray  # (S,) int64: its earlier point
    rest: np.ndarray  # (S,) float64 rest length
    stiffness: np.ndarray  # (S,) float64 k, 0 where its kind is disabled
    structural: int  # springs [0, structural) are structural, the rest bending
    start: np.ndarray  # (N + 1,) int64: point p's springs are slot[start[p]:start[p + 1]]
    slot: np.ndarray  # (2 S,) int64 spring indices, ascending per point
    sign: np.ndarray  # (2 S,) float64: +1 where the point is the spring's a, -1 where its b


class MeshFem(NamedTuple):
    """The finite-element model of a mesh cloth (System.fem for a mesh)."""

    k_stretch: float  # N/m
    k_shear: float  # N/m
    k_bend: float  # N m
    triangles: np.ndarray  # (T, 3) int64
    tri_area: np.ndarray  # (T,) rest area
    tri_inv: np.ndarray  # (T, 4) R^-1 entries (00, 01, 10, 11), R the rest edges in (u, v)
    hinges: np.ndarray  # (H, 4) int64 (a, b, c, d): edge a-b, triangles (a, b, c), (b, a, d)
    hinge_factor: np.ndarray  # (H,) |e|^2 / (2 (A1 + A2)) at rest
    rest_angle: np.ndarray  # (H,) dihedral angle at rest (filled by mesh_forces)
    corner_force: np.ndarray  # (3 T + 4 H, 3) scratch: each element corner's force
    start: np.ndarray  # (N + 1,) int64: point p's corners are slot[start[p]:start[p + 1]]
    slot: np.ndarray  # (3 T + 4 H,) int64 rows of corner_force, ascending per point
    # the elements in blocks (element_blocks): triangle blocks [0, tri_blocks), then hinges
    tri_blocks: int = 0
    part_blocks: np.ndarray | None = None  # (PARTS + 1, 2) int64: part q's triangle blocks
    # are [part_blocks[q, 0], part_blocks[q + 1, 0]), its hinge blocks likewise in column 1
    part_points: np.ndarray | None = None  # (PARTS + 2,) int64: part q sums the points
    # point_order[part_points[q]:part_points[q + 1]]; q = PARTS: the points of several parts
    point_order: np.ndarray | None = None  # (N,) int64 the points by part, ascending
    block_points: np.ndarray | None = None  # (BLOCK (3 tri_blocks + 4 hinge blocks),) int64
    block_constants: np.ndarray | None = None  # (BLOCK (5 tri_blocks + 2 hinge blocks),)
    block_rows: np.ndarray | None = None  # (BLOCK (9 tri_blocks + 12 hinge blocks),) scratch
    row_slot: np.ndarray | None = None  # (3 T + 4 H,) int64: slot's rows in block_rows
    # (axis 0; axes 1, 2 follow at BLOCK and 2 BLOCK), in slot's order (fem.start's)


@dataclass(frozen=True)
class MeshTopology:
    """What the model keeps of a mesh cloth beyond its springs and elements: its faces, uvs
    (per triangle corner, seams kept) for drawing, edges, hinges and scale."""

    triangles: np.ndarray  # (T, 3) int64
    corner_uv: np.ndarray  # (T, 3, 2) float64
    has_uv: bool  # False: corner_uv is a planar projection
    edges: np.ndarray  # (E, 2) int64 (earlier, later point), sorted
    hinges: np.ndarray  # (H, 4) int64, see MeshFem
    mean_edge: float  # mean rest edge length, m
    point_uv: np.ndarray  # (N, 2) a uv of each point (its first corner's), for mass maps


def incidence(owner: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(start, slot): the rows of `owner` (the point each row belongs to) grouped by point,
    ascending within a point."""
    slot = np.argsort(owner, kind="stable").astype(np.int64)
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(owner, minlength=n), out=start[1:])
    return start, slot


def topology(points: np.ndarray, triangles: np.ndarray, corner_uv: np.ndarray,
             has_uv: bool) -> MeshTopology:
    """Edges and hinges of a consistently wound manifold mesh; points (N, 3)."""
    tris = np.asarray(triangles, dtype=np.int64)
    tail = tris.reshape(-1)
    head = tris[:, [1, 2, 0]].reshape(-1)
    opposite = tris[:, [2, 0, 1]].reshape(-1)
    lo, hi = np.minimum(tail, head), np.maximum(tail, head)
    edges, inverse, counts = np.unique(np.stack([lo, hi], axis=1), axis=0, return_inverse=True,
                                       return_counts=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(inverse, kind="stable")  # the directed edges of each edge, in face order
    first = np.zeros(len(edges) + 1, dtype=np.int64)
    np.cumsum(counts, out=first[1:])
    interior = np.nonzero(counts == 2)[0]
    one, two = order[first[interior]], order[first[interior] + 1]
    hinges = np.stack([tail[one], head[one], opposite[one], opposite[two]], axis=1)
    length = np.linalg.norm(points[edges[:, 1]] - points[edges[:, 0]], axis=1)
    point_uv = np.zeros((len(points), 2))
    point_uv[tail[::-1]] = corner_uv.reshape(-1, 2)[::-1]  # the first corner's uv wins
    return MeshTopology(triangles=tris, corner_uv=np.asarray(corner_uv, dtype=np.float64),
                        has_uv=has_uv, edges=edges.astype(np.int64), hinges=hinges,
                        mean_edge=float(length.mean()), point_uv=point_uv)


def mesh_springs(points: np.ndarray, topo: MeshTopology, ks: float,
                 structural: bool, bending: bool) -> MeshSprings:
    """The classic springs of the mesh, rest lengths from `points` (N, 3)."""
    n = len(points)
    edges = topo.edges[:, ::-1]  # (later, earlier)
    structural_pairs = edges[np.lexsort((edges[:, 1], edges[:, 0]))]
    bend = np.sort(topo.hinges[:, 2:], axis=1)[:, ::-1]  # (later, earlier) opposite points
    bend = np.unique(bend[bend[:, 0] != bend[:, 1]], axis=0)  # sorted rows
    both = np.concatenate([structural_pairs, bend.reshape(-1, 2)]).astype(np.int64)
    a, b = np.ascontiguousarray(both[:, 0]), np.ascontiguousarray(both[:, 1])
    rest = np.linalg.norm(points[b] - points[a], axis=1)
    k = np.concatenate([np.full(len(structural_pairs), ks if structural else 0.0),
                        np.full(len(bend), BENDING_FACTOR * ks if bending else 0.0)])
    owner = np.concatenate([a, b])
    start, slot2 = incidence(owner, n)
    count = len(a)
    slot = np.where(slot2 < count, slot2, slot2 - count)
    order = np.lexsort((slot, np.repeat(np.arange(n), np.diff(start))))
    slot, sign_rows = slot[order], slot2[order]
    sign = np.where(sign_rows < count, 1.0, -1.0)
    return MeshSprings(a=a, b=b, rest=rest, stiffness=k, structural=len(structural_pairs),
                       start=start, slot=slot.astype(np.int64), sign=sign)


def rest_frames(points: np.ndarray, triangles: np.ndarray,
                corner_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(area (T,), R^-1 (T, 4)): each triangle's rest area and the inverse of its rest edge
    matrix R = [e1 e2] in its (u, v) frame: u along dP/du, v orthogonal to it in the plane
    (towards dP/dv). Where the uvs give no direction, u runs along the first edge."""
    p0, p1, p2 = (points[triangles[:, k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    normal = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(normal, axis=1)
    n_hat = normal / np.maximum(2.0 * area, 1e-300)[:, None]
    duv1 = corner_uv[:, 1] - corner_uv[:, 0]
    duv2 = corner_uv[:, 2] - corner_uv[:, 0]
    det = duv1[:, 0] * duv2[:, 1] - duv2[:, 0] * duv1[:, 1]
    ok = np.abs(det) > 1e-14
    safe = np.where(ok, det, 1.0)
    dpdu = (e1 * duv2[:, 1:2] - e2 * duv1[:, 1:2]) / safe[:, None]
    dpdv = (e2 * duv1[:, 0:1] - e1 * duv2[:, 0:1]) / safe[:, None]
    dpdu = dpdu - np.sum(dpdu * n_hat, axis=1)[:, None] * n_hat
    good = ok & (np.linalg.norm(dpdu, axis=1) > 0.0)
    t1 = np.where(good[:, None], dpdu, e1)
    t1 = t1 / np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(n_hat, t1)
    flip = good & (np.sum(t2 * dpdv, axis=1) < 0.0)  # v towards dP/dv (mirrored uvs)
    t2[flip] *= -1.0
    r = np.empty((len(triangles), 2, 2))
    r[:, 0, 0], r[:, 1, 0] = np.sum(e1 * t1, axis=1), np.sum(e1 * t2, axis=1)
    r[:, 0, 1], r[:, 1, 1] = np.sum(e2 * t1, axis=1), np.sum(e2 * t2, axis=1)
    return area, np.linalg.inv(r).reshape(-1, 4)


def mesh_fem(points: np.ndarray, topo: MeshTopology, k_stretch: float, k_shear: float,
             k_bend: float) -> MeshFem:
    """The FEM of the mesh at rest in `points` (N, 3); rest angles are filled in by
    pipeline.physics.mesh_forces.with_rest_angles (the kernels' own dihedral angle)."""
    n = len(points)
    tris, hinges = topo.triangles, topo.hinges
    area, inv = rest_frames(points, tris, topo.corner_uv)
    a, b, c, d = (points[hinges[:, k]] for k in range(4))
    e = b - a
    area1 = 0.5 * np.linalg.norm(np.cross(e, c - a), axis=1)
    area2 = 0.5 * np.linalg.norm(np.cross(d - a, e), axis=1)
    factor = np.sum(e * e, axis=1) / (2.0 * (area1 + area2))
    owner = np.concatenate([tris.reshape(-1), hinges.reshape(-1)])
    start, slot = incidence(owner, n)
    return element_blocks(MeshFem(
        k_stretch=float(k_stretch), k_shear=float(k_shear), k_bend=float(k_bend),
        triangles=tris, tri_area=area, tri_inv=np.ascontiguousarray(inv),
        hinges=np.ascontiguousarray(hinges), hinge_factor=factor,
        rest_angle=np.zeros(len(hinges)), corner_force=np.zeros((len(owner), 3)),
        start=start, slot=slot))


def _blocked(rows: np.ndarray, blocks: int) -> np.ndarray:
    """(blocks BLOCK K,): rows (M, K) of M <= blocks BLOCK elements as blocks of K rows of
    BLOCK values (element b BLOCK + j's row k at (b K + k) BLOCK + j), padded with zeros."""
    m, k = rows.shape
    padded = np.zeros((blocks * BLOCK, k), dtype=rows.dtype)
    padded[:m] = rows
    return padded.reshape(blocks, BLOCK, k).transpose(0, 2, 1).reshape(-1)


def element_blocks(fem: MeshFem) -> MeshFem:
    """`fem` with its block fields made from its element lists (again after a change of
    them, e.g. of the rest angles). Each kind's elements go into blocks by their lowest
    point, and part q takes the blocks whose first element's lowest point is in
    [q N / PARTS, (q + 1) N / PARTS): on a mesh whose points are numbered along its surface,
    most of a point's elements are in one part. Padding elements have point 0 and zero
    constants; no point sums their rows."""
    tris, hinges, n = fem.triangles, fem.hinges, len(fem.start) - 1
    tb = -(-len(tris) // BLOCK)
    cuts = np.arange(PARTS + 1) * n // PARTS
    points, constants, corner_rows, bounds = [], [], [], []
    first_row = 0
    for elements, own, size in ((tris, np.concatenate([fem.tri_inv, fem.tri_area[:, None]], 1),
                                 TRIANGLE_ROWS),
                                (hinges, np.stack([fem.hinge_factor, fem.rest_angle], 1),
                                 HINGE_ROWS)):
        blocks = -(-len(elements) // BLOCK)
        key = elements.min(axis=1) if len(elements) else np.zeros(0, dtype=np.int64)
        order = np.argsort(key, kind="stable")
        points.append(_blocked(elements[order], blocks))
        constants.append(_blocked(own[order], blocks))
        at = np.empty(len(order), dtype=np.int64)
        at[order] = np.arange(len(order))  # each element's place in the blocks
        # each corner's axis-0 row in block_rows, corner_force's row order (element, corner)
        e, k = np.divmod(np.arange(elements.size), elements.shape[1])
        corner_rows.append((first_row + at[e] // BLOCK * size + 3 * k) * BLOCK + at[e] % BLOCK)
        bounds.append(np.searchsorted(key[order][::BLOCK], cuts, side="left"))
        bounds[-1][-1] = blocks
        first_row += blocks * size
    row = np.concatenate(corner_rows).astype(np.int64)
    part = np.concatenate([np.searchsorted(bounds[0], corner_rows[0] // BLOCK // TRIANGLE_ROWS,
                                           side="right"),
                           np.searchsorted(bounds[1], (corner_rows[1] // BLOCK - tb * TRIANGLE_ROWS)
                                           // HINGE_ROWS, side="right")]) - 1
    owner = np.repeat(np.arange(n), np.diff(fem.start))
    lowest, highest = np.full(n, PARTS), np.zeros(n, dtype=np.int64)
    np.minimum.at(lowest, owner, part[fem.slot])
    np.maximum.at(highest, owner, part[fem.slot])
    point_part = np.where(lowest == highest, lowest, PARTS)
    part_points = np.zeros(PARTS + 2, dtype=np.int64)
    np.cumsum(np.bincount(point_part, minlength=PARTS + 1), out=part_points[1:])
    return fem._replace(
        tri_blocks=tb, part_blocks=np.stack(bounds, axis=1).astype(np.int64),
        part_points=part_points,
        point_order=np.argsort(point_part, kind="stable").astype(np.int64),
        block_points=np.concatenate(points).astype(np.int64),
        block_constants=np.ascontiguousarray(np.concatenate(constants), dtype=np.float64),
        block_rows=np.zeros(first_row * BLOCK), row_slot=row[fem.slot])


def lumped_masses(points: np.ndarray, triangles: np.ndarray, density: float) -> np.ndarray:
    """(N,) density times a third of the rest area of every incident triangle."""
    p0, p1, p2 = (points[triangles[:, k]] for k in range(3))
    third = np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1) / 6.0
    area = np.zeros(len(points))
    for k in range(3):
        np.add.at(area, triangles[:, k], third)
    return density * area
