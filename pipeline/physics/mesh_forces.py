"""Forces and Provot's limit of a mesh cloth (pipeline.physics.mesh_model): the kernels
System.kernels points to when the cloth is a mesh, with the signatures of the grid's
(forces.internal_forces, constraints.limit_stretch).

Each spring or element computes its forces into its own rows (a parallel loop over chunks
of them); each point then sums its rows in incidence order (a parallel loop over chunks of
points): no two threads write one place, and every sum has one order whatever the threads.
The FEM's element formulas are pipeline.physics.fem's, so a mesh of the grid's triangles
has the grid's energy.
"""
from __future__ import annotations

import numpy as np

from clothjit import njit, prange

from .fem import (_comb, _deformation, _dot, _hinge, _hinge_gradient, _membrane_diagonal,
                  _membrane_hessian, _membrane_stress)
from .constraints import shorten
from .forces import CHUNKS, _chunk
from .mesh_model import BLOCK, HINGE_CONSTANTS, PARTS, TRIANGLE_CONSTANTS, element_blocks


@njit(cache=True, nogil=True, forceinline=True, no_cpython_wrapper=True)
def _at(x, p):
    return (x[0, p], x[1, p], x[2, p])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _deformation_of(x, tris, inv, t):
    """fem._deformation (w_u, w_v) of triangle t at x (3, N)."""
    return _deformation(_at(x, tris[t, 0]), _at(x, tris[t, 1]), _at(x, tris[t, 2]),
                        inv[t, 0], inv[t, 1], inv[t, 2], inv[t, 3])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _hinge_at(x, hinges, h):
    """fem._hinge of hinge h at x (3, N)."""
    return _hinge(_at(x, hinges[h, 0]), _at(x, hinges[h, 1]), _at(x, hinges[h, 2]),
                  _at(x, hinges[h, 3]))


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def mesh_spring_forces(x, springs, mass, gravity, buffer, f):
    """f[:] = mass * gravity + the springs' forces at x (3, N); buffer (3, S) scratch. Reads
    the springs' int32 `ends` and `code` where they fit (at 100x100 the pass streams
    several MB a step, beyond a core's cache)."""
    ends, rest, stiffness = springs.ends, springs.rest, springs.stiffness
    start, code = springs.start, springs.code
    count, n = ends.shape[1], x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, count)
        _spring_pass(x, ends[0], ends[1], rest, stiffness, buffer, lo, hi)
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for p in range(lo, hi):
            m = mass[p]
            f[0, p], f[1, p], f[2, p] = m * gravity[0], m * gravity[1], m * gravity[2]
        _add_signed_sums(buffer, start, code, f, lo, hi)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _signed(buffer, code, j):
    """Spring column j of a point's incidence (MeshSprings.code) times its sign: -1 where the
    point is the spring's b end (adding -1 times it has the bits of subtracting it)."""
    e = np.uint64(code[j])
    s = e >> np.uint64(1)
    sign = 1.0 - 2.0 * np.float64(e & np.uint64(1))
    return sign * buffer[0, s], sign * buffer[1, s], sign * buffer[2, s]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _add_signed_sums(buffer, start, code, out, lo, hi):
    """out[:, p] plus buffer's column of each spring at point p (_signed), in p's incidence
    order, for p in [lo, hi): two points at a time (_signed_sums)."""
    for p in range(lo, hi, 2):
        q = min(p + 1, hi - 1)  # an odd run's last point twice: the same sum twice
        fp, fq = _signed_sums(buffer, start, code, p, q, (out[0, p], out[1, p], out[2, p]),
                              (out[0, q], out[1, q], out[2, q]))
        out[0, p], out[1, p], out[2, p] = fp
        out[0, q], out[1, q], out[2, q] = fq


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _signed_sums(buffer, start, code, p, q, fp, fq):
    """(fp, fq) plus buffer's column of each spring at point p and at q (_signed), in each
    point's incidence order: the two sums in one loop, two chains of additions that the
    CPU overlaps (one sum at a time waited on each addition)."""
    px, py, pz = fp
    qx, qy, qz = fq
    i, i_end = np.uint64(start[p]), np.uint64(start[p + 1])
    j, j_end = np.uint64(start[q]), np.uint64(start[q + 1])
    one = np.uint64(1)
    while i < i_end and j < j_end:
        ax, ay, az = _signed(buffer, code, i)
        bx, by, bz = _signed(buffer, code, j)
        px += ax
        py += ay
        pz += az
        qx += bx
        qy += by
        qz += bz
        i += one
        j += one
    for k in range(i, i_end):
        ax, ay, az = _signed(buffer, code, k)
        px += ax
        py += ay
        pz += az
    for k in range(j, j_end):
        bx, by, bz = _signed(buffer, code, k)
        qx += bx
        qy += by
        qz += bz
    return (px, py, pz), (qx, qy, qz)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _spring_pass(x, a, b, rest, stiffness, buffer, lo, hi):
    """buffer[:, s] = the force of spring s on its point a, s in [lo, hi): the endpoints'
    differences gathered first (unsigned indices: no wraparound test), then arithmetic
    over consecutive springs that LLVM vectorises."""
    for s in range(lo, hi):
        p, q = np.uint64(a[s]), np.uint64(b[s])
        for ax in range(3):
            buffer[ax, s] = x[ax, q] - x[ax, p]
    bx, by, bz = buffer[0, lo:hi], buffer[1, lo:hi], buffer[2, lo:hi]
    r, k = rest[lo:hi], stiffness[lo:hi]
    for i in range(hi - lo):
        dx, dy, dz = bx[i], by[i], bz[i]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        scale = k[i] * (length - r[i]) / length
        ok = length > 0.0  # zero length: direction undefined, no force
        bx[i] = dx * scale if ok else 0.0
        by[i] = dy * scale if ok else 0.0
        bz[i] = dz * scale if ok else 0.0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def mesh_internal_forces(x, fem, springs, mass, gravity, spring_force, passes, f):
    """forces.internal_forces for a classic mesh cloth (`fem` and `passes` unused;
    spring_force (1, 3, S))."""
    mesh_spring_forces(x, springs, mass, gravity, spring_force[0], f)


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _row_sum(rows, start, slot, p, fx, fy, fz):
    """(fx, fy, fz) plus the element rows of point p, in incidence order (unsigned
    indices: no wraparound test)."""
    for j in range(np.uint64(start[p]), np.uint64(start[p + 1])):
        r = np.uint64(slot[j])
        fx += rows[r, 0]
        fy += rows[r, 1]
        fz += rows[r, 2]
    return fx, fy, fz


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _corner(rows, r, k, j):
    """Corner k's (x, y, z) of lane j in the block rows from r."""
    return (rows[r + np.uint64(3 * k * BLOCK) + j], rows[r + np.uint64((3 * k + 1) * BLOCK) + j],
            rows[r + np.uint64((3 * k + 2) * BLOCK) + j])


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _put(rows, r, k, j, v):
    """Corner k's rows of lane j = v (3,)."""
    rows[r + np.uint64(3 * k * BLOCK) + j] = v[0]
    rows[r + np.uint64((3 * k + 1) * BLOCK) + j] = v[1]
    rows[r + np.uint64((3 * k + 2) * BLOCK) + j] = v[2]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _gather(x, points, first, corners, b, rows, r):
    """The block rows from r = the positions at x (3, N) of the corners of element block b
    of a kind (its points from points[first + b corners BLOCK]): a scalar loop (the points
    are indices), so that the arithmetic after it reads rows at constant distances."""
    for k in range(corners):
        at = np.uint64(first + (b * corners + k) * BLOCK)
        out = r + np.uint64(3 * k * BLOCK)
        for j in range(np.uint64(BLOCK)):
            p = np.uint64(points[at + j])
            rows[out + j] = x[0, p]
            rows[out + np.uint64(BLOCK) + j] = x[1, p]
            rows[out + np.uint64(2 * BLOCK) + j] = x[2, p]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _triangle_block(rows, r, constants, c, ks, kh):
    """A triangle block's corner positions (rows from r) -> their membrane forces, in place
    (constants from c)."""
    for j in range(np.uint64(BLOCK)):
        i00, i01 = constants[c + j], constants[c + np.uint64(BLOCK) + j]
        i10, i11 = constants[c + np.uint64(2 * BLOCK) + j], constants[c + np.uint64(3 * BLOCK) + j]
        area = constants[c + np.uint64(4 * BLOCK) + j]
        wu, wv = _deformation(_corner(rows, r, 0, j), _corner(rows, r, 1, j),
                              _corner(rows, r, 2, j), i00, i01, i10, i11)
        pu, pv = _membrane_stress(wu, wv, area * ks, area * kh)
        g1 = _comb(pu, i00, pv, i01)  # dE/dx1
        g2 = _comb(pu, i10, pv, i11)  # dE/dx2
        _put(rows, r, 0, j, (g1[0] + g2[0], g1[1] + g2[1], g1[2] + g2[2]))  # -(dE/dx0)
        _put(rows, r, 1, j, (-g1[0], -g1[1], -g1[2]))
        _put(rows, r, 2, j, (-g2[0], -g2[1], -g2[2]))


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _hinge_block(rows, r, constants, c, kb):
    """A hinge block's corner positions (rows from r) -> their bending forces, in place
    (constants from c)."""
    for j in range(np.uint64(BLOCK)):
        factor, rest = constants[c + j], constants[c + np.uint64(BLOCK) + j]
        theta, ok, length, n1, n2, inv1, inv2, t1, t2 = _hinge(
            _corner(rows, r, 0, j), _corner(rows, r, 1, j), _corner(rows, r, 2, j),
            _corner(rows, r, 3, j))
        scale = -2.0 * kb * factor * (theta - rest) if ok else 0.0
        g = _hinge_gradient(length, (n1[0] * inv1, n1[1] * inv1, n1[2] * inv1),
                            (n2[0] * inv2, n2[1] * inv2, n2[2] * inv2), t1, t2)
        for k in range(4):
            _put(rows, r, k, j, (scale * g[k][0], scale * g[k][1], scale * g[k][2]))


@njit(cache=True, nogil=True, error_model="numpy", forceinline=True, no_cpython_wrapper=True)
def _sum_points(rows, start, slot, order, lo, hi, mass, gravity, f):
    """f[:, p] = mass * gravity + the rows of p in incidence order, p = order[lo:hi]."""
    for i in range(lo, hi):
        p = np.uint64(order[i])
        m = mass[p]
        fx, fy, fz = m * gravity[0], m * gravity[1], m * gravity[2]
        for j in range(np.uint64(start[p]), np.uint64(start[p + 1])):
            s = np.uint64(slot[j])
            fx += rows[s]
            fy += rows[s + np.uint64(BLOCK)]
            fz += rows[s + np.uint64(2 * BLOCK)]
        f[0, p], f[1, p], f[2, p] = fx, fy, fz


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def mesh_fem_forces(x, fem, mass, gravity, f):
    """f[:] = mass * gravity + the FEM's elastic forces at x (3, N) (fem: MeshFem): each run
    of parts (one per thread; a thread takes several if it must), part by part: its element
    blocks into their rows (fem.block_row) and the sums of the points whose rows all lie in
    the run and end there; then the sums of the other points."""
    points, constants, rows, at = (fem.block_points, fem.block_constants, fem.block_rows,
                                   fem.block_row)
    bounds, part_points, order = fem.part_blocks, fem.part_points, fem.point_order
    start, slot, tb, runs = fem.start, fem.row_slot, fem.tri_blocks, fem.runs
    ks, kh, kb = fem.k_stretch, fem.k_shear, fem.k_bend
    hinge_points, hinge_constants = 3 * tb * BLOCK, TRIANGLE_CONSTANTS * tb * BLOCK
    for t in prange(runs):
        for q in range(t * PARTS // runs, (t + 1) * PARTS // runs):
            for b in range(bounds[q, 0], bounds[q + 1, 0]):
                r = np.uint64(at[b])
                _gather(x, points, 0, 3, b, rows, r)
                _triangle_block(rows, r, constants, np.uint64(TRIANGLE_CONSTANTS * BLOCK * b),
                                ks, kh)
            for b in range(bounds[q, 1], bounds[q + 1, 1]):
                r = np.uint64(at[tb + b])
                _gather(x, points, hinge_points, 4, b, rows, r)
                _hinge_block(rows, r, constants,
                             np.uint64(hinge_constants + HINGE_CONSTANTS * BLOCK * b), kb)
            _sum_points(rows, start, slot, order, part_points[q], part_points[q + 1], mass,
                        gravity, f)
    first, shared = part_points[PARTS], part_points[PARTS + 1] - part_points[PARTS]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, shared)
        _sum_points(rows, start, slot, order, first + lo, first + hi, mass, gravity, f)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def mesh_fem_internal_forces(x, fem, springs, mass, gravity, spring_force, passes, f):
    """forces.internal_forces for a FEM mesh cloth (`springs`, `spring_force` and `passes`
    unused)."""
    mesh_fem_forces(x, fem, mass, gravity, f)


@njit(cache=True, nogil=True)
def hinge_angles(x, hinges, out):
    """out[h] = the dihedral angle of hinge h at x (3, N), as mesh_fem_forces measures it."""
    for h in range(hinges.shape[0]):
        out[h] = _hinge_at(x, hinges, h)[0]


def with_rest_angles(fem, x0: np.ndarray):
    """`fem` (MeshFem) with its rest angles measured at x0 (3, N)."""
    angles = np.zeros(fem.hinges.shape[0])
    hinge_angles(x0, fem.hinges, angles)
    return element_blocks(fem._replace(rest_angle=angles))


@njit(cache=True, nogil=True)
def mesh_fem_energy(x, fem):
    """Elastic energy (J) of the FEM mesh cloth at x (3, N)."""
    tris, area, inv = fem.triangles, fem.tri_area, fem.tri_inv
    energy = 0.0
    for t in range(tris.shape[0]):
        wu, wv = _deformation_of(x, tris, inv, t)
        lu, lv = np.sqrt(_dot(wu, wu)), np.sqrt(_dot(wv, wv))
        shear = _dot(wu, wv)
        energy += 0.5 * area[t] * (fem.k_stretch * ((lu - 1.0) ** 2 + (lv - 1.0) ** 2)
                                   + fem.k_shear * shear * shear)
    for h in range(fem.hinges.shape[0]):
        theta = _hinge_at(x, fem.hinges, h)[0]
        energy += fem.k_bend * fem.hinge_factor[h] * (theta - fem.rest_angle[h]) ** 2
    return energy


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def mesh_limit_stretch(x, springs, exist_bits, limit, limit_sq_lo, pinned, scratch):
    """Provot's limit on the structural springs in list order (constraints.limit_stretch's
    rule; `limit` (1, S) is 1.1 rest, `limit_sq_lo` its square lowered by 1e-9 relative: a
    spring not longer than that is short of its limit and takes no square root, as in
    limit_stretch's pre-pass; `exist_bits` and `scratch` unused)."""
    a, b, lim_row, lim_sq_row = springs.ends[0], springs.ends[1], limit[0], limit_sq_lo[0]
    for s in range(springs.structural):
        p, q = np.uint64(a[s]), np.uint64(b[s])
        dx = x[0, q] - x[0, p]
        dy = x[1, q] - x[1, p]
        dz = x[2, q] - x[2, p]
        length_sq = dx * dx + dy * dy + dz * dz
        if length_sq <= lim_sq_row[s]:
            continue
        pa = pinned[p] != 0
        pb = pinned[q] != 0
        if pa and pb:
            continue
        length = np.sqrt(length_sq)
        lim = lim_row[s]
        if length > lim:
            shorten(x, p, q, dx, dy, dz, length, lim, pa, pb)


# --- the force Jacobian K = df/dx for implicit Euler (forces.JacobianKernels) --------------


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def mesh_spring_jacobian(x, springs, unit, alpha):
    """Per-spring data of K at x (forces.spring_jacobian's, over the spring list): unit[0, :,
    s] the spring's direction, alpha[0, s] = k max(0, 1 - rest / l), -1 where it exerts no
    force."""
    a, b, rest, stiffness = springs.a, springs.b, springs.rest, springs.stiffness
    count = a.shape[0]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, count)
        for s in range(lo, hi):
            p, q, k = a[s], b[s], stiffness[s]
            dx = x[0, q] - x[0, p]
            dy = x[1, q] - x[1, p]
            dz = x[2, q] - x[2, p]
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            if k == 0.0 or not length > 0.0:
                alpha[0, s] = -1.0
                continue
            unit[0, 0, s] = dx / length
            unit[0, 1, s] = dy / length
            unit[0, 2, s] = dz / length
            alpha[0, s] = k * max(0.0, 1.0 - rest[s] / length)


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def mesh_spring_product(y, springs, unit, alpha, buffer, out):
    """out = K y at the point of mesh_spring_jacobian: (K y)_a = K_s (y_b - y_a) and minus
    that at b, K_s = k u u^T + alpha (I - u u^T); buffer (3, S)."""
    a, b, stiffness = springs.a, springs.b, springs.stiffness
    start, code = springs.start, springs.code
    count, n = a.shape[0], y.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, count)
        for s in range(lo, hi):
            w, k, p, q = alpha[0, s], stiffness[s], a[s], b[s]
            ux, uy, uz = unit[0, 0, s], unit[0, 1, s], unit[0, 2, s]
            rx = y[0, q] - y[0, p]
            ry = y[1, q] - y[1, p]
            rz = y[2, q] - y[2, p]
            along = ux * rx + uy * ry + uz * rz
            buffer[0, s] = 0.0 if w < 0.0 else (k - w) * along * ux + w * rx
            buffer[1, s] = 0.0 if w < 0.0 else (k - w) * along * uy + w * ry
            buffer[2, s] = 0.0 if w < 0.0 else (k - w) * along * uz + w * rz
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        out[:, lo:hi] = 0.0
        _add_signed_sums(buffer, start, code, out, lo, hi)


@njit(cache=True, nogil=True, error_model="numpy")
def mesh_spring_diagonal_of(springs, unit, alpha, out):
    """out[a, p] = the diagonal of -K at the point of mesh_spring_jacobian: the sum of
    k u_a^2 + alpha (1 - u_a^2) over the springs at p."""
    start, code, stiffness = springs.start, springs.code, springs.stiffness
    for p in range(out.shape[1]):
        for ax in range(3):
            total = 0.0
            for j in range(start[p], start[p + 1]):
                s = code[j] >> 1
                w, u = alpha[0, s], unit[0, ax, s]
                if w >= 0.0:
                    total += stiffness[s] * u * u + w * (1.0 - u * u)
            out[ax, p] = total


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def mesh_fem_product(x, y, fem, out, diagonal):
    """out = K_f y, K_f the FEM's filtered force Jacobian at x (the positive semi-definite
    part of the Hessian, negated: membrane as fem._membrane_hessian with `filtered`, bending
    2 k_bend f g g^T, g = d theta / dx), or with `diagonal` out = the diagonal of -K_f."""
    tris, area, inv = fem.triangles, fem.tri_area, fem.tri_inv
    hinges, factor = fem.hinges, fem.hinge_factor
    rows, start, slot = fem.corner_force, fem.start, fem.slot
    n_tri, n_hinge, n = tris.shape[0], hinges.shape[0], x.shape[1]
    ks, kh, kb = fem.k_stretch, fem.k_shear, fem.k_bend
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n_tri)
        for t in range(lo, hi):
            i00, i01, i10, i11 = inv[t, 0], inv[t, 1], inv[t, 2], inv[t, 3]
            wu, wv = _deformation_of(x, tris, inv, t)
            ka, kc = area[t] * ks, area[t] * kh
            if diagonal:
                du, dv = _membrane_diagonal(wu, wv, ka, kc), _membrane_diagonal(wv, wu, ka, kc)
                for k, cu, cv in ((0, -(i00 + i10), -(i01 + i11)), (1, i00, i01), (2, i10, i11)):
                    for ax in range(3):
                        rows[3 * t + k, ax] = (cu * cu * du[ax] + cv * cv * dv[ax]
                                               + 2.0 * cu * cv * kc * wu[ax] * wv[ax])
                continue
            dwu, dwv = _deformation_of(y, tris, inv, t)
            pu, pv = _membrane_hessian(wu, wv, dwu, dwv, ka, kc, True)
            g1, g2 = _comb(pu, i00, pv, i01), _comb(pu, i10, pv, i11)
            for ax in range(3):
                rows[3 * t, ax] = g1[ax] + g2[ax]
                rows[3 * t + 1, ax] = -g1[ax]
                rows[3 * t + 2, ax] = -g2[ax]
    base = 3 * n_tri
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n_hinge)
        for h in range(lo, hi):
            theta, ok, length, n1, n2, inv1, inv2, t1, t2 = _hinge_at(x, hinges, h)
            g = _hinge_gradient(length, (n1[0] * inv1, n1[1] * inv1, n1[2] * inv1),
                                (n2[0] * inv2, n2[1] * inv2, n2[2] * inv2), t1, t2)
            stiff = 2.0 * kb * factor[h] if ok else 0.0
            along = 0.0
            for k in range(4):
                along += _dot(g[k], _at(y, hinges[h, k]))
            for k in range(4):
                for ax in range(3):
                    rows[base + 4 * h + k, ax] = (stiff * g[k][ax] * g[k][ax] if diagonal
                                                  else -stiff * along * g[k][ax])
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for p in range(lo, hi):
            fx, fy, fz = _row_sum(rows, start, slot, p, 0.0, 0.0, 0.0)
            out[0, p], out[1, p], out[2, p] = fx, fy, fz


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def mesh_spring_prepare(x, fem, springs, unit, alpha):
    mesh_spring_jacobian(x, springs, unit, alpha)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def mesh_spring_apply(x, y, fem, springs, unit, alpha, buffer, out, passes):
    mesh_spring_product(y, springs, unit, alpha, buffer[0], out)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def mesh_spring_diagonal(x, fem, springs, unit, alpha, out):
    mesh_spring_diagonal_of(springs, unit, alpha, out)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def mesh_fem_prepare(x, fem, springs, unit, alpha):
    """Nothing: the FEM's products need nothing beyond x."""


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def mesh_fem_apply(x, y, fem, springs, unit, alpha, buffer, out, passes):
    # np.bool_, not a literal: numba would compile the product once per literal (seconds each)
    mesh_fem_product(x, y, fem, out, np.bool_(False))


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def mesh_fem_diagonal(x, fem, springs, unit, alpha, out):
    mesh_fem_product(x, x, fem, out, np.bool_(True))
