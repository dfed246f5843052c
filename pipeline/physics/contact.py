"""Robust self-contact (`simulation.contact` "robust"): the cloth never passes through
itself (Bridson, Fedkiw and Anderson 2002, "Robust treatment of collisions, contact and
friction for cloth animation", in position form).

After the integrator and the other position passes have moved the points from x0 (the
start of the step, free of crossings) to x1, between every point and triangle, and every
two edges, of the cloth that share no vertex and lie further apart than `thickness` h at
rest:
1. one visit of every pair: one that meets on the straight paths x0 -> x1 (continuous
   collision detection, pipeline.physics.ccd) is stopped IMPACT_GAP h apart along the
   normal at impact, on the side it came from; one closer than h at x1 is pushed apart to
   h (inelastic repulsion), with friction: its relative tangential motion over the step
   shrinks by at most `friction` times the push. The moves are averaged per point (Jacobi);
   while a round finds a pair closer than DEEP_GAP h, it is repeated (PROXIMITY_ROUNDS
   more at most), each push moving its points at once (Gauss-Seidel: a stack of layers
   pressed together parts in a round, where averaged pushes part one layer a round);
2. if anything moved, rounds of CCD alone until one finds no meeting (CCD_ROUNDS at most);
3. fail-safe: while any pair still meets, every free point of every such pair goes back
   to x0 (moves no further this step). x0 has no crossing, so this ends, at worst with
   every point back at x0; a pair that meets with none of its points free (pins moving
   into each other) is counted as unresolvable.

Pairs come from a candidate list: every pair within h plus the skins of its two primitives
at the list's making (a point's skin: how far it may move before the list is made again, a
primitive's the largest of its points'), made on a grid of the primitives' boxes
(_make_list) and made again when a point has moved further than its skin from where it was
(less the cloth's mean move). The skins follow the points: each is what its point moved
while the last list held, at that rate over SKIN_CALLS calls, so that a still cloth lists
few pairs and a fast point does not make the list again every step. The list is kept in
order of its pairs' slack (their distance beyond h over their skins): a visit reads only the
pairs whose slack the moves since may have used up. A step that moves further, or whose
list did not fit (Simulation then doubles its room: with_room), visits a spatial hash of
the primitives' swept boxes directly (each pair found once, in its canonical cell).
The list's queries run on the threads, each run listing into rows of its own, moved into
place in order; everything else is serial. Everything is in a fixed order: results are
bit-for-bit the same on every run and thread count.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from numba.core import types
from numba.extending import register_jitable

from clothjit import KernelPointer, njit, prange

from .collider_contact import (FACE_PUSHES, MOVED_OUT, NOT_KEPT, PATH_STOPS, PIN_POINT, PIN_STEP,
                               solid_faces)
from .ccd import (edge_edge_distance, edge_edge_impact, orient, point_triangle_distance,
                  point_triangle_impact)
from .forces import CHUNKS, _chunk
from .mesh_contact import MeshContact, mesh_pointers, pack_meshes
from .self_collision import cell_hash

CCD_ROUNDS = 4
# a pair found closer than DEEP_GAP h: up to PROXIMITY_ROUNDS more rounds of proximity, in
# place (the averaged pushes of one round fall short where layers are pressed together, as
# in a cloth wrung into a rope)
DEEP_GAP, PROXIMITY_ROUNDS = 0.75, 4
PRESSED_GAP = 0.5  # a last round that finds a pair closer than this, in h: stats[PRESSED]
# the candidate list: every pair within h plus its skins at its making, good while no point
# has moved further than its skin from there (then no pair outside can have come within h,
# nor meet on the straight paths of a step inside that range). A point's skin, in h: SKIN
# in the first list, then its move while the last list held at that rate over SKIN_CALLS
# calls of robust_contact, at least SKIN_SHRINK times its last (a point that moved back and
# forth keeps some), within [SKIN_MIN, SKIN_MAX]
SKIN, SKIN_MIN, SKIN_MAX = 0.5, 0.125, 1.0
SKIN_CALLS, SKIN_SHRINK = 32.0, 0.75
LIST_CELL = 0.5  # the list's grid cells, in the triangles' mean box side
GAP_BINS = 16  # the list is kept in order of these bins of its pairs' slack, in [0, 1]
LISTED_PER_POINT = 64  # room in the list at first; with_room doubles it when it overflows
LIST_HITS = 1024  # room for the entries a query meets (_list_pairs; taken in turns past it)
NEIGHBOURS = 8  # pairs within h at rest learnt per primitive (RobustContact.neighbours)
MAX_LISTED_PER_POINT = 1024  # beyond this, the steps visit the hash directly
BATCH = 1024  # _visit hands the pairs it finds on the hash to _listed this many at a time
OVERFLOWED = -2  # RobustContact.count: the list made at `anchor` did not fit
BINS = 3  # RobustContact.count: where the slack bins' starts begin
IMPACT_GAP = 0.1  # CCD stops a pair at this fraction of the thickness apart
TOLERANCE = 1e-6  # of the thickness: a pair this close at a coplanar instant meets
STATS = 16  # stats: pairs tested, proximity pushes, CCD hits, fail-safe points,
#            unresolvable pairs, smallest gap (in thickness, at the step's end), steps,
#            candidate lists made; then the colliders' (pipeline.physics.collider_contact);
#            then PRESSED, PRESSED_STEP
# steps whose last proximity round still found a pair closer than PRESSED_GAP h, and the
# first
PRESSED, PRESSED_STEP = 14, 15


class RobustContact(NamedTuple):
    """The packed robust self-contact of a cloth (System.contact)."""

    thickness: float
    friction: float
    triangles: np.ndarray  # (T, 3) int64
    edges: np.ndarray  # (E, 2) int64
    rest: np.ndarray  # (3, N) rest positions (pairs closer than h there are neighbours)
    inv_mass: np.ndarray  # (N,) 1 / mass, 0 for pinned points
    start: np.ndarray  # (3, N) scratch: x0
    push: np.ndarray  # (3, N) scratch: corrections summed (the colliders' pass too)
    pushes: np.ndarray  # (N,) scratch: corrections counted
    frozen: np.ndarray  # (N,) uint8 scratch
    box: np.ndarray  # (6, max(T, E)) scratch: swept boxes
    bucket_start: np.ndarray  # (H + 1,) int64 scratch of the hash (_grid: of the grid)
    bucket_work: np.ndarray  # (2, H) int64 scratch of _build: each bucket's fill, last box
    #                          (_grid: each cell's fill, each box's place)
    entries: np.ndarray  # (cap,) int64 scratch of the hash: the primitives, by bucket
    entry_box: np.ndarray  # (9, cap) scratch: their boxes in the same order (read in turn),
    #                        then the cell of each box's lower corner (_grid: the boxes)
    roots: np.ndarray  # (4,) scratch of the cubic's roots
    ids: np.ndarray  # (BATCH, 5) int64 scratch: the pairs _visit finds on the hash, in
    #                  turns; _make_list's, one at a time
    listed: np.ndarray  # (cap, 5) int64: the candidate pairs (4 points, kind) near at `anchor`
    listed_gap: np.ndarray  # (cap,) their distance at `anchor`
    count: np.ndarray  # (BINS + GAP_BINS + 1,) int64 pairs listed; -1: no valid list;
    #                    OVERFLOWED: count[1] pairs at `anchor`, more than its room
    #                    (Simulation makes room: with_room); count[2]: stats[6] (the calls)
    #                    when it was made; from count[BINS]: where each slack bin starts
    anchor: np.ndarray  # (4, N) where each point was when the list was made, and its skin
    #                     (row 3, see SKIN)
    moved: np.ndarray  # (N,) scratch: each point's move from `anchor` (see _drift)
    stats: np.ndarray  # (STATS,) float64, summed over the run (smallest gap: minimum)
    deep: np.ndarray  # (3,) int64 scratch: pairs a proximity round found closer than DEEP_GAP
    #                   h, and than PRESSED_GAP h; 1 while a round moves points at once
    # pairs found within h at rest (neighbours, never listed), learnt as _make_list meets
    # them: point p's triangles neighbours[p, :neighbour_count[p]], edge e's edges in row
    # N + e (at most NEIGHBOURS a primitive; the others are measured again at each making)
    neighbours: np.ndarray
    neighbour_count: np.ndarray
    hits: np.ndarray  # (CHUNKS, LIST_HITS) int64 scratch of _make_list's runs
    found: np.ndarray  # (CHUNKS,) int64 scratch: the pairs each run of _make_list found
    self_on: bool = True  # self-contact too (else the colliders' robust pass only)
    meshes: MeshContact | None = None  # the mesh colliders' triangles (none: no rows)
    # mesh_contact.mesh_colliders and its stages for solid and one-sided meshes, through
    # pointers absent where the scene has no such mesh (every scene's RobustContact has one
    # type, so robust contact's kernels compile once for all): mesh_contact.mesh_pointers
    mesh_pass: KernelPointer | None = None
    solid_stage: KernelPointer | None = None
    sheet_stage: KernelPointer | None = None
    # collider_contact.solid_faces (a sphere's or box's stage 2), absent where the scene has
    # neither
    solid_pass: KernelPointer | None = None
    # _make_list's runs on the threads (_list_runs) and their queries (_list_pairs), absent
    # without self-contact
    list_runs: KernelPointer | None = None
    list_pairs: KernelPointer | None = None
    # _visit through a pointer: compiled once, not again inside robust_contact (a first use
    # of robust contact compiled 12 s with it linked there); None in the params it is handed
    visit: KernelPointer | None = None


def pack_contact(thickness: float, friction: float, triangles: np.ndarray,
                 rest: np.ndarray, mass: np.ndarray, pinned: np.ndarray,
                 self_on: bool = True, meshes: MeshContact | None = None,
                 solids: bool = False) -> RobustContact:
    """RobustContact for a cloth of `triangles` (T, 3) at rest in `rest` (3, N); without
    `self_on`, for the colliders' robust pass alone (no self-contact scratch); `meshes`:
    the scene's mesh colliders (mesh_contact.pack_meshes), none by default; `solids`:
    whether the scene has a sphere or a box collider (none by default: their stage's
    kernel is compiled only where it is)."""
    if meshes is None:
        meshes = pack_meshes((), rest.shape[1])
    # a writeable copy: a mesh's triangles are read-only, a type of its own to numba (every
    # robust contact kernel compiled again for a mesh cloth)
    tris = np.array(triangles, dtype=np.int64, order="C")
    pairs = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    edges = np.unique(pairs, axis=0)
    n = rest.shape[1]
    m = n if self_on else 0  # the self-contact's scratch
    size = 1
    while size < 4 * max(len(tris), len(edges)) * self_on:
        size <<= 1
    inv = np.where(pinned != 0, 0.0, 1.0 / mass)
    room = max(LISTED_PER_POINT * m, BATCH * self_on)  # _listed reads a batch's gaps too
    stats = np.zeros(STATS)
    stats[5] = math.inf
    stats[PIN_POINT] = -1.0  # no pinned point forced into a collider yet
    c = RobustContact(float(thickness), float(friction), tris, edges,
                      np.ascontiguousarray(rest, dtype=np.float64), inv,
                      np.zeros((3, n)), np.zeros((3, n)), np.zeros(n), np.zeros(m, np.uint8),
                      np.zeros((6, max(len(tris), len(edges)) if self_on else 0)),
                      np.zeros(size + 1, np.int64), np.zeros((2, size), np.int64),
                      np.zeros(4 * size, np.int64),
                      np.zeros((9, 4 * size)), np.zeros(4), np.zeros((BATCH, 5), np.int64),
                      np.zeros((room, 5), np.int64), np.zeros(room), _no_list(),
                      np.concatenate([np.zeros((3, m)), np.full((1, m), SKIN * thickness)]),
                      np.zeros(m), stats, np.zeros(3, np.int64),
                      np.zeros(((n + len(edges)) * self_on, NEIGHBOURS), np.int64),
                      np.zeros((n + len(edges)) * self_on, np.int64),
                      np.zeros((CHUNKS, LIST_HITS * self_on), np.int64),
                      np.zeros(CHUNKS, np.int64), bool(self_on))
    field = types.float64[:, ::1]
    passes = mesh_pointers(meshes, c.edges, inv, stats)
    solid = KernelPointer(solid_faces, (
        field, tris, inv, c.push, c.pushes, stats, types.int64, field, types.int64[::1], field,
        types.float64[:, :, ::1], types.int64), types.int64, present=bool(solids))
    c = c._replace(meshes=meshes, mesh_pass=passes[0], solid_stage=passes[1],
                   sheet_stage=passes[2], solid_pass=solid)
    grid = types.UniTuple(types.float64, 10)  # _grid's
    i64, f64, arrays = types.int64, types.float64, _list_arrays(c)
    pairs = KernelPointer(_list_pairs, (field, i64, i64, i64, grid, f64, arrays, c.hits[0],
                                        c.ids[0], i64, i64), i64, present=bool(self_on))
    runs = KernelPointer(_list_runs, (field, i64, i64, grid, f64, arrays, c.hits, c.ids, i64,
                                      i64, c.found, pairs), present=bool(self_on))
    c = c._replace(list_runs=runs, list_pairs=pairs)
    return c._replace(visit=KernelPointer(_visit, (field, field, c, types.int64, types.float64),
                                          types.int64, present=bool(self_on)))


def with_room(c: RobustContact) -> RobustContact:
    """c with room in its candidate list for 1.25 times the pairs that overflowed it (at
    least twice its room, at most MAX_LISTED_PER_POINT a point), else c itself: the list is
    made again at the next step, the hash no longer visited every step (the first list of
    an 80x80 cloth at rest holds about 73 pairs a point)."""
    n = c.rest.shape[1]
    if c.count[0] != OVERFLOWED or c.listed.shape[0] >= MAX_LISTED_PER_POINT * n:
        return c
    cap = min(max(2 * c.listed.shape[0], int(1.25 * c.count[1])), MAX_LISTED_PER_POINT * n)
    return c._replace(listed=np.zeros((cap, 5), np.int64), listed_gap=np.zeros(cap),
                      count=_no_list())


@register_jitable
def _list_arrays(c):
    """The arrays _make_list's queries read and write, in _list_pairs's order (one argument
    for the pointers between them, not thirteen; from Python too, for their types)."""
    return (c.triangles, c.edges, c.box, c.anchor[3], c.rest, c.neighbours, c.neighbour_count,
            c.entry_box, c.bucket_start, c.entries, c.bucket_work[1], c.listed, c.listed_gap)


def _no_list() -> np.ndarray:
    """RobustContact.count with no valid list."""
    count = np.zeros(BINS + GAP_BINS + 1, np.int64)
    count[0] = -1
    return count


def contact_summary(c: RobustContact, steps_per_frame: int = 1) -> str:
    """One line on what the robust contact did over the run so far."""
    s = c.stats
    steps = max(s[6], 1.0)
    parts = []
    if c.self_on:
        gap = ("none closer than the thickness" if not np.isfinite(s[5])
               else f"{s[5]:.2f} x thickness")
        parts.append(f"{s[0] / steps:.0f} pairs tested a step, {s[1]:.0f} proximity pushes, "
                     f"{s[2]:.0f} CCD stops, {s[3]:.0f} points held by the fail-safe; smallest "
                     f"gap found: {gap}")
    parts.append(f"colliders: {s[PATH_STOPS]:.0f} paths stopped at a surface, "
                 f"{s[MOVED_OUT]:.0f} points moved out, {s[FACE_PUSHES]:.0f} triangles or "
                 "edges pushed out")
    line = "robust contact: " + "; ".join(parts)
    if s[PRESSED] > 0:
        frame = int(s[PRESSED_STEP] - 1) // steps_per_frame + 1
        line += (f"; from frame {frame}, {s[PRESSED]:.0f} steps ended with layers still "
                 f"pressed closer than {PRESSED_GAP:g} x thickness after {PROXIMITY_ROUNDS + 1} "
                 "rounds of pushes (the cloth pulls them together faster than the contact "
                 'parts them; simulation.integrator "vbd" holds contact inside its solve)')
    if s[4] > 0:
        line += f"; {s[4]:.0f} pairs met with no point free to move (pins forcing them)"
    if s[PIN_POINT] >= 0:
        frame = int(s[PIN_STEP] - 1) // steps_per_frame + 1
        line += (f"; pinned point {int(s[PIN_POINT])} is inside a collider from frame {frame} "
                 f"(pins forcing the cloth into it: no valid state)")
    elif s[NOT_KEPT] > 0:
        line += (f"; {s[NOT_KEPT]:.0f} times a triangle or an edge stayed in a collider after "
                 "its rounds")
    return line


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _p(x, i):
    return (x[0, i], x[1, i], x[2, i])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _lerp(x0, x1, i, t):
    """Point i at time t of its straight path from x0 to x1."""
    return (x0[0, i] + t * (x1[0, i] - x0[0, i]), x0[1, i] + t * (x1[1, i] - x0[1, i]),
            x0[2, i] + t * (x1[2, i] - x0[2, i]))


# --- the spatial hash of swept boxes ---------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def _boxes(x0, x1, prims, margin, skin, grow, box):
    """box[:, k] = the swept box of primitive k (its points at x0 and x1), grown by margin
    plus `grow` times the largest skin of its points; returns the mean of the boxes' largest
    sides."""
    total = 0.0
    for k in range(prims.shape[0]):
        side = 0.0
        out = 0.0
        for j in range(prims.shape[1]):
            out = max(out, skin[prims[k, j]])
        out = margin + grow * out
        for a in range(3):
            lo, hi = math.inf, -math.inf
            for j in range(prims.shape[1]):
                i = prims[k, j]
                lo = min(lo, x0[a, i], x1[a, i])
                hi = max(hi, x0[a, i], x1[a, i])
            box[a, k], box[3 + a, k] = lo - out, hi + out
            side = max(side, hi - lo + 2.0 * out)
        total += side
    return total / max(prims.shape[0], 1)


@njit(cache=True, nogil=True, error_model="numpy")
def _build(box, count, cell, bucket_start, work, entries, entry_box):
    """Hash `count` boxes into cells of side `cell`; False if the entries do not fit. A box
    goes once into each bucket, however many of its cells hash there (a second copy would
    make its pairs twice)."""
    size = bucket_start.shape[0] - 1
    mask = size - 1
    bucket_start[:] = 0
    fill, last = work[0], work[1]  # each bucket's next slot, the last box put in it
    last[:] = -1
    total = 0
    for k in range(count):
        lo = (math.floor(box[0, k] / cell), math.floor(box[1, k] / cell), math.floor(box[2, k] / cell))
        hi = (math.floor(box[3, k] / cell), math.floor(box[4, k] / cell), math.floor(box[5, k] / cell))
        for ix in range(lo[0], hi[0] + 1):
            for iy in range(lo[1], hi[1] + 1):
                for iz in range(lo[2], hi[2] + 1):
                    b = cell_hash(ix, iy, iz, mask)
                    if last[b] != k:
                        last[b] = k
                        bucket_start[b + 1] += 1
                        total += 1
    if total > entries.shape[0]:
        return False
    for b in range(size):
        bucket_start[b + 1] += bucket_start[b]
    for b in range(size):
        fill[b] = bucket_start[b]
    last[:] = -1
    for k in range(count):
        lo = (math.floor(box[0, k] / cell), math.floor(box[1, k] / cell), math.floor(box[2, k] / cell))
        hi = (math.floor(box[3, k] / cell), math.floor(box[4, k] / cell), math.floor(box[5, k] / cell))
        for ix in range(lo[0], hi[0] + 1):
            for iy in range(lo[1], hi[1] + 1):
                for iz in range(lo[2], hi[2] + 1):
                    b = cell_hash(ix, iy, iz, mask)
                    if last[b] == k:
                        continue
                    last[b] = k
                    entries[fill[b]] = k
                    for a in range(6):
                        entry_box[a, fill[b]] = box[a, k]
                    for a in range(3):
                        entry_box[6 + a, fill[b]] = lo[a]
                    fill[b] += 1
    return True


# --- pairs -----------------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def _shares(tri, p):
    return tri[0] == p or tri[1] == p or tri[2] == p


@njit(cache=True, nogil=True, error_model="numpy")
def _rest_close(rest, h, ids):
    """Whether the pair (4 point ids: p, a, b, c or a, b, c, d) lies within h at `rest`
    (neighbours in a fine mesh: never a contact)."""
    if ids[4] == 0:
        d = point_triangle_distance(_p(rest, ids[0]), _p(rest, ids[1]), _p(rest, ids[2]),
                                    _p(rest, ids[3]))[0]
    else:
        d = edge_edge_distance(_p(rest, ids[0]), _p(rest, ids[1]), _p(rest, ids[2]),
                               _p(rest, ids[3]))[0]
    return d < h


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def _visit(x0, x1, c, mode, cell):
    """Visit every candidate pair once: mode 0 CCD responses, else proximity at x1; 1 CCD
    responses only; 2 CCD detection for the fail-safe (freezing); 3 make the candidate list
    at x1 (_make_list); 4-6 modes 0-2 over it (_listed; `cell`: the drift). Returns the
    pairs acted on. On the hash, the triangles' and edges' boxes grow by the margin (h for
    proximity), the points' not: a box pair overlaps where the primitives may be within the
    margin; its pairs go to _listed in batches. Without numba's reference counts
    (`_nrt=False`, as _listed: nothing here allocates, the pairs are scratch): at every
    pair numba counted the references to the RobustContact's arrays that the inlined _pair
    takes, which tripled the cost of robust contact."""
    if mode >= 4:
        end = c.count[BINS + min(int((cell + 1e-9) * GAP_BINS), GAP_BINS - 1) + 1]
        return _listed(x0, x1, c, mode - 4, c.listed, end, 0.0)
    if mode == 3:
        return _make_list(x1, c)
    tris, edges, box, eb, batch = c.triangles, c.edges, c.box, c.entry_box, c.ids
    h = c.thickness
    acted = 0
    count = 0
    margin = h if mode == 0 else h * TOLERANCE
    mask = c.bucket_start.shape[0] - 2
    # point-triangle (kind 0): hash the triangles, query each point's swept box; edge-edge
    # (1): hash the edges, query each edge's swept box against later edges (cells doubled
    # until the entries fit)
    for kind in range(2):
        prims = tris if kind == 0 else edges
        _boxes(x0, x1, prims, margin / (1.0 + kind), c.anchor[3], 0.0, box)
        while not _build(box, prims.shape[0], cell, c.bucket_start, c.bucket_work, c.entries,
                             eb):
            cell *= 2.0
        for q in range(x0.shape[1] if kind == 0 else edges.shape[0]):
            if kind == 0:
                lo = (min(x0[0, q], x1[0, q]), min(x0[1, q], x1[1, q]), min(x0[2, q], x1[2, q]))
                hi = (max(x0[0, q], x1[0, q]), max(x0[1, q], x1[1, q]), max(x0[2, q], x1[2, q]))
            else:
                lo, hi = (box[0, q], box[1, q], box[2, q]), (box[3, q], box[4, q], box[5, q])
            q0, q1, q2 = (math.floor(lo[0] / cell), math.floor(lo[1] / cell),
                          math.floor(lo[2] / cell))
            for ix in range(q0, math.floor(hi[0] / cell) + 1):
                for iy in range(q1, math.floor(hi[1] / cell) + 1):
                    for iz in range(q2, math.floor(hi[2] / cell) + 1):
                        b = cell_hash(ix, iy, iz, mask)
                        for e in range(c.bucket_start[b], c.bucket_start[b + 1]):
                            k = c.entries[e]
                            if kind == 1 and k <= q:
                                continue
                            if (eb[0, e] > hi[0] or eb[3, e] < lo[0] or eb[1, e] > hi[1]
                                    or eb[4, e] < lo[1] or eb[2, e] > hi[2] or eb[5, e] < lo[2]):
                                continue
                            # the canonical cell: that of the larger of the two lower corners
                            # (floor(max(a, b) / cell) = max of the floors: both monotone)
                            if (max(eb[6, e], q0) != ix or max(eb[7, e], q1) != iy
                                    or max(eb[8, e], q2) != iz):
                                continue
                            if kind == 0:
                                if _shares(tris[k], q):
                                    continue
                                ids = (q, tris[k, 0], tris[k, 1], tris[k, 2])
                            else:
                                ids = (edges[q, 0], edges[q, 1], edges[k, 0], edges[k, 1])
                                if (ids[0] == ids[2] or ids[0] == ids[3] or ids[1] == ids[2]
                                        or ids[1] == ids[3]):
                                    continue
                            for j in range(4):
                                batch[count, j] = ids[j]
                            batch[count, 4] = kind
                            count += 1
                            if count == batch.shape[0]:
                                acted += _listed(x0, x1, c, mode, batch, count, math.inf)
                                count = 0
    # np.int64: numba types the count here as the literal 0 and would compile _listed again
    return acted + _listed(x0, x1, c, mode, batch, np.int64(count), math.inf)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _skins(skin, ids):
    """The pair's skins: the largest of each primitive's points'."""
    if ids[4] == 0:
        return skin[ids[0]] + max(skin[ids[1]], skin[ids[2]], skin[ids[3]])
    return max(skin[ids[0]], skin[ids[1]]) + max(skin[ids[2]], skin[ids[3]])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _slack_bin(listed, gap, skin, h, k):
    """The bin of listed pair k's slack: its distance beyond h at the making over its skins
    (a pair's points move no further than f times their skins: the pairs in the bins past
    f GAP_BINS stay further than h apart)."""
    slack = (gap[k] - h) / _skins(skin, listed[k])
    return min(int(max(slack, 0.0) * GAP_BINS), GAP_BINS - 1)


@njit(cache=True, nogil=True, error_model="numpy")
def _by_gap(listed, gap, count, start, fill, skin, h):
    """Order the `count` listed pairs by slack bin, in place (a fixed order of swaps: the
    same every run); start: where each bin starts; fill: scratch."""
    start[:] = 0
    # each pair's bin once, kept beside its kind (listed[:, 4] is 0 or 1) while it moves
    for k in range(count):
        b = _slack_bin(listed, gap, skin, h, k)
        start[b + 1] += 1
        listed[k, 4] += 2 * b
    for b in range(GAP_BINS):
        start[b + 1] += start[b]
        fill[b] = start[b]
    for b in range(GAP_BINS):
        while fill[b] < start[b + 1]:
            k = fill[b]
            d = listed[k, 4] >> 1
            if d == b:
                fill[b] += 1
                continue
            j = fill[d]  # k goes to bin d's next place, what was there to k
            fill[d] += 1
            gap[k], gap[j] = gap[j], gap[k]
            for i in range(5):
                listed[k, i], listed[j, i] = listed[j, i], listed[k, i]
    for k in range(count):
        listed[k, 4] &= 1


@njit(cache=True, nogil=True, error_model="numpy")
def _grid(box, count, cell, start, fill, slot, entries, eb):
    """Sort `count` boxes into a grid of cells of side `cell` (coarser where it would have
    more cells than `fill` holds), each box once, in the cell of its lower corner, in the
    order of the cells (along x, then y, then z) and within one in that of the boxes: cell
    q's boxes are entries[start[q]:start[q + 1]], their boxes in eb's rows 0-5 in the same
    order, box k at slot[k]. Returns the grid: its lower corner (3), cell, the largest box
    sides (3; a box that overlaps another has its lower corner at most that far below the
    other's) and the cells along each axis (3)."""
    lo0 = lo1 = lo2 = math.inf
    hi0 = hi1 = hi2 = -math.inf
    s0 = s1 = s2 = 0.0
    for k in range(count):
        lo0, lo1, lo2 = min(lo0, box[0, k]), min(lo1, box[1, k]), min(lo2, box[2, k])
        hi0, hi1, hi2 = max(hi0, box[0, k]), max(hi1, box[1, k]), max(hi2, box[2, k])
        s0, s1, s2 = (max(s0, box[3, k] - box[0, k]), max(s1, box[4, k] - box[1, k]),
                      max(s2, box[5, k] - box[2, k]))
    while True:
        n0, n1, n2 = (math.floor((hi0 - lo0) / cell) + 1.0, math.floor((hi1 - lo1) / cell) + 1.0,
                      math.floor((hi2 - lo2) / cell) + 1.0)
        if n0 * n1 * n2 <= fill.shape[0]:
            break
        cell *= 1.25
    # the sides with a rounding's margin: a query computes its lowest cell from them
    pad = 1.0 + 1e-9
    g = (lo0, lo1, lo2, cell, s0 * pad, s1 * pad, s2 * pad, n0, n1, n2)
    cells = int(n0 * n1 * n2)
    start[:cells + 1] = 0
    for k in range(count):
        start[_cell_of(g, box, k) + 1] += 1
    for q in range(cells):
        start[q + 1] += start[q]
        fill[q] = start[q]
    for k in range(count):
        q = _cell_of(g, box, k)
        e = fill[q]
        fill[q] += 1
        entries[e] = k
        slot[k] = e
        for a in range(6):
            eb[a, e] = box[a, k]
    return g


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _axis_cell(g, a, v):
    """The cell along axis a of the grid g (_grid) that holds the coordinate v."""
    return min(math.floor((v - g[a]) / g[3]), int(g[7 + a]) - 1)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cell_of(g, box, k):
    """The grid cell of box k's lower corner."""
    return (_axis_cell(g, 0, box[0, k])
            + int(g[7]) * (_axis_cell(g, 1, box[1, k]) + int(g[8]) * _axis_cell(g, 2, box[2, k])))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _span(g, a, lo, hi):
    """The cells along axis a of the grid g that may hold the lower corner of a box
    overlapping [lo, hi] on that axis."""
    return max(math.floor((lo - g[4 + a] - g[a]) / g[3]), 0), _axis_cell(g, a, hi)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _make_list(x, c):
    """List every pair within h plus its skins at x that are not neighbours at rest (in
    order of slack: _by_gap), on grids of the triangles' and the edges' boxes grown by h
    and h / 2 plus their skins (_grid; each box once, in its cell: cheaper than the hash,
    whose boxes lie in every cell they meet and whose pairs are met in every cell both
    do): a point looks at the triangles in the cells that may hold the lower corner of a
    box meeting its own, an edge likewise at the edges from its own place in the grid on
    (a pair met from one of its edges only). The queries run in CHUNKS runs on the threads
    (c.list_runs), each listing into its own share of the free rows, then moved up in
    order: the same list on any thread count. The steps' own visits keep the hash: a fast
    point's swept box can be far larger than the others, and on the grid every query
    would look that far below its own box. Returns 0."""
    tris, edges, box, skin = c.triangles, c.edges, c.box, c.anchor[3]
    h = c.thickness
    eb, start, fill, slot, found = (c.entry_box, c.bucket_start, c.bucket_work[0],
                                    c.bucket_work[1], c.found)
    rows = c.listed.shape[0]
    total = 0  # pairs found so far (listed while they fit)
    cell = LIST_CELL * _boxes(x, x, tris, h, skin, 1.0, box)
    for kind in range(2):  # point-triangle, edge-edge (one loop: it compiles once)
        prims = tris if kind == 0 else edges
        if kind == 1:
            _boxes(x, x, edges, 0.5 * h, skin, 1.0, box)
        g = _grid(box, prims.shape[0], cell, start, fill, slot, c.entries, eb)
        queries = x.shape[1] if kind == 0 else edges.shape[0]
        base = min(total, rows)
        share = (rows - base) // CHUNKS
        c.list_runs(x, kind, queries, g, h, _list_arrays(c), c.hits, c.ids, base, share, found,
                    c.list_pairs)
        fits, here = True, 0
        for run in range(CHUNKS):
            fits &= found[run] <= share
            here += found[run]
        if fits:
            for run in range(CHUNKS):  # each run's pairs after the last's, in order
                for k in range(found[run]):
                    at, to = base + run * share + k, total + k
                    for j in range(5):
                        c.listed[to, j] = c.listed[at, j]
                    c.listed_gap[to] = c.listed_gap[at]
                total += found[run]
        elif total + here <= rows:  # a share, not the rows, too small: again in one run
            total += c.list_pairs(x, kind, 0, queries, g, h, _list_arrays(c), c.hits[0],
                                  c.ids[0], base, rows)
        else:
            total += here
    c.count[0] = total  # past the rows: no valid list (_round)
    if c.count[0] <= rows:
        _by_gap(c.listed, c.listed_gap, c.count[0], c.count[BINS:], fill, skin, h)
    return 0


@njit(cache=True, nogil=True, error_model="numpy", parallel=True, no_cpython_wrapper=True,
      pointer=True)
def _list_runs(x, kind, count, g, h, arrays, hits, ids, base, share, found, pairs):
    """The `count` queries of `kind` in CHUNKS runs on the threads (`pairs`: the
    _list_pairs pointer), run r listing into listed[base + r share:][:share] and counting
    its pairs in found[r] (past its share too: then they did not fit)."""
    for run in prange(CHUNKS):
        lo, hi = _chunk(run, count)
        at = base + run * share
        found[run] = pairs(x, kind, lo, hi, g, h, arrays, hits[run], ids[run], at, at + share)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def _list_pairs(x, kind, lo, hi, g, h, arrays, hits, ids, at, end):
    """_make_list's queries lo..hi of `kind` on the grid g (_grid), listing their pairs in
    order into listed[at:end] and their distances into gap; returns how many pairs it
    found (past `end` too). hits: scratch for the entries a query meets, ids: for a pair."""
    (tris, edges, box, skin, rest, neighbours, neighbour_count, eb, start, entries, slot,
     listed, gap) = arrays
    n0, n1 = int(g[7]), int(g[8])
    first_at = at
    for q in range(lo, hi):
        if kind == 0:
            qlo = (x[0, q] - skin[q], x[1, q] - skin[q], x[2, q] - skin[q])
            qhi = (x[0, q] + skin[q], x[1, q] + skin[q], x[2, q] + skin[q])
        else:
            qlo, qhi = (box[0, q], box[1, q], box[2, q]), (box[3, q], box[4, q], box[5, q])
        a0, b0 = _span(g, 0, qlo[0], qhi[0])
        a1, b1 = _span(g, 1, qlo[1], qhi[1])
        a2, b2 = _span(g, 2, qlo[2], qhi[2])
        # an edge looks from its own place in the grid on: the edges before it meet it
        own, oy, oz = slot[q], _axis_cell(g, 1, qlo[1]), _axis_cell(g, 2, qlo[2])
        met = 0  # the entries whose boxes meet the query's: hits[:met], in the rows' order
        for iz in range(a2 if kind == 0 else oz, b2 + 1):
            for iy in range(a1 if kind == 0 or iz > oz else oy, b1 + 1):
                row = n0 * (iy + n1 * iz)
                first = own + 1 if kind == 1 and iz == oz and iy == oy else start[row + a0]
                for e in range(first, start[row + b0 + 1]):
                    # no branch on the tests (their outcomes are unpredictable, and a
                    # mispredicted branch costs more than they do): every entry is written,
                    # and kept by counting it
                    hits[met] = e
                    met += ((eb[0, e] <= qhi[0]) & (eb[3, e] >= qlo[0])
                            & (eb[1, e] <= qhi[1]) & (eb[4, e] >= qlo[1])
                            & (eb[2, e] <= qhi[2]) & (eb[5, e] >= qlo[2]))
                    if met == hits.shape[0]:
                        at = _pairs_met(x, kind, q, hits, met, tris, edges, entries, skin,
                                        rest, neighbours, neighbour_count, h, ids, listed, gap,
                                        at, end)
                        met = 0
        at = _pairs_met(x, kind, q, hits, met, tris, edges, entries, skin, rest, neighbours,
                        neighbour_count, h, ids, listed, gap, at, end)
    return at - first_at


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _pairs_met(x, kind, q, hits, met, tris, edges, entries, skin, rest, neighbours,
               neighbour_count, h, ids, listed, gap, at, end):
    """List the pairs of query q with the entries hits[:met] that share no point with
    it, within h plus their skins at x, not within h at rest (those it learns: not measured
    again), at row `at` on (below `end`); returns the next row."""
    row = q if kind == 0 else neighbours.shape[0] - edges.shape[0] + q
    known = neighbour_count[row]
    for j in range(met):
        k = entries[hits[j]]
        if kind == 0:
            if _shares(tris[k], q):
                continue
            ids[0], ids[1], ids[2], ids[3] = q, tris[k, 0], tris[k, 1], tris[k, 2]
        else:
            u, v, w, z = edges[q, 0], edges[q, 1], edges[k, 0], edges[k, 1]
            if u == w or u == z or v == w or v == z:
                continue
            if k < q:  # in the order of the edges
                u, v, w, z = w, z, u, v
            ids[0], ids[1], ids[2], ids[3] = u, v, w, z
        if _among(neighbours[row], known, k):
            continue
        ids[4] = kind
        d = _distance(x, ids)
        if d > h + _skins(skin, ids):
            continue
        if _rest_close(rest, h, ids):  # learnt: not measured again
            if neighbour_count[row] < neighbours.shape[1]:
                neighbours[row, neighbour_count[row]] = k
                neighbour_count[row] += 1
            continue
        if at < end:
            for i in range(5):
                listed[at, i] = ids[i]
            gap[at] = d
        at += 1
    return at


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _among(values, count, k):
    """Whether k is among values[:count]."""
    for j in range(count):
        if values[j] == k:
            return True
    return False


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _listed(x0, x1, c, mode, listed, end, slack):
    """_visit's modes 0-2 over the pairs listed[:end]: a pair is skipped where its distance
    at the list's making (c.listed_gap), less what its two primitives' points may have moved
    since (c.moved), and `slack` leaves it further than h (mode 0) or apart (CCD) all
    through the step (slack inf: none skipped; a flag would have numba compile the loop,
    and _pair in it, twice). The one place _pair is inlined (it compiles for seconds)."""
    acted = 0
    h = c.thickness
    reach = h if mode == 0 else h * TOLERANCE
    moved, gap = c.moved, c.listed_gap
    for k in range(end):
        m0, m1, m2, m3 = (moved[listed[k, 0]], moved[listed[k, 1]], moved[listed[k, 2]],
                          moved[listed[k, 3]])
        # a point of a triangle or edge moves no further than its farthest corner
        near = (m0 + max(m1, m2, m3) if listed[k, 4] == 0 else max(m0, m1) + max(m2, m3))
        if gap[k] > reach + near + slack:
            continue
        acted += _pair(x0, x1, c, mode, listed[k])
    return acted


@njit(cache=True, nogil=True, error_model="numpy")
def _drift(x0, x1, anchor, moved):
    """The largest move of any point at x0 or at x1 from the anchor, less the cloth's mean
    move at each, over its skin: a common move changes no distance, and on the straight
    paths between x0 and x1 a point's move less the interpolated mean stays within the
    larger of the two. moved[i]: that larger move of point i."""
    n = anchor.shape[1]
    moved[:] = 0.0
    for x in (x0, x1):
        m0 = m1 = m2 = 0.0
        for i in range(n):
            m0 += x[0, i] - anchor[0, i]
            m1 += x[1, i] - anchor[1, i]
            m2 += x[2, i] - anchor[2, i]
        m0, m1, m2 = m0 / n, m1 / n, m2 / n
        for i in range(n):
            d = ((x[0, i] - anchor[0, i] - m0) ** 2 + (x[1, i] - anchor[1, i] - m1) ** 2
                 + (x[2, i] - anchor[2, i] - m2) ** 2)
            moved[i] = max(moved[i], d)
    worst = 0.0
    for i in range(n):
        moved[i] = math.sqrt(moved[i])
        worst = max(worst, moved[i] / anchor[3, i])
    return worst


@njit(cache=True, nogil=True, error_model="numpy")
def _round(start, x, c, visit, mode):
    """One visit of every pair in `mode` (0-2), from the candidate list where it holds (made
    again, with new skins, where a point has moved further than its skin from where it was
    made), else the hash."""
    # an overflowed list is tried again only where the points have moved from where it was
    # (then the steps visit the hash)
    drift = _drift(start, x, c.anchor, c.moved) if c.count[0] != -1 else math.inf
    if drift > 1.0:
        if c.count[0] != -1:  # each point's skin from its move since the last list
            h = c.thickness
            rate = SKIN_CALLS / max(c.stats[6] - c.count[2], 1.0)
            skin = c.anchor[3]
            for i in range(x.shape[1]):
                skin[i] = min(max(c.moved[i] * rate, SKIN_SHRINK * skin[i], SKIN_MIN * h),
                              SKIN_MAX * h)
        c.count[2] = c.stats[6]
        c.stats[7] += 1.0
        for a in range(3):
            for i in range(x.shape[1]):
                c.anchor[a, i] = x[a, i]
        visit(x, x, c, 3, 0.0)
        if c.count[0] > c.listed.shape[0]:  # no valid list until the points have moved
            c.count[1] = c.count[0]
            c.count[0] = OVERFLOWED
        drift = _drift(start, x, c.anchor, c.moved)
    if c.count[0] >= 0 and drift <= 1.0:
        return visit(start, x, c, 4 + mode, drift)
    return visit(start, x, c, mode, _cell(start, x, c))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _pair(x0, x1, c, mode, ids):
    """One candidate pair (ids: 4 points and the kind, 0 point-triangle, 1 edge-edge)."""
    h = c.thickness
    c.stats[0] += 1.0
    i0, i1, i2, i3 = ids[0], ids[1], ids[2], ids[3]
    kind = ids[4]
    tol = h * TOLERANCE
    # swept boxes further apart than h (mode 0) or the tolerance: neither a meeting nor
    # proximity at the end, and cheaper to tell than the distance
    if _apart(x0, x1, ids, h if mode == 0 else tol):
        return 0
    # the distance at the step's end; every point of the pair's paths is within `reach`
    # of its end, so no impact is possible where that distance exceeds 2 reach: the cubic
    # only for the others
    if kind == 0:
        d, u, v, w = point_triangle_distance(_p(x1, i0), _p(x1, i1), _p(x1, i2), _p(x1, i3))
        weights = (1.0, -u, -v, -w)
    else:
        d, s, tt = edge_edge_distance(_p(x1, i0), _p(x1, i1), _p(x1, i2), _p(x1, i3))
        weights = (1.0 - s, s, -(1.0 - tt), -tt)
    reach = _reach(x0, x1, ids)
    if d > 2.0 * reach + tol or _apart(x0, x1, ids, tol):
        t = -1.0
    elif kind == 0:
        t = point_triangle_impact(_p(x0, i0), _p(x0, i1), _p(x0, i2), _p(x0, i3),
                                  _p(x1, i0), _p(x1, i1), _p(x1, i2), _p(x1, i3), tol, c.roots)
    else:
        t = edge_edge_impact(_p(x0, i0), _p(x0, i1), _p(x0, i2), _p(x0, i3),
                             _p(x1, i0), _p(x1, i1), _p(x1, i2), _p(x1, i3), tol, c.roots)
    if t < 0.0:
        if mode != 0:
            return 0
        # no impact: proximity at the end of the step
        if d >= h or _rest_close(c.rest, h, ids):
            return 0
        c.stats[1] += 1.0
        c.stats[5] = min(c.stats[5], d / h)
        c.deep[0] += d < DEEP_GAP * h
        c.deep[1] += d < PRESSED_GAP * h
        _respond(x0, x1, c, ids, weights, _normal(x0, x1, ids, weights, d), h - d,
                 np.bool_(True))  # not literals: one _respond for both
        return 1
    if _rest_close(c.rest, h, ids):
        return 0
    if mode == 2:
        movable = 0
        for i in (i0, i1, i2, i3):
            if c.inv_mass[i] > 0.0:
                movable += 1
                c.frozen[i] = 1
        if movable == 0:
            c.stats[4] += 1.0  # pins moving into each other
        return 1
    # the weights of the closest points at the time of impact
    a0, a1, a2, a3 = (_lerp(x0, x1, i0, t), _lerp(x0, x1, i1, t), _lerp(x0, x1, i2, t),
                      _lerp(x0, x1, i3, t))
    if kind == 0:
        _, u, v, w = point_triangle_distance(a0, a1, a2, a3)
        weights = (1.0, -u, -v, -w)
    else:
        _, s, tt = edge_edge_distance(a0, a1, a2, a3)
        weights = (1.0 - s, s, -(1.0 - tt), -tt)
    normal = _normal(x0, x1, ids, weights, 0.0)
    # the end separation along the normal; stop the pair IMPACT_GAP h apart on its side
    sep = 0.0
    for j in range(4):
        for a in range(3):
            sep += weights[j] * x1[a, ids[j]] * normal[a]
    target = IMPACT_GAP * h
    if sep >= target:
        return 0
    c.stats[2] += 1.0
    _respond(x0, x1, c, ids, weights, normal, target - sep, np.bool_(False))
    return 1


@njit(cache=True, nogil=True, error_model="numpy")
def _apart(x0, x1, ids, tol):
    """Whether the swept boxes of the pair's two primitives are more than tol apart."""
    first = 1 if ids[4] == 0 else 2  # point | triangle, or edge | edge
    for a in range(3):
        lo1 = hi1 = x0[a, ids[0]]
        lo2 = hi2 = x0[a, ids[first]]
        for j in range(4):
            i = ids[j]
            lo, hi = min(x0[a, i], x1[a, i]), max(x0[a, i], x1[a, i])
            if j < first:
                lo1, hi1 = min(lo1, lo), max(hi1, hi)
            else:
                lo2, hi2 = min(lo2, lo), max(hi2, hi)
        if lo1 > hi2 + tol or lo2 > hi1 + tol:
            return True
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _reach(x0, x1, ids):
    """The longest move of the pair's points in the step."""
    reach = 0.0
    for j in range(4):
        i = ids[j]
        reach = max(reach, (x1[0, i] - x0[0, i]) ** 2 + (x1[1, i] - x0[1, i]) ** 2
                    + (x1[2, i] - x0[2, i]) ** 2)
    return math.sqrt(reach)


@njit(cache=True, nogil=True, error_model="numpy")
def _distance(x0, ids):
    """The pair's distance at x0."""
    if ids[4] == 0:
        return point_triangle_distance(_p(x0, ids[0]), _p(x0, ids[1]), _p(x0, ids[2]),
                                       _p(x0, ids[3]))[0]
    return edge_edge_distance(_p(x0, ids[0]), _p(x0, ids[1]), _p(x0, ids[2]), _p(x0, ids[3]))[0]


@njit(cache=True, nogil=True, error_model="numpy")
def _normal(x0, x1, ids, weights, d):
    """The unit normal along which the pair separates, pointing from the second primitive
    towards the first on the side they were at the step's start: the direction between
    their closest points at x1 when apart, else the triangle's normal (the edges' cross
    product), oriented by the start."""
    gap = (0.0, 0.0, 0.0)
    start = (0.0, 0.0, 0.0)
    for j in range(4):
        i = ids[j]
        gap = (gap[0] + weights[j] * x1[0, i], gap[1] + weights[j] * x1[1, i],
               gap[2] + weights[j] * x1[2, i])
        start = (start[0] + weights[j] * x0[0, i], start[1] + weights[j] * x0[1, i],
                 start[2] + weights[j] * x0[2, i])
    if ids[4] == 0:
        e1 = (x1[0, ids[2]] - x1[0, ids[1]], x1[1, ids[2]] - x1[1, ids[1]], x1[2, ids[2]] - x1[2, ids[1]])
        e2 = (x1[0, ids[3]] - x1[0, ids[1]], x1[1, ids[3]] - x1[1, ids[1]], x1[2, ids[3]] - x1[2, ids[1]])
    else:
        e1 = (x1[0, ids[1]] - x1[0, ids[0]], x1[1, ids[1]] - x1[1, ids[0]], x1[2, ids[1]] - x1[2, ids[0]])
        e2 = (x1[0, ids[3]] - x1[0, ids[2]], x1[1, ids[3]] - x1[1, ids[2]], x1[2, ids[3]] - x1[2, ids[2]])
    geo = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
    length = math.sqrt(gap[0] ** 2 + gap[1] ** 2 + gap[2] ** 2)
    if d > 0.0 and length > 0.0:
        n = (gap[0] / length, gap[1] / length, gap[2] / length)
    else:
        g = math.sqrt(geo[0] ** 2 + geo[1] ** 2 + geo[2] ** 2)
        n = (geo[0] / g, geo[1] / g, geo[2] / g) if g > 0.0 else (0.0, 1.0, 0.0)
    side = start[0] * n[0] + start[1] * n[1] + start[2] * n[2]
    if side < 0.0:
        n = (-n[0], -n[1], -n[2])
    return n


@njit(cache=True, nogil=True, error_model="numpy")
def _respond(x0, x1, c, ids, weights, normal, amount, friction):
    """Add to c.push the moves that separate the pair by `amount` more along `normal`,
    shared by inverse mass and weight; with `friction`, also damp its relative tangential
    motion over the step by at most friction * amount."""
    total = 0.0
    for j in range(4):
        total += weights[j] * weights[j] * c.inv_mass[ids[j]]
    if total <= 0.0:
        c.stats[4] += 1.0
        return
    tangential = (0.0, 0.0, 0.0)
    if friction and c.friction > 0.0:
        rel = (0.0, 0.0, 0.0)
        for j in range(4):
            i = ids[j]
            rel = (rel[0] + weights[j] * (x1[0, i] - x0[0, i]), rel[1] + weights[j] * (x1[1, i] - x0[1, i]),
                   rel[2] + weights[j] * (x1[2, i] - x0[2, i]))
        along = rel[0] * normal[0] + rel[1] * normal[1] + rel[2] * normal[2]
        tan = (rel[0] - along * normal[0], rel[1] - along * normal[1], rel[2] - along * normal[2])
        size = math.sqrt(tan[0] ** 2 + tan[1] ** 2 + tan[2] ** 2)
        if size > 0.0:
            cut = min(1.0, c.friction * amount / size)
            tangential = (-cut * tan[0], -cut * tan[1], -cut * tan[2])
    for j in range(4):
        i = ids[j]
        k = weights[j] * c.inv_mass[i] / total
        if k == 0.0:
            continue
        if c.deep[2]:  # a Gauss-Seidel round: the move at once
            for a in range(3):
                x1[a, i] += k * (amount * normal[a] + tangential[a])
            continue
        for a in range(3):
            c.push[a, i] += k * (amount * normal[a] + tangential[a])
        c.pushes[i] += 1.0


@njit(cache=True, nogil=True, error_model="numpy")
def segment_crosses_triangle(p, q, a, b, c):
    """Whether the segment p-q passes through the triangle (a, b, c): its ends strictly on
    opposite sides of the triangle's plane and its line strictly inside the triangle."""
    sp, sq = orient(a, b, c, p), orient(a, b, c, q)
    if not ((sp > 0.0 and sq < 0.0) or (sp < 0.0 and sq > 0.0)):
        return False
    u, v, w = orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)
    return (u > 0.0 and v > 0.0 and w > 0.0) or (u < 0.0 and v < 0.0 and w < 0.0)


def tangles(x: np.ndarray, c: RobustContact, out: np.ndarray) -> int:
    """The edge-triangle crossings of the cloth at x (3, N), pairs sharing no point: their
    count, the first len(out) written to out as (edge, triangle) rows."""
    kernel, arguments = tangles_call(x, c, out)
    return kernel(*arguments)


def tangles_call(x: np.ndarray, c: RobustContact, out: np.ndarray) -> tuple:
    """(kernel, arguments) of `tangles` (a first run compiles the kernel for them:
    pipeline.run.warmup)."""
    return _tangles, (x, c.triangles, c.edges, c.anchor[3], c.box, c.bucket_start,
                      c.bucket_work, c.entries, c.entry_box, out)


@njit(cache=True, nogil=True, error_model="numpy")
def _tangles(x, tris, edges, skin, box, bucket_start, bucket_work, entries, entry_box, out):
    """tangles on the contact's arrays (a kernel taking the whole contact from Python
    compiles its unboxing: seconds)."""
    cell = _boxes(x, x, tris, 0.0, skin, 0.0, box)
    cell = max(cell, 1e-12)
    while not _build(box, tris.shape[0], cell, bucket_start, bucket_work, entries, entry_box):
        cell *= 2.0
    mask = bucket_start.shape[0] - 2
    count = 0
    for e in range(edges.shape[0]):
        p, q = edges[e, 0], edges[e, 1]
        lo = (min(x[0, p], x[0, q]), min(x[1, p], x[1, q]), min(x[2, p], x[2, q]))
        hi = (max(x[0, p], x[0, q]), max(x[1, p], x[1, q]), max(x[2, p], x[2, q]))
        for ix in range(math.floor(lo[0] / cell), math.floor(hi[0] / cell) + 1):
            for iy in range(math.floor(lo[1] / cell), math.floor(hi[1] / cell) + 1):
                for iz in range(math.floor(lo[2] / cell), math.floor(hi[2] / cell) + 1):
                    b = cell_hash(ix, iy, iz, mask)
                    for k in range(bucket_start[b], bucket_start[b + 1]):
                        t = entries[k]
                        if (box[0, t] > hi[0] or box[3, t] < lo[0] or box[1, t] > hi[1]
                                or box[4, t] < lo[1] or box[2, t] > hi[2] or box[5, t] < lo[2]):
                            continue
                        if (math.floor(max(box[0, t], lo[0]) / cell) != ix
                                or math.floor(max(box[1, t], lo[1]) / cell) != iy
                                or math.floor(max(box[2, t], lo[2]) / cell) != iz):
                            continue
                        if _shares(tris[t], p) or _shares(tris[t], q):
                            continue
                        if segment_crosses_triangle(_p(x, p), _p(x, q), _p(x, tris[t, 0]),
                                                    _p(x, tris[t, 1]), _p(x, tris[t, 2])):
                            if count < out.shape[0]:
                                out[count, 0], out[count, 1] = e, t
                            count += 1
    return count


@njit(cache=True, nogil=True, error_model="numpy")
def _apply(x, c):
    for i in range(x.shape[1]):
        if c.pushes[i] > 0.0:
            for a in range(3):
                x[a, i] += c.push[a, i] / c.pushes[i]
            c.push[:, i] = 0.0
            c.pushes[i] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _cell(x0, x1, c):
    """Cells as large as the triangles' swept boxes on average (their largest sides, with
    the thickness): a typical primitive covers up to 2 x 2 x 2 cells, a fast one more."""
    return _boxes(x0, x1, c.triangles, c.thickness, c.anchor[3], 0.0, c.box)


@njit(cache=True, nogil=True, error_model="numpy", pointer=True)
def robust_contact(x, x0, c):
    """The robust self-contact of one step from x0 to x (3, N), in place (see above)."""
    c.stats[6] += 1.0
    if not c.self_on:
        return
    for a in range(3):
        for i in range(x.shape[1]):
            c.start[a, i] = x0[a, i]
    start = c.start
    # the kernels below take c without its pointer to _visit (the type _visit was compiled
    # for; one contact passed, not two, compiles quicker)
    visit, c = c.visit, RobustContact(*c[:-1], None)
    # the modes are passed as np.int64, not literals: numba compiles a kernel once per
    # literal argument (_round three times, seconds each)
    # one visit for both: CCD where a pair meets within the step, else proximity
    c.deep[:] = 0
    if _round(start, x, c, visit, np.int64(0)) == 0:
        return  # no pair met or came close: nothing moved, no crossing
    _apply(x, c)
    for _ in range(PROXIMITY_ROUNDS):
        if c.deep[0] == 0:
            break
        c.deep[:] = 0
        c.deep[2] = 1
        moved = _round(start, x, c, visit, np.int64(0))
        c.deep[2] = 0
        if moved == 0:
            break
        _apply(x, c)
    if c.deep[1] > 0:  # the rounds ran out, a pair still closer than PRESSED_GAP h
        if c.stats[PRESSED] == 0.0:
            c.stats[PRESSED_STEP] = c.stats[6]
        c.stats[PRESSED] += 1.0
    # the pushes may have made new meetings: CCD rounds until one finds none
    for _ in range(CCD_ROUNDS):
        if _round(start, x, c, visit, np.int64(1)) == 0:
            return
        _apply(x, c)
    c.frozen[:] = 0
    while True:
        before = c.frozen.sum()
        if _round(start, x, c, visit, np.int64(2)) == 0:
            break
        after = c.frozen.sum()
        for i in range(x.shape[1]):
            if c.frozen[i]:
                for a in range(3):
                    x[a, i] = start[a, i]
        c.stats[3] += after - before
        if after == before:
            break  # only pinned points left moving into each other: unresolvable
