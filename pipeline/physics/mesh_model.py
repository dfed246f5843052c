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
consecutive blocks of each kind, and the parts into `runs` runs of consecutive parts, one
per thread numba may start: mesh_forces.mesh_fem_forces goes through each run's parts in
order. A point whose rows all lie in one run is summed right after the last part holding
any of them (on a mesh whose points are numbered along its surface, a point's rows lie in a
few consecutive parts), the others after every run. So a run's parts can share a few slots
of rows, a part taking over the slot of the part `slots` before it once no point still to
be summed reads it (`_block_rows`), and the rows a run writes and sums stay in its core's
cache: rows for every block (4.2 MB on a 100x100 cloth, twice a core's cache here) made the
gather that writes them 40 % of the forces' time on 2 threads. The blocks that points
summed after every run read keep rows of their own. Every point sums its rows in incidence
order, so neither the runs nor the thread count change a bit.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

BENDING_FACTOR = 0.2  # k = 0.2 * ks for bending springs, as the grid's
BLOCK = 64  # elements per block (see the module docstring)
PARTS = 16  # parts of the element pass (see the module docstring)
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
    start: np.ndarray  # (N + 1,) int64: point p's springs are code[start[p]:start[p + 1]]
    # (2 S,) per point its springs, ascending: 2 spring + 1 where p is the spring's b end
    # (its force taken with sign -1), 2 spring where its a; int32 where it fits (_indices)
    code: np.ndarray
    ends: np.ndarray  # (2, S) a and b as _indices makes them: fewer bytes a step to stream


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
    runs: int = 1  # runs of consecutive parts (mesh_forces.mesh_fem_forces)
    part_blocks: np.ndarray | None = None  # (PARTS + 1, 2) int64: part q's triangle blocks
    # are [part_blocks[q, 0], part_blocks[q + 1, 0]), its hinge blocks likewise in column 1
    part_points: np.ndarray | None = None  # (PARTS + 2,) int64: part q sums the points
    # point_order[part_points[q]:part_points[q + 1]]; q = PARTS: those of several runs
    point_order: np.ndarray | None = None  # (N,) int64 the points by part, ascending
    # indices int32 where they fit (_indices)
    block_points: np.ndarray | None = None  # (BLOCK (3 tri_blocks + 4 hinge blocks),) int32
    block_constants: np.ndarray | None = None  # (BLOCK (5 tri_blocks + 2 hinge blocks),)
    block_row: np.ndarray | None = None  # (tri_blocks + hinge blocks,) int64: the block's
    # first row in block_rows; its TRIANGLE_ROWS or HINGE_ROWS rows of BLOCK values follow
    block_rows: np.ndarray | None = None  # scratch: the blocks' rows (element_blocks)
    row_slot: np.ndarray | None = None  # (3 T + 4 H,) int32: slot's rows in block_rows
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
    code = 2 * slot[order].astype(np.int64) + (slot2[order] >= count)
    return MeshSprings(a=a, b=b, rest=rest, stiffness=k, structural=len(structural_pairs),
                       start=start, code=_indices(code), ends=_indices(np.stack([a, b])))


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


def element_blocks(fem: MeshFem, runs: int | None = None) -> MeshFem:
    """`fem` with its block fields made from its element lists (again after a change of
    them, e.g. of the rest angles). Each kind's elements go into blocks by their lowest
    point, and part q takes the blocks whose first element's lowest point is in
    [q N / PARTS, (q + 1) N / PARTS): on a mesh whose points are numbered along its surface,
    a point's elements are in one part or a few consecutive ones. Padding elements have
    point 0 and zero constants; no point sums their rows. `runs`: the runs of parts
    (default: one per thread numba may start in this process, at most PARTS)."""
    tris, hinges, n = fem.triangles, fem.hinges, len(fem.start) - 1
    cuts = np.arange(PARTS + 1) * n // PARTS
    points, constants, bounds, corner_block, corner_offset = [], [], [], [], []
    first_block = 0
    for elements, own in ((tris, np.concatenate([fem.tri_inv, fem.tri_area[:, None]], 1)),
                          (hinges, np.stack([fem.hinge_factor, fem.rest_angle], 1))):
        blocks = -(-len(elements) // BLOCK)
        key = elements.min(axis=1) if len(elements) else np.zeros(0, dtype=np.int64)
        order = np.argsort(key, kind="stable")
        points.append(_blocked(elements[order], blocks))
        constants.append(_blocked(own[order], blocks))
        at = np.empty(len(order), dtype=np.int64)
        at[order] = np.arange(len(order))  # each element's place in the blocks
        # each corner's block (triangle blocks, then hinge blocks) and its axis-0 row in
        # the block, in corner_force's row order (element, corner)
        e, k = np.divmod(np.arange(elements.size), elements.shape[1])
        corner_block.append(first_block + at[e] // BLOCK)
        corner_offset.append(3 * k * BLOCK + at[e] % BLOCK)
        bounds.append(np.searchsorted(key[order][::BLOCK], cuts, side="left"))
        bounds[-1][-1] = blocks
        first_block += blocks
    tb = int(bounds[0][-1])
    part_blocks = np.stack(bounds, axis=1).astype(np.int64)
    block_part = np.concatenate([np.repeat(np.arange(PARTS), np.diff(part_blocks[:, kind]))
                                 for kind in (0, 1)])
    block = np.concatenate(corner_block)[fem.slot]  # the blocks of fem.slot's corners
    owner = np.repeat(np.arange(n), np.diff(fem.start))
    lowest, highest = np.full(n, PARTS - 1), np.zeros(n, dtype=np.int64)  # no rows: part 0
    np.minimum.at(lowest, owner, block_part[block])
    np.maximum.at(highest, owner, block_part[block])
    lowest = np.minimum(lowest, highest)
    runs = min(PARTS, numba.config.NUMBA_NUM_THREADS) if runs is None else runs
    run_of = np.searchsorted(np.arange(runs + 1) * PARTS // runs, np.arange(PARTS),
                             side="right") - 1
    local = run_of[lowest] == run_of[highest]  # summed in its run, right after part highest
    kept = np.zeros(first_block, dtype=bool)  # blocks read by the sums after every run
    kept[block[~local[owner]]] = True
    # part q + slots takes over part q's rows: a point summed in its run must have read its
    # rows (parts lowest to highest) by then
    slots = min(int(np.max(highest - lowest, where=local, initial=0)) + 1, -(-PARTS // runs))
    size = np.where(np.arange(first_block) < tb, TRIANGLE_ROWS, HINGE_ROWS) * BLOCK
    row, total = _block_rows(block_part, size, kept, run_of, slots)
    point_part = np.where(local, highest, PARTS)
    part_points = np.zeros(PARTS + 2, dtype=np.int64)
    np.cumsum(np.bincount(point_part, minlength=PARTS + 1), out=part_points[1:])
    return fem._replace(
        tri_blocks=tb, runs=runs, part_blocks=part_blocks, part_points=part_points,
        point_order=np.argsort(point_part, kind="stable").astype(np.int64),
        block_points=_indices(np.concatenate(points)),
        block_constants=np.ascontiguousarray(np.concatenate(constants), dtype=np.float64),
        block_row=row, block_rows=np.zeros(total),
        row_slot=_indices(row[block] + np.concatenate(corner_offset)[fem.slot]))


def _block_rows(block_part: np.ndarray, size: np.ndarray, kept: np.ndarray,
                run_of: np.ndarray, slots: int) -> tuple[np.ndarray, int]:
    """(each block's first row, rows in all): the `kept` blocks one after the other, after
    the others. Those: run r puts part q's blocks in its slot q % `slots` (each slot as long
    as the longest part's blocks not kept), where part q + slots overwrites them, so that
    a run's slots stay in its core's cache while it goes through its parts; or, where that
    takes no fewer rows (parts of very different lengths), every part in rows of its own."""
    by_part = np.lexsort((np.arange(len(size)), block_part))  # as the runs go through them
    part = block_part[by_part]
    kept_size = np.where(kept[by_part], size[by_part], 0)
    slot_size = size[by_part] - kept_size
    place = np.cumsum(slot_size) - slot_size  # every part in rows of its own
    area = int(np.sum(slot_size))
    offset = place - place[np.searchsorted(part, part)]  # from its part's first block
    slot_rows = int(np.max(offset + slot_size, initial=0))
    if (int(run_of[-1]) + 1) * slots * slot_rows < area:
        place = (run_of[part] * slots + part % slots) * slot_rows + offset
        area = (int(run_of[-1]) + 1) * slots * slot_rows
    row = np.empty(len(size), dtype=np.int64)
    row[by_part] = np.where(kept[by_part], area + np.cumsum(kept_size) - kept_size, place)
    return row, area + int(np.sum(kept_size))


def _indices(values: np.ndarray) -> np.ndarray:
    """`values` as int32 where they fit (half the bytes to stream per step), else int64."""
    return values.astype(np.int32 if values.max(initial=0) < 2**31 else np.int64)


def lumped_masses(points: np.ndarray, triangles: np.ndarray, density: float) -> np.ndarray:
    """(N,) density times a third of the rest area of every incident triangle."""
    p0, p1, p2 = (points[triangles[:, k]] for k in range(3))
    third = np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1) / 6.0
    area = np.zeros(len(points))
    for k in range(3):
        np.add.at(area, triangles[:, k], third)
    return density * area
