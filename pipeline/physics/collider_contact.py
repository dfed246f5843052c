"""Robust colliders (`simulation.contact` "robust"): at the end of every step no free cloth
point is inside a sphere or box collider, none has passed through one during the step, and
no cloth edge passes through one, whatever the collider's speed.

It runs after the course's collider pass (pipeline.physics.colliders), which moves the points
that end a step inside, and after the robust self-contact. Each collider is worked in its
rest frame: the point's path is the straight line from its start-of-step position under the
collider's start pose to its position under the end pose (a keyframed collider's motion
taken as the cloth's relative motion, as the course pass takes it).
1. Paths: a free point whose path enters the solid from outside stops where it enters, keeps
   the part of its remaining motion along the surface, takes the collider's friction rule
   (last + (1 - friction) (target - last), as the course pass) and ends SURFACE_GAP outside.
   A point still inside (it started inside, or another pass moved it in) goes out to the
   nearest surface point, SURFACE_GAP outside.
2. Edges: a cloth edge whose segment passes through the solid is moved out along the
   direction of least overlap (a sphere: from its centre through the segment's closest point;
   a box: the separating axis of least overlap), its free ends weighted by inverse mass so the
   segment's deepest point moves the overlap plus SURFACE_GAP; rounds until none passes
   through (FACE_ROUNDS at most, else counted as not kept).
A plane needs only the first, paths (the course's plane pass keeps a point on its side,
but the self-contact after it can push it through): a segment between two points on one
side stays there.
Mesh colliders (the course's level set of their distance grid, not exact) get the same two
stages on their triangles: pipeline.physics.mesh_contact.
A pinned point inside a solid, or an edge of two pinned points through one, cannot be moved:
it is counted (stats), with the first step it happened at and one such point.
"""
from __future__ import annotations

import numpy as np

from clothjit import njit

from .ccd import point_triangle_distance
from .colliders import _to_rest, _to_world, box, mesh, plane, sphere

SURFACE_GAP = 1e-4  # metres kept outside a surface (the course's box and plane keep the same)
FACE_ROUNDS = 16
MIN_FREE_WEIGHT = 0.25  # of a triangle's deepest point on free corners, to move it
# stats (RobustContact.stats): path stops, points moved out, triangle pushes, not kept
# (pins or rounds exhausted), first step of a pinned violation, one pinned point there
PATH_STOPS, MOVED_OUT, FACE_PUSHES, NOT_KEPT, PIN_STEP, PIN_POINT = range(8, 14)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rest(frame, c, s, x, p):
    """Point p of x (3, N) in collider c's rest frame under its start (s 0) or end (1) pose."""
    key_count, pivot, pose = frame
    if key_count[c] == 0:
        return x[0, p], x[1, p], x[2, p]
    return _to_rest(pose, c, s, pivot[c, 0], pivot[c, 1], pivot[c, 2], x[0, p], x[1, p], x[2, p])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _world(frame, c, qx, qy, qz):
    """A rest-frame point of collider c in the world under its end pose."""
    key_count, pivot, pose = frame
    if key_count[c] == 0:
        return qx, qy, qz
    return _to_world(pose, c, 1, pivot[c, 0], pivot[c, 1], pivot[c, 2], qx, qy, qz)


# --- a sphere: params origin (3), radius, friction ----------------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def _sphere_entry(prm, s, e):
    """Parameter u in [0, 1] where the path s -> e first enters the sphere from outside, with
    the outward normal there; u = -1 when it does not."""
    ox, oy, oz, r = prm[0], prm[1], prm[2], prm[3]
    fx, fy, fz = s[0] - ox, s[1] - oy, s[2] - oz
    dx, dy, dz = e[0] - s[0], e[1] - s[1], e[2] - s[2]
    a = dx * dx + dy * dy + dz * dz
    b = fx * dx + fy * dy + fz * dz
    c = fx * fx + fy * fy + fz * fz - r * r
    if c < 0.0 or a == 0.0 or b >= 0.0:  # starts inside, does not move, or moves away
        return -1.0, 0.0, 0.0, 0.0
    disc = b * b - a * c
    if disc < 0.0:
        return -1.0, 0.0, 0.0, 0.0
    u = c / (-b + np.sqrt(disc))  # the smaller root, without cancellation
    if u > 1.0:
        return -1.0, 0.0, 0.0, 0.0
    px, py, pz = fx + u * dx, fy + u * dy, fz + u * dz
    n = np.sqrt(px * px + py * py + pz * pz)
    return u, px / n, py / n, pz / n


@njit(cache=True, nogil=True, error_model="numpy")
def _sphere_out(prm, q):
    """q moved out to SURFACE_GAP outside the sphere along the radius; None-like (False) when
    it is not inside."""
    ox, oy, oz, r = prm[0], prm[1], prm[2], prm[3]
    dx, dy, dz = q[0] - ox, q[1] - oy, q[2] - oz
    d = np.sqrt(dx * dx + dy * dy + dz * dz)
    if not d < r:
        return False, q[0], q[1], q[2]
    if d == 0.0:
        dx, dy, dz, d = 0.0, 1.0, 0.0, 1.0
    k = (r + SURFACE_GAP) / d
    return True, ox + k * dx, oy + k * dy, oz + k * dz


@njit(cache=True, nogil=True, error_model="numpy")
def _sphere_face(prm, a, b, c):
    """(overlap, direction, weights) of the triangle (a, b, c) through the sphere: its
    closest point to the centre (barycentric weights u, v, w), the overlap r - distance
    (<= 0: clear) and the direction from the centre to that point."""
    ox, oy, oz, r = prm[0], prm[1], prm[2], prm[3]
    d, u, v, w = point_triangle_distance((ox, oy, oz), a, b, c)
    if not d < r:
        return 0.0, 0.0, 0.0, 0.0, u, v, w
    qx = u * a[0] + v * b[0] + w * c[0] - ox
    qy = u * a[1] + v * b[1] + w * c[1] - oy
    qz = u * a[2] + v * b[2] + w * c[2] - oz
    if d == 0.0:  # through the centre: out along the triangle's normal
        nx, ny, nz = _normal(a, b, c)
        return r, nx, ny, nz, u, v, w
    return r - d, qx / d, qy / d, qz / d, u, v, w


# --- a plane: params point (3), unit normal (3), friction ----------------------------------


@njit(cache=True, nogil=True, error_model="numpy")
def _plane_entry(prm, s, e):
    """Parameter u in [0, 1] where the path s -> e crosses the plane from the side it
    starts on, with the normal towards that side; u = -1 when it stays on its side (or
    starts on the plane: its side is the one the course's pass gave it)."""
    d0 = (s[0] - prm[0]) * prm[3] + (s[1] - prm[1]) * prm[4] + (s[2] - prm[2]) * prm[5]
    d1 = (e[0] - prm[0]) * prm[3] + (e[1] - prm[1]) * prm[4] + (e[2] - prm[2]) * prm[5]
    if not ((d0 > 0.0 and d1 < 0.0) or (d0 < 0.0 and d1 > 0.0)):
        return -1.0, 0.0, 0.0, 0.0
    side = 1.0 if d0 > 0.0 else -1.0
    return d0 / (d0 - d1), side * prm[3], side * prm[4], side * prm[5]


@njit(cache=True, nogil=True, error_model="numpy")
def _normal(a, b, c):
    """The unit normal of the triangle (a, b, c) ((0, 1, 0) if degenerate)."""
    ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    vx, vy, vz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    n = np.sqrt(nx * nx + ny * ny + nz * nz)
    if n == 0.0:
        return 0.0, 1.0, 0.0
    return nx / n, ny / n, nz / n


# --- a box: params center (3), R row-major (9), half extents (3), friction -----------------


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _box_local(prm, q):
    dx, dy, dz = q[0] - prm[0], q[1] - prm[1], q[2] - prm[2]
    return (prm[3] * dx + prm[6] * dy + prm[9] * dz, prm[4] * dx + prm[7] * dy + prm[10] * dz,
            prm[5] * dx + prm[8] * dy + prm[11] * dz)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _box_axis(prm, k, sign):
    """The world direction of the box's local axis k, times sign."""
    return sign * prm[3 + k], sign * prm[6 + k], sign * prm[9 + k]


@njit(cache=True, nogil=True, error_model="numpy")
def _box_entry(prm, s, e):
    """Parameter u in [0, 1] where the path s -> e first enters the box from outside (slab
    clipping), with the outward normal of the face it enters by; u = -1 when it does not."""
    ls, le = _box_local(prm, s), _box_local(prm, e)
    enter, leave, face, sign = -np.inf, np.inf, -1, 0.0
    outside = False
    for k in range(3):
        h = prm[12 + k]
        a, d = ls[k], le[k] - ls[k]
        if abs(a) >= h:
            outside = True
        if d == 0.0:
            if abs(a) >= h:
                return -1.0, 0.0, 0.0, 0.0
            continue
        t1, t2 = (-h - a) / d, (h - a) / d
        lo, hi = min(t1, t2), max(t1, t2)
        if lo > enter:
            enter, face, sign = lo, k, (-1.0 if d > 0.0 else 1.0)
        leave = min(leave, hi)
    if not outside or face < 0 or enter > leave or enter < 0.0 or enter > 1.0 or enter >= leave:
        return -1.0, 0.0, 0.0, 0.0
    nx, ny, nz = _box_axis(prm, face, sign)
    return enter, nx, ny, nz


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _unit(k):
    """The unit vector of axis k (0, 1, 2)."""
    return (1.0 if k == 0 else 0.0), (1.0 if k == 1 else 0.0), (1.0 if k == 2 else 0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def _box_face(prm, a, b, c):
    """(overlap, direction, weights) of the triangle (a, b, c) through the box by the
    separating axis test (Akenine-Moller's 13 axes: the box's face normals, the triangle's
    normal, each triangle edge crossed with each box axis): the axis of least overlap, as a
    world direction (overlap <= 0: clear), and the weights of the triangle's corners that
    lie deepest along it (equal among ties)."""
    pa, pb, pc = _box_local(prm, a), _box_local(prm, b), _box_local(prm, c)
    h0, h1, h2 = prm[12], prm[13], prm[14]
    e = ((pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]), (pc[0] - pb[0], pc[1] - pb[1], pc[2] - pb[2]),
         (pa[0] - pc[0], pa[1] - pc[1], pa[2] - pc[2]))
    best = np.inf
    bx = by = bz = 0.0
    wa = wb = wc = 1.0
    for k in range(13):
        if k < 3:
            ax, ay, az = _unit(k)
        elif k == 3:
            ax = e[0][1] * e[1][2] - e[0][2] * e[1][1]
            ay = e[0][2] * e[1][0] - e[0][0] * e[1][2]
            az = e[0][0] * e[1][1] - e[0][1] * e[1][0]
        else:  # edge i of the triangle crossed with box axis j
            ex, ey, ez = e[(k - 4) // 3]
            j = (k - 4) % 3
            ux, uy, uz = _unit(j)
            ax, ay, az = ey * uz - ez * uy, ez * ux - ex * uz, ex * uy - ey * ux
        n = np.sqrt(ax * ax + ay * ay + az * az)
        if n < 1e-12:
            continue
        ax, ay, az = ax / n, ay / n, az / n
        radius = h0 * abs(ax) + h1 * abs(ay) + h2 * abs(az)
        da = pa[0] * ax + pa[1] * ay + pa[2] * az
        db = pb[0] * ax + pb[1] * ay + pb[2] * az
        dc = pc[0] * ax + pc[1] * ay + pc[2] * az
        up = radius - min(da, db, dc)  # the move along +axis that separates, and along -axis
        down = max(da, db, dc) + radius
        if not (up > 0.0 and down > 0.0):
            return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if up <= down:
            overlap, sign, deepest = up, 1.0, min(da, db, dc)
        else:
            overlap, sign, deepest = down, -1.0, max(da, db, dc)
        if overlap < best:
            best, bx, by, bz = overlap, sign * ax, sign * ay, sign * az
            wa = 1.0 if da == deepest else 0.0
            wb = 1.0 if db == deepest else 0.0
            wc = 1.0 if dc == deepest else 0.0
    total = wa + wb + wc
    wx = prm[3] * bx + prm[4] * by + prm[5] * bz  # the axis back to the world: R local
    wy = prm[6] * bx + prm[7] * by + prm[8] * bz
    wz = prm[9] * bx + prm[10] * by + prm[11] * bz
    return best, wx, wy, wz, wa / total, wb / total, wc / total


# --- the passes ----------------------------------------------------------------------------


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _paths(x, x0, inv_mass, stats, kind, params, frame, k):
    """Stage 1 for collider k (a sphere, a box or a plane: kind, parameter rows params) on
    every free point; returns points moved. Without numba's reference counts, as _faces
    and _pinned_inside (`_nrt=False`: nothing allocates): numba counted the references to
    the pose arrays of the inlined _rest at every point (a third of the pass's time)."""
    prm = params[k]
    friction = prm[4] if kind == sphere.KIND else prm[15] if kind == box.KIND else prm[6]
    keep = 1.0 - friction
    moved = 0
    for p in range(x.shape[1]):
        if inv_mass[p] == 0.0:
            continue
        s = _rest(frame, k, 0, x0, p)
        e = _rest(frame, k, 1, x, p)
        if kind == sphere.KIND:
            u, nx, ny, nz = _sphere_entry(prm, s, e)
        elif kind == box.KIND:
            u, nx, ny, nz = _box_entry(prm, s, e)
        else:
            u, nx, ny, nz = _plane_entry(prm, s, e)
        q = e
        if u >= 0.0:  # stop at the entry, keep the motion along the surface after it
            ex, ey, ez = s[0] + u * (e[0] - s[0]), s[1] + u * (e[1] - s[1]), s[2] + u * (e[2] - s[2])
            rx, ry, rz = e[0] - ex, e[1] - ey, e[2] - ez
            along = rx * nx + ry * ny + rz * nz
            tx = ex + rx - along * nx + SURFACE_GAP * nx
            ty = ey + ry - along * ny + SURFACE_GAP * ny
            tz = ez + rz - along * nz + SURFACE_GAP * nz
            q = (s[0] + keep * (tx - s[0]), s[1] + keep * (ty - s[1]), s[2] + keep * (tz - s[2]))
            stats[PATH_STOPS] += 1.0
        if kind == sphere.KIND:
            inside, qx, qy, qz = _sphere_out(prm, q)
        elif kind == box.KIND:
            inside, qx, qy, qz = box.outside(params, k, q[0], q[1], q[2])
        else:  # a plane has no inside: a point on either side stays there
            inside, qx, qy, qz = False, q[0], q[1], q[2]
        if inside:
            stats[MOVED_OUT] += 1.0
        if u >= 0.0 or inside:
            x[0, p], x[1, p], x[2, p] = _world(frame, k, qx, qy, qz)
            moved += 1
    return moved


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _faces(x, triangles, inv_mass, push, pushes, stats, kind, prm, frame, k, apply):
    """One round of stage 2 for collider k: (triangles in it that can move, triangles in it
    that pinned corners hold there), moving the first out when `apply`; (0, 0): every
    triangle, so every edge, is clear."""
    through = stuck = 0
    for t in range(triangles.shape[0]):
        i, j, l = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        a = _rest(frame, k, 1, x, i)
        b = _rest(frame, k, 1, x, j)
        d = _rest(frame, k, 1, x, l)
        if kind == sphere.KIND:
            overlap, nx, ny, nz, u, v, w = _sphere_face(prm, a, b, d)
        else:
            overlap, nx, ny, nz, u, v, w = _box_face(prm, a, b, d)
        if not overlap > 0.0:
            continue
        # the smallest mass-weighted move of the corners that moves the point of weights
        # (u, v, w) by the overlap; none where that point is mostly held by pinned corners
        # (a free corner would have to move many times the overlap)
        wi, wj, wl = u * inv_mass[i], v * inv_mass[j], w * inv_mass[l]
        free = ((u if inv_mass[i] > 0.0 else 0.0) + (v if inv_mass[j] > 0.0 else 0.0)
                + (w if inv_mass[l] > 0.0 else 0.0))
        if free < MIN_FREE_WEIGHT:
            stuck += 1
            continue
        through += 1
        if not apply:
            continue
        norm = u * wi + v * wj + w * wl
        move = (overlap + SURFACE_GAP) / norm
        if frame[0][k] != 0:  # the direction back to the world (rotation only)
            nx, ny, nz = _rotate(frame[2], k, nx, ny, nz)
        for p, weight in ((i, wi), (j, wj), (l, wl)):
            if weight != 0.0:
                push[0, p] += move * weight * nx
                push[1, p] += move * weight * ny
                push[2, p] += move * weight * nz
                pushes[p] += 1.0
        stats[FACE_PUSHES] += 1.0
    if apply and through > 0:  # the mean of each point's pushes (Jacobi: a point of six
        # triangles is not pushed six times over)
        for p in range(x.shape[1]):
            if pushes[p] > 0.0:
                for a in range(3):
                    x[a, p] += push[a, p] / pushes[p]
                    push[a, p] = 0.0
                pushes[p] = 0.0
    return through, stuck


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _rotate(pose, k, nx, ny, nz):
    """A rest-frame direction of collider k in the world under its end pose."""
    return (pose[k, 1, 0] * nx + pose[k, 1, 1] * ny + pose[k, 1, 2] * nz,
            pose[k, 1, 3] * nx + pose[k, 1, 4] * ny + pose[k, 1, 5] * nz,
            pose[k, 1, 6] * nx + pose[k, 1, 7] * ny + pose[k, 1, 8] * nz)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _pinned_inside(x, inv_mass, kind, params, frame, k):
    """The first pinned point inside collider k, or -1."""
    prm = params[k]
    for p in range(x.shape[1]):
        if inv_mass[p] != 0.0:
            continue
        q = _rest(frame, k, 1, x, p)
        if kind == sphere.KIND:
            inside = _sphere_out(prm, q)[0]
        else:
            inside = box.outside(params, k, q[0], q[1], q[2])[0]
        if inside:
            return p
    return -1


@njit(cache=True, nogil=True, error_model="numpy", pointer=True)
def robust_colliders(x, x0, c, table):
    """Stages 1 and 2 for every active sphere and box collider, stage 1 for every plane, the
    mesh colliders' own (pipeline.physics.mesh_contact), in scene order, on the step
    from x0 to x (3, N), in place; returns the number of points and triangles moved. (The
    passes take plain arrays, not the two tables: numba's compile time grows with the
    types its functions take.)"""
    frame = (table.key_count, table.pivot, table.pose)
    inv_mass, stats = c.inv_mass, c.stats
    moved = 0
    for k in range(table.kinds.shape[0]):
        kind = table.kinds[k]
        if table.active[k] == 0:
            continue
        if kind == mesh.KIND:  # pipeline.physics.mesh_contact, through a pointer
            moved += c.mesh_pass(x, x0, c.meshes, c.edges, inv_mass, stats, table.params,
                                 table.data, table.key_count, table.pivot, table.pose, k,
                                 c.solid_stage, c.sheet_stage)
            continue
        moved += _paths(x, x0, inv_mass, stats, kind, table.params, frame, k)
        if kind == plane.KIND:  # no solid: no edge through it once no point is
            continue
        moved += c.solid_pass(x, c.triangles, inv_mass, c.push, c.pushes, stats, kind,
                              table.params, table.key_count, table.pivot, table.pose, k)
    return moved


@njit(cache=True, nogil=True, error_model="numpy", pointer=True)
def solid_faces(x, triangles, inv_mass, push, pushes, stats, kind, params, key_count, pivot,
                pose, k):
    """Stage 2 for sphere or box collider k, then its pinned points' check; returns the
    triangles moved. Called through a pointer (RobustContact.solid_pass), compiled only for
    scenes with a sphere or a box (a plane's scene does not need it: 2 s of a first run)."""
    frame = (key_count, pivot, pose)
    prm = params[k]
    moved = through = stuck = 0
    for r in range(FACE_ROUNDS + 1):  # the last round only looks
        through, stuck = _faces(x, triangles, inv_mass, push, pushes, stats, kind, prm, frame,
                                k, r < FACE_ROUNDS)
        if through == 0:
            break
        moved += through
    if through + stuck > 0:  # still in it after the rounds, or held in it by pins
        stats[NOT_KEPT] += 1.0
    pin = _pinned_inside(x, inv_mass, kind, params, frame, k)
    if pin >= 0:
        stats[NOT_KEPT] += 1.0
        if stats[PIN_POINT] < 0.0:
            stats[PIN_STEP], stats[PIN_POINT] = stats[6], float(pin)
    return moved
