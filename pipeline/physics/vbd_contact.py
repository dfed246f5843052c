"""Contact as energies of Vertex Block Descent's incremental potential (issue 44; Chen, Liu,
Yang and Yuksel 2024, sections 3.6-3.7, as NVIDIA Newton's SolverVBD): the colliders and
the cloth's self-contact enter each point's Newton step (pipeline.physics.integrators.vbd
adds these terms to a point's own in `_local`), instead of acting only after the descent.

Colliders. For a free point at x and an active collider, d(x) is the signed distance from
the collider's surface at its pose at the step's end, taken in its rest frame as the
position passes take it (pipeline.physics.colliders): a sphere's |x - o| - r; a plane's
distance along its normal, on the side the point was at the step's start (the course's
plane keeps that side); a box's distance to the cuboid outside, minus the depth below its
nearest face inside; a mesh's trilinear distance grid (pipeline.physics.sdf), a one-sided
mesh's on the side the point started on, its untrusted cells ignored (colliders.mesh).
The contact distance `level` is the pass's own offset (sphere 0; plane and box their
SURFACE_OFFSET; a mesh its `thickness`) plus COLLIDER_MARGIN of the cloth's thickness, and
the energy

    E = k_p / 2 max(0, level - d)^2,  gradient k_p (d - level) grad d,  block k_p g g^T

(g = grad d; the block drops the exact Hessian's curvature term -k_p (level - d) Hess d,
negative semi-definite wherever d is convex, as outside a sphere or a box and between two
points: the block is positive semi-definite, at most the exact one there). A point
at rest then sits `level` minus a small penetration from the surface: outside the passes'
reach, so they have nothing left to do. The margin is small: the cloth lies on a collider
where the other integrators put it (a full thickness showed a gap under it), and a point
that starts a step on the pass's surface (a cloth authored resting on a plane, as
selfCollision's bottom edge) is pushed out by no more than the margin in one step (a
thickness launched it at 25 m/s).

Self-contact. The point pairs within reach at the step's start (`find_pairs`, once per
step on a spatial hash of the start positions, inflated by what the step can move; its
arrays are a PairSearch, None in a scene without self-collision and wind), none closer
than the contact distance at rest (those are the cloth's own neighbours: robust contact
excludes them alike), and E = k_pq / 2 max(0, 2 t - |x_p - x_q|)^2, 2 t the course
self-collision's distance (t the cloth's thickness). A point's terms read its
partners' positions from `snapshot`, the positions at the start of the colour being
swept: a partner may share the point's colour (pairs are not in the colouring), and then
its own update may be writing x at the same moment; the snapshot is written only between
colours, so every thread count gives the same bits. Partners of the other colours are
where x has them (their colours' updates are over): Gauss-Seidel across colours, Jacobi
within one. Jacobi on a stiff pair overshoots (each point takes the whole correction, the
pair swaps sides every sweep: seen on a cloth piling up at one step per frame, layers left
at half the contact distance after 10 sweeps), so a same-colour pair's block counts twice
in each point's system: each point then takes half of it, as damped Jacobi does.

Stiffness: k_p = CONTACT_STIFFNESS (w_p + e_p), w_p = (1 + h gamma) m_p / h^2 the point's
inertia weight and e_p its elastic stiffness at rest (`rest_stiffness`: the trace / 3 of
its springs' and membrane triangles' blocks; bending is orders softer), k_pq the mean of
the pair's. Scaled to the point's own 3x3 system, a contact is that many times stiffer than
whatever presses the point in, whatever the step, mass or material: the penetration is
about 1 / CONTACT_STIFFNESS of the displacement the point's other terms ask for
(docs/integrators.md has the measured figures). A penalty is no barrier: a point's
Newton step taken without a contact it has not reached yet could carry it deep into it;
a step that would enter one (linearised) is taken again with that contact's penalty
linearised at the point (`contact_terms` with `entering`), which is exact for the
penalised quadratic model; a step shorter than the point's clearance to the contacts it
is outside of needs no second look.

Friction (IPC's, Li et al. 2020, as the VBD paper and Newton take it): with the normal
force lambda = k_p (level - d) |g| and the tangent plane of n = g / |g| lagged (taken at
the point's position before its update), the point's tangential displacement u over the
step relative to the collider's surface (for a pair, relative to its partner) meets the
potential mu lambda f0(|u|): force -mu lambda f1(|u|) u / |u|, f1 smoothed below eps =
FRICTION_SPEED h (static friction up to about that slip per second), block mu lambda
f1(|u|) / |u| (I - n n^T): IPC's and Newton's, the curvature of a quadratic that lies
above the potential, so a step never overshoots a slide's stop (the exact block has no
curvature along a slide: with it a pile of cloth at one step per frame kept jumping,
21 J of kinetic energy where this leaves 0.03 J). mu is the collider's friction, or the
cloth's (`cloth.friction`) for self-contact. Lagged, friction is not part of the
potential: the descent decreases G without it.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from clothjit import njit

from . import sdf
from .colliders import _to_rest, box, mesh, plane, sphere
from .self_collision import _EMPTY_LIMIT, cell_hash
from .vbd_energy import add_terms

COLLIDER_MARGIN = 0.01  # of the thickness: a collider's contact distance beyond its pass's
CONTACT_STIFFNESS = 100.0  # k_p over the point's inertia weight plus its elastic stiffness
FRICTION_SPEED = 1e-2  # m/s: the friction's smoothing slip, per second of the step
PAIRS_PER_POINT = 32  # room for the self-contact partners at first (grown on overflow)
QUERY_MARGIN = 0.5  # of the self-contact distance: pairs listed beyond it (find_pairs)
UNBINNED = np.iinfo(np.int64).min  # the cell of a point find_pairs leaves out
FAR = sdf.FAR


class VbdContact(NamedTuple):
    """What the contact terms read: the cloth's, the colliders' (the System's table's
    arrays, shared: its poses are updated before the descent) and the self-contact pairs."""

    thickness: float
    friction: float  # cloth on cloth
    colliders: int  # how many of the table's colliders the descent sees (0: none)
    self_on: bool  # self-contact in the descent
    elastic: np.ndarray  # (N,) e_p, see the module docstring
    start: np.ndarray  # (3, N) the positions at the step's start (the State's `last`)
    slip: np.ndarray  # (1,) the friction's eps this step: FRICTION_SPEED h
    # the colliders: the ColliderTable's kinds, params, data, key_count, pivot, pose, active
    kinds: np.ndarray
    params: np.ndarray
    data: np.ndarray
    key_count: np.ndarray
    pivot: np.ndarray
    pose: np.ndarray
    active: np.ndarray
    side: np.ndarray  # (C, N) a plane's or one-sided mesh's side of each point at the start
    # self-contact (its arrays have no points when it is off)
    colour: np.ndarray  # (N,) int64 each point's colour (vbd_energy's colouring)
    snapshot: np.ndarray  # (3, N) the positions at the start of the colour being swept
    pair_start: np.ndarray  # (N + 1,) int64: point p's partners are partners[ps[p]:ps[p + 1]]
    partners: np.ndarray  # (2 room,) int64


class PairSearch(NamedTuple):
    """find_pairs' arrays (a tuple of their own: the sweeps need none of them)."""

    rest: np.ndarray  # (3, N) rest positions: pairs closer than 2 t there are never listed
    count: np.ndarray  # (2,) int64: pairs found at the last step, and kept (room)
    # scratch: each point's reach and cell; the spatial hash's buckets (B + 1, B a power of
    # 2), their members and the members' start positions, reaches and cells in that order;
    # each pair once; each list's end while it is filled
    reach: np.ndarray  # (N,)
    cell: np.ndarray  # (3, N) int64
    bucket_start: np.ndarray  # (B + 1,) int64
    members: np.ndarray  # (N,) int64
    near: np.ndarray  # (4, N)
    near_cell: np.ndarray  # (3, N) int64
    found_pairs: np.ndarray  # (room, 2) int64
    fill: np.ndarray  # (N,) int64


def vbd_contact(system, elements, start: np.ndarray,
                on: bool = True) -> tuple[VbdContact, PairSearch | None]:
    """The System's contact for its VBD descent and its pair search (`start`: the State's
    start-of-step positions); `on` False: none (contact left to the passes after it). The
    search is None in a System without wind and self-collision (system.StepKernels' lean
    scenes): vbd._predict then has no find_pairs to compile (1.2 s of a first run); with
    either it has a search (of no points without self-contact), so that wind, self-contact
    or both share one stepping kernel, as the System's passes do."""
    n = system.x0.shape[1]
    table = system.colliders
    self_on = on and (system.self_collision
                      or (system.contact is not None and system.contact.self_on))
    m = n if self_on else 0
    count = len(table.kinds) if on else 0  # the colliders the descent sees
    room = PAIRS_PER_POINT * m // 2
    buckets = 1
    while buckets < 2 * m:
        buckets <<= 1
    contact = VbdContact(
        thickness=float(system.thickness), friction=float(system.friction),
        colliders=count, self_on=bool(self_on),
        elastic=rest_stiffness(elements, n), start=start, slip=np.zeros(1),
        kinds=table.kinds, params=table.params, data=table.data, key_count=table.key_count,
        pivot=table.pivot, pose=table.pose, active=table.active,
        side=np.ones((len(table.kinds), n)), colour=colours(elements, n),
        snapshot=np.zeros((3, m)), pair_start=np.zeros(m + 1, np.int64),
        partners=np.zeros(2 * room, np.int64))
    search = None if system.scratch is None else PairSearch(
        rest=np.ascontiguousarray(system.x0, dtype=np.float64), count=np.zeros(2, np.int64),
        reach=np.zeros(m), cell=np.zeros((3, m), np.int64),
        bucket_start=np.zeros(buckets + 1, np.int64), members=np.zeros(m, np.int64),
        near=np.zeros((4, m)), near_cell=np.zeros((3, m), np.int64),
        found_pairs=np.zeros((room, 2), np.int64), fill=np.zeros(m, np.int64))
    return contact, search


def with_room(contact: VbdContact,
              search: PairSearch | None) -> tuple[VbdContact, PairSearch | None]:
    """(contact, search) with room for 1.25 times the pairs the last step found, if they
    did not fit."""
    if search is None or search.count[0] <= search.count[1]:
        return contact, search
    found = search.count[0]
    room = int(1.25 * found) + 1
    return (contact._replace(partners=np.zeros(2 * room, np.int64)),
            search._replace(found_pairs=np.zeros((room, 2), np.int64)))


def colours(el, n: int) -> np.ndarray:
    """Each point's colour in the elements' colouring."""
    colour = np.zeros(n, np.int64)
    for c in range(len(el.colour_start) - 1):
        colour[el.order[el.colour_start[c]:el.colour_start[c + 1]]] = c
    return colour


def rest_stiffness(el, n: int) -> np.ndarray:
    """e_p: the trace / 3 of the Hessian blocks of point p's springs (k) and membrane
    triangles (area (k_stretch + k_shear) (c_u^2 + c_v^2), c its row of the FEM's
    gradient operator) at rest."""
    trace = np.zeros(n)
    if len(el.springs):
        np.add.at(trace, el.springs.ravel(), np.repeat(el.spring_k, 2))
    if len(el.triangles):
        inv = el.tri_inv
        cu = np.stack([-(inv[:, 0] + inv[:, 2]), inv[:, 0], inv[:, 2]], axis=1)
        cv = np.stack([-(inv[:, 1] + inv[:, 3]), inv[:, 1], inv[:, 3]], axis=1)
        scale = el.tri_area * (el.k_stretch + el.k_shear)
        np.add.at(trace, el.triangles.ravel(), (scale[:, None] * (cu * cu + cv * cv)).ravel())
    return trace / 3.0


# --- the colliders ---------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _box_distance(params, c, x, y, z):
    """(d, gradient) of box c at a rest-frame point: outside, the distance to the cuboid;
    inside, minus the depth below the nearest face (colliders.box's choice of face)."""
    dx, dy, dz = x - params[c, 0], y - params[c, 1], z - params[c, 2]
    q0 = params[c, 3] * dx + params[c, 6] * dy + params[c, 9] * dz  # R^T (p - center)
    q1 = params[c, 4] * dx + params[c, 7] * dy + params[c, 10] * dz
    q2 = params[c, 5] * dx + params[c, 8] * dy + params[c, 11] * dz
    e0, e1, e2 = abs(q0) - params[c, 12], abs(q1) - params[c, 13], abs(q2) - params[c, 14]
    s0 = 1.0 if q0 >= 0.0 else -1.0  # colliders.box's face on a tie
    s1 = 1.0 if q1 >= 0.0 else -1.0
    s2 = 1.0 if q2 >= 0.0 else -1.0
    if e0 > 0.0 or e1 > 0.0 or e2 > 0.0:
        o0, o1, o2 = max(e0, 0.0), max(e1, 0.0), max(e2, 0.0)
        d = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
        l0, l1, l2 = s0 * o0 / d, s1 * o1 / d, s2 * o2 / d
    elif e0 >= e1 and e0 >= e2:
        d, l0, l1, l2 = e0, s0, 0.0, 0.0
    elif e1 >= e2:
        d, l0, l1, l2 = e1, 0.0, s1, 0.0
    else:
        d, l0, l1, l2 = e2, 0.0, 0.0, s2
    return d, (params[c, 3] * l0 + params[c, 4] * l1 + params[c, 5] * l2,
               params[c, 6] * l0 + params[c, 7] * l1 + params[c, 8] * l2,
               params[c, 9] * l0 + params[c, 10] * l1 + params[c, 11] * l2)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _surface(cn, c, x, y, z, side, reach):
    """(d, level, grad d, friction) of collider c at the rest-frame point (x, y, z), a
    plane's and a one-sided mesh's d on `side` (+1 the normal's, -1 the other; 0: a plane
    gives no contact, a mesh the side the point is on). A mesh's cell farther than `reach`
    beyond the level gives a lower bound of d and no gradient; d = FAR where the point
    cannot be told (outside the grid, a one-sided mesh's untrusted cell)."""
    params, kind, level = cn.params, cn.kinds[c], COLLIDER_MARGIN * cn.thickness
    if kind == sphere.KIND:
        dx, dy, dz = x - params[c, 0], y - params[c, 1], z - params[c, 2]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        if r == 0.0:
            return -params[c, 3], level, (0.0, 1.0, 0.0), params[c, 4]
        return r - params[c, 3], level, (dx / r, dy / r, dz / r), params[c, 4]
    if kind == plane.KIND:
        level += plane.SURFACE_OFFSET
        if side == 0.0:  # started on the plane: no side yet (the course's pass gives one)
            return FAR, level, (0.0, 0.0, 0.0), params[c, 6]
        nx, ny, nz = side * params[c, 3], side * params[c, 4], side * params[c, 5]
        d = (x - params[c, 0]) * nx + (y - params[c, 1]) * ny + (z - params[c, 2]) * nz
        return d, level, (nx, ny, nz), params[c, 6]
    if kind == box.KIND:
        d, g = _box_distance(params, c, x, y, z)
        return d, level + box.SURFACE_OFFSET, g, params[c, 15]
    data, grid = cn.data, sdf.grid_of(params, c)
    level += params[c, mesh._THICKNESS]
    friction = params[c, mesh._FRICTION]
    base, tx, ty, tz, inside = sdf.locate(grid, x, y, z)
    if not inside:
        return FAR, level, (0.0, 0.0, 0.0), friction
    corner, diagonal = data[base], grid[9]  # d in the cell is within `diagonal` of it
    solid = params[c, mesh._SOLID] != 0.0
    if not (solid or sdf.trusted(grid, data, base)):
        return FAR, level, (0.0, 0.0, 0.0), friction
    near = (corner if solid else abs(corner)) - diagonal  # at most d (on the point's side)
    if near >= level + reach:  # no need for d: its lower bound, no gradient
        return near, level, (0.0, 0.0, 0.0), friction
    d, gx, gy, gz = sdf.trilinear(grid, data, base, tx, ty, tz)
    if not solid:  # on the side the point started on (or, unknown there, is on now)
        side = side if side != 0.0 else math.copysign(1.0, d)
        d, gx, gy, gz = side * d, side * gx, side * gy, side * gz
    return d, level, (gx, gy, gz), friction


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _rotated(pose, c, v):
    """A rest-frame direction of collider c in the world under its end pose."""
    return (pose[c, 1, 0] * v[0] + pose[c, 1, 1] * v[1] + pose[c, 1, 2] * v[2],
            pose[c, 1, 3] * v[0] + pose[c, 1, 4] * v[1] + pose[c, 1, 5] * v[2],
            pose[c, 1, 6] * v[0] + pose[c, 1, 7] * v[1] + pose[c, 1, 8] * v[2])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def collider_gap(cn, c, x, p, reach):
    """(d - level, grad d, the point's motion over the step relative to the collider,
    friction) of collider c at point p, in the world: the point where x has it under the
    collider's end pose, where it started under its start pose (colliders._sweep's frames)."""
    qx, qy, qz = x[0, p], x[1, p], x[2, p]
    lx, ly, lz = cn.start[0, p], cn.start[1, p], cn.start[2, p]
    moving = cn.key_count[c] != 0
    if moving:
        ox, oy, oz = cn.pivot[c, 0], cn.pivot[c, 1], cn.pivot[c, 2]
        qx, qy, qz = _to_rest(cn.pose, c, 1, ox, oy, oz, qx, qy, qz)
        lx, ly, lz = _to_rest(cn.pose, c, 0, ox, oy, oz, lx, ly, lz)
    d, level, g, friction = _surface(cn, c, qx, qy, qz, cn.side[c, p], reach)
    u = (qx - lx, qy - ly, qz - lz)
    if moving:  # back to the world (the motion: relative to the surface's)
        g, u = _rotated(cn.pose, c, g), _rotated(cn.pose, c, u)
    return d - level, g, u, friction


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True)
def start_sides(cn, pinned):
    """Each free point's side of every plane and one-sided mesh at the step's start, under
    the collider's start pose. 0 on a plane: no contact with it this step (the course's
    pass sends such a point to the side opposite to where it goes); 0 for a mesh that
    cannot tell there: the side the point is on (colliders.mesh's rule)."""
    params = cn.params
    for c in range(cn.colliders):
        kind = cn.kinds[c]
        if not (kind == plane.KIND or (kind == mesh.KIND and params[c, mesh._SOLID] == 0.0)):
            continue
        ox, oy, oz = cn.pivot[c, 0], cn.pivot[c, 1], cn.pivot[c, 2]
        for p in range(pinned.shape[0]):
            if pinned[p]:
                continue
            x, y, z = cn.start[0, p], cn.start[1, p], cn.start[2, p]
            if cn.key_count[c] != 0:
                x, y, z = _to_rest(cn.pose, c, 0, ox, oy, oz, x, y, z)
            if kind == plane.KIND:
                d = ((x - params[c, 0]) * params[c, 3] + (y - params[c, 1]) * params[c, 4]
                     + (z - params[c, 2]) * params[c, 5])
            else:
                d = _mesh_distance(params, cn.data, c, x, y, z)
            cn.side[c, p] = 0.0 if d == 0.0 or d == FAR else math.copysign(1.0, d)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _mesh_distance(params, data, c, x, y, z):
    """Mesh c's distance at a rest-frame point where its grid can tell (inside the grid,
    a trusted cell), else FAR (start_sides' own: `_surface` carries every kind, and
    compiling it again here cost half a second of a first run)."""
    grid = sdf.grid_of(params, c)
    base, tx, ty, tz, inside = sdf.locate(grid, x, y, z)
    if not (inside and sdf.trusted(grid, data, base)):
        return FAR
    return sdf.trilinear(grid, data, base, tx, ty, tz)[0]


# --- the terms of one contact: (energy, gradient, Hessian block (xx, yy, zz, xy, xz, yz)) --


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def penalty_terms(gap, g, u, k, mu, eps, share):
    """k / 2 gap^2 (gap = d - level < 0, g = grad d) and the lagged friction mu lambda
    f0(|u_t|) of the tangential part u_t of the motion u: their energy, gradient and block,
    the block `share` times over (2 for a pair whose points are updated at once)."""
    gx, gy, gz = g
    g2 = gx * gx + gy * gy + gz * gz
    s = k * gap
    energy = 0.5 * s * gap
    grad = (s * gx, s * gy, s * gz)
    b = share * k
    block = (b * gx * gx, b * gy * gy, b * gz * gz, b * gx * gy, b * gx * gz, b * gy * gz)
    if not (mu > 0.0 and g2 > 0.0):
        return energy, grad, block
    norm = math.sqrt(g2)
    nx, ny, nz = gx / norm, gy / norm, gz / norm
    along = u[0] * nx + u[1] * ny + u[2] * nz
    tx, ty, tz = u[0] - along * nx, u[1] - along * ny, u[2] - along * nz
    slip = math.sqrt(tx * tx + ty * ty + tz * tz)
    force = -mu * s * norm  # mu lambda
    if slip >= eps:  # sliding: f0 = slip, f1 / slip = 1 / slip
        f0, f1 = slip, 1.0 / slip
    else:  # IPC's smoothed static friction
        f0 = slip * slip * (1.0 / eps - slip / (3.0 * eps * eps)) + eps / 3.0
        f1 = (2.0 - slip / eps) / eps
    w = force * f1
    b = share * w
    return energy + force * f0, (grad[0] + w * tx, grad[1] + w * ty, grad[2] + w * tz), (
        block[0] + b * (1.0 - nx * nx), block[1] + b * (1.0 - ny * ny),
        block[2] + b * (1.0 - nz * nz), block[3] - b * nx * ny, block[4] - b * nx * nz,
        block[5] - b * ny * nz)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _squared_distance(cn, x, p, q):
    """|x_p - x_q|^2, the partner q at its snapshot."""
    dx, dy = x[0, p] - cn.snapshot[0, q], x[1, p] - cn.snapshot[1, q]
    dz = x[2, p] - cn.snapshot[2, q]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def pair_gap(cn, x, p, q):
    """(|x_p - x_q| - 2 t, its gradient in x_p, the pair's relative motion over the step)
    with the partner q at its snapshot; FAR where the points coincide."""
    qx, qy, qz = cn.snapshot[0, q], cn.snapshot[1, q], cn.snapshot[2, q]
    dx, dy, dz = x[0, p] - qx, x[1, p] - qy, x[2, p] - qz
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if d == 0.0:
        return FAR, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    s, r = cn.start, 2.0 * cn.thickness
    return d - r, (dx / d, dy / d, dz / d), (
        dx - (s[0, p] - s[0, q]), dy - (s[1, p] - s[1, q]), dz - (s[2, p] - s[2, q]))


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def stiffness(cn, inertia, p):
    """k_p = CONTACT_STIFFNESS (w_p + e_p)."""
    return CONTACT_STIFFNESS * (inertia[p] + cn.elastic[p])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _joins(gap, g, sx, sy, sz, entering):
    """Whether a contact's penalty joins point p's terms: where the point is inside it; with
    `entering`, where it is outside and its step (sx, sy, sz) enters it (linearised)."""
    if entering:
        return gap >= 0.0 and gap + g[0] * sx + g[1] * sy + g[2] * sz < 0.0
    return gap < 0.0


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True)
def contact_terms(x, inertia, cn, p, terms, entering, sx, sy, sz):
    """(how many contacts joined, the clearance, `terms` (energy, gradient, block) of point
    p plus their penalties): those it is inside of, with their friction (vbd's `_local`);
    or, with `entering`, those its Newton step (sx, sy, sz) would enter from outside,
    linearised at x: k / 2 (gap + g . s)^2, whose Newton step from x is the penalised
    step's wherever it ends inside them (vbd's `_update_point` takes it instead: without
    them a step can carry a point deep into a contact it has not reached yet, a penalty
    being no barrier). The clearance: how far the point can move before it can enter a
    contact (min gap / max(|g|, 1) over those outside); no step shorter needs the second
    call. A call of its own, so that the descent without contact stays as lean as before."""
    k, eps, count, clear = stiffness(cn, inertia, p), cn.slip[0], 0, np.inf
    reach = math.sqrt(sx * sx + sy * sy + sz * sz)  # for a mesh's test of far cells
    for c in range(cn.colliders):
        if cn.active[c]:
            gap, g, u, mu = collider_gap(cn, c, x, p, reach)
            if _joins(gap, g, sx, sy, sz, entering):
                terms = add_terms(terms, penalty_terms(gap, g, u, k, 0.0 if entering else mu,
                                                       eps, 1.0))
                count += 1
            else:
                clear = min(clear, _clearance(gap, g))
    if cn.self_on:
        r = 2.0 * cn.thickness
        within = (r + reach) * (r + reach)  # no pair farther is inside, nor entered
        nearest = np.inf  # the smallest squared distance of those
        for j in range(cn.pair_start[p], cn.pair_start[p + 1]):
            q = cn.partners[j]
            d2 = _squared_distance(cn, x, p, q)
            if not d2 < within:
                nearest = min(nearest, d2)
                continue
            gap, g, u = pair_gap(cn, x, p, q)
            if _joins(gap, g, sx, sy, sz, entering):
                k_pair = 0.5 * (k + stiffness(cn, inertia, q))
                share = 2.0 if cn.colour[q] == cn.colour[p] else 1.0  # Jacobi: see above
                terms = add_terms(terms, penalty_terms(
                    gap, g, u, k_pair, 0.0 if entering else cn.friction, eps, share))
                count += 1
            else:
                clear = min(clear, _clearance(gap, g))
        clear = min(clear, math.sqrt(nearest) - r)
    return count, clear, terms


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _clearance(gap, g):
    """How far a point gap outside a contact (grad d = g) moves before it can enter it."""
    return gap / max(math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]), 1.0)


# --- the self-contact pairs of a step ------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True)
def find_pairs(cn, search, y, pinned):
    """Every free point's partners (pair_start, partners) for this step: the points q whose
    start positions are within 2 t + QUERY_MARGIN 2 t + reach_p + reach_q of its own
    (reach: how far the inertial prediction y moves a point relative to the cloth's mean
    motion, at most QUERY_MARGIN 2 t; the margin for what the prediction misses, as
    Newton's query margin), found on a hash of cells that wide, and that lie farther than
    2 t from it at rest (nearer ones are the cloth's own neighbours; robust contact leaves
    them out alike; sharing an element is no reason: a pile's sharp folds bring points two
    apart closer than 2 t, and the course's pass pushes those, so must the descent). Each pair
    is met once, in a fixed order (points, cells, members): the same lists on every run.
    Pairs beyond the room are counted (count) and left to the position passes."""
    x, r, n = cn.start, 2.0 * cn.thickness, cn.start.shape[1]
    mx = my = mz = 0.0
    free = 0
    for p in range(n):
        if pinned[p] == 0:
            free += 1
            mx += y[0, p] - x[0, p]
            my += y[1, p] - x[1, p]
            mz += y[2, p] - x[2, p]
    scale = 1.0 / max(free, 1)
    mx, my, mz = mx * scale, my * scale, mz * scale
    margin = QUERY_MARGIN * r
    widest = 0.0
    for p in range(n):
        ax, ay, az = y[0, p] - x[0, p] - mx, y[1, p] - x[1, p] - my, y[2, p] - x[2, p] - mz
        search.reach[p] = min(math.sqrt(ax * ax + ay * ay + az * az), margin)
        widest = max(widest, search.reach[p])
    size = r + margin + 2.0 * widest  # the farthest a listed pair can be: the cells' side
    starts, members, cell = search.bucket_start, search.members, search.cell
    mask = starts.shape[0] - 2
    starts[:] = 0
    for p in range(n):
        _bin(x, p, size, cell)
        if cell[0, p] != UNBINNED:
            starts[cell_hash(cell[0, p], cell[1, p], cell[2, p], mask) + 1] += 1
    for b in range(mask + 1):
        starts[b + 1] += starts[b]
    near, near_cell = search.near, search.near_cell  # the members', in member order
    for p in range(n):  # a counting sort: each bucket's points ascending
        if cell[0, p] != UNBINNED:
            b = cell_hash(cell[0, p], cell[1, p], cell[2, p], mask)
            m = starts[b]
            members[m] = p
            for a in range(3):
                near[a, m], near_cell[a, m] = x[a, p], cell[a, p]
            near[3, m] = search.reach[p]
            starts[b] += 1
    for b in range(mask, 0, -1):  # back to each bucket's start
        starts[b] = starts[b - 1]
    starts[0] = 0
    # each pair once, from the point of the lower cell (or the lower index in one cell),
    # kept in `found_pairs`; then every free point's list, in the order they were found
    found = kept = 0
    rest, pairs, counts = search.rest, search.found_pairs, cn.pair_start
    counts[:] = 0
    for p in range(n):
        if cell[0, p] == UNBINNED:
            continue
        for k in range(13, 27):  # its own cell and the 13 after it
            di, dj, dk = k // 9 - 1, (k // 3) % 3 - 1, k % 3 - 1
            ix, iy, iz = cell[0, p] + di, cell[1, p] + dj, cell[2, p] + dk
            b = cell_hash(ix, iy, iz, mask)
            for m in range(starts[b], starts[b + 1]):
                # that cell's own members only (each q met once), after p in its own cell
                if near_cell[0, m] != ix or near_cell[1, m] != iy or near_cell[2, m] != iz or (
                        k == 13 and members[m] <= p):
                    continue
                reach = r + margin + search.reach[p] + near[3, m]
                d2 = ((x[0, p] - near[0, m]) ** 2 + (x[1, p] - near[1, m]) ** 2
                      + (x[2, p] - near[2, m]) ** 2)
                q = members[m]
                if not d2 < reach * reach or (pinned[p] and pinned[q]) or (
                        (rest[0, p] - rest[0, q]) ** 2 + (rest[1, p] - rest[1, q]) ** 2
                        + (rest[2, p] - rest[2, q]) ** 2 < r * r):
                    continue
                found += 1
                if kept < pairs.shape[0]:
                    pairs[kept, 0], pairs[kept, 1] = p, q
                    kept += 1
                    counts[p + 1] += pinned[p] == 0
                    counts[q + 1] += pinned[q] == 0
    for p in range(n):
        counts[p + 1] += counts[p]
    fill = search.fill  # each list's end while filling them
    for p in range(n):
        fill[p] = counts[p]
    for i in range(kept):
        p, q = pairs[i, 0], pairs[i, 1]
        if pinned[p] == 0:
            cn.partners[fill[p]] = q
            fill[p] += 1
        if pinned[q] == 0:
            cn.partners[fill[q]] = p
            fill[q] += 1
    search.count[0], search.count[1] = found, kept


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True)
def _bin(x, p, size, cell):
    """cell[:, p] = point p's cell on cells of `size`, or UNBINNED (not finite, or absurdly
    far)."""
    fx, fy, fz = (math.floor(x[0, p] / size), math.floor(x[1, p] / size),
                  math.floor(x[2, p] / size))
    if not (abs(fx) < _EMPTY_LIMIT and abs(fy) < _EMPTY_LIMIT and abs(fz) < _EMPTY_LIMIT):
        cell[0, p] = UNBINNED
        return
    cell[0, p], cell[1, p], cell[2, p] = np.int64(fx), np.int64(fy), np.int64(fz)
