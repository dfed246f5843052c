"""Forces of the classic model: gravity on every point plus Hooke's law along every enabled
spring (SPEC section 2, step 1), plus the scene's other forces (wind), shared by every
integrator through `total_force`. With the FEM model (System.classic False) the springs'
forces and Jacobians give way to pipeline.physics.fem's (System.kernels.internal points to
`fem_internal_forces`, `jacobian_kernels` to the FEM's, see below).

A force beyond gravity and springs is one @njit function `add_...(x, v, t, params, f)` that
adds to f, packed into the System by system.build_system (params None, or of the same type
as the force's with a flag saying it is off: see system.StepKernels) and called through a
pointer in System.kernels from `add_other_forces`, which `total_force` and `external_force`
hand each force's params and pointer (not the System: see below).

Positions and forces are structure-of-arrays, shape (3, N). The spring forces are computed
direction by direction into `spring_force` (6, 3, N + pad): contiguous loops the compiler
turns into SIMD code, split over the cores. Each point then gathers its forces in the order
the course code accumulates them (its own six springs in direction order, then the springs
of later points ending at it, by creating point), so the sums are bit-identical to a scalar
walk over the spring list.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba.core import types
from numba.extending import register_jitable

from clothjit import KernelPointer, njit, prange

from .fem import add_fem_forces, fem_energy, fem_filtered_jacobian_product, fem_jacobian_diagonal
from .mesh_model import MeshSprings
from .model import DIRECTION_DI, DIRECTION_DJ

CHUNKS = 16  # work items per pass; numba spreads them over the threads
# From this many points on, the colliders' and Provot's per-point passes run as parallel
# loops (colliders.ColliderTable.points, constraints.CandidateMask.mark); under it, in one
# serial call, which is as fast there and compiles sooner (numba's parallel loop costs
# 0.6-1.0 s of compile whatever its body). Measured, one serial call against the parallel
# loop at 2 threads: the colliders on the draped sphere scene 11.0 against 9.5-10.0 us at
# 2500 points, 37-54 against 20-34 us at 10,000, 141-153 against 79-83 us at 40,000
# (at 1 thread); Provot's pre-pass 9.9-10.1 against 10.1-11.7 us at 2500 points, 37.8
# against 24.5 us at 10,000, 162 against 94 us at 40,000.
PARALLEL_POINTS = 5000


def direction_offsets(nw: int) -> np.ndarray:
    """Index offset q - p of the neighbour of each spring direction (all negative)."""
    return (DIRECTION_DI * nw + DIRECTION_DJ).astype(np.int64)


def gather_order(nw: int) -> np.ndarray:
    """Directions ordered by the creating point of the springs that end at a point (then by
    direction): the order in which the course code subtracts them from that point."""
    offsets = direction_offsets(nw)
    return np.array(sorted(range(6), key=lambda d: (-offsets[d], d)), dtype=np.int64)


def spring_force_buffer(n: int, nw: int) -> np.ndarray:
    """Zeroed (6, 3, N + pad) buffer; the pad stays zero so the gather needs no bounds test."""
    return np.zeros((6, 3, n + 2 * nw + 2), dtype=np.float64)


@njit(cache=True, nogil=True, inline="always")
def _chunk(c, n):
    return (c * n) // CHUNKS, ((c + 1) * n) // CHUNKS


# The loops below index slices by a loop counter from 0: numba then knows the index is not
# negative and emits no wraparound select per load, and with error_model="numpy" no
# zero-division branch either, so LLVM vectorises them. Same arithmetic, same bits.

@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def _direction_forces(x, offsets, exists, rest_lengths, stiffness, spring_force, d, lo, hi):
    """spring_force[d, :, p] = force of the spring (d, p) on p for p in [lo, hi) (0 where
    none). Takes whole arrays and d, not their rows, which the caller's parallel loop
    would make as views (a reference count raised and dropped per call); without numba's
    reference counts (`_nrt=False`: nothing here allocates), as _gather."""
    off, k, f_d = offsets[d], stiffness[d], spring_force[d]
    start = min(max(lo, -off), hi)  # the neighbour p + off must be a point
    f_d[:, lo:start] = 0.0
    m = hi - start
    ax, ay, az = x[0, start:hi], x[1, start:hi], x[2, start:hi]
    bx, by, bz = x[0, start + off:hi + off], x[1, start + off:hi + off], x[2, start + off:hi + off]
    ex, rest = exists[d, start:hi], rest_lengths[d, start:hi]
    fx, fy, fz = f_d[0, start:hi], f_d[1, start:hi], f_d[2, start:hi]
    for i in range(m):
        dx = bx[i] - ax[i]
        dy = by[i] - ay[i]
        dz = bz[i] - az[i]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        s = k * (length - rest[i])
        ok = ex[i] & (length > 0.0)  # zero length: direction undefined, no force
        fx[i] = (dx / length) * s if ok else 0.0
        fy[i] = (dy / length) * s if ok else 0.0
        fz[i] = (dz / length) * s if ok else 0.0


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def _gather(spring_force, offsets, order, mass, gravity, f, lo, hi):
    """f[:, lo:hi] = mass * gravity + own springs - springs of later points ending there, in
    the course code's order of accumulation."""
    m = hi - lo
    mass_lo = mass[lo:hi]
    for a in range(3):
        out = f[a, lo:hi]
        g = gravity[a]
        for i in range(m):
            out[i] = mass_lo[i] * g
        for d in range(6):
            own = spring_force[d, a, lo:hi]
            for i in range(m):
                out[i] += own[i]
        for j in range(6):
            d = order[j]
            other = spring_force[d, a, lo - offsets[d]:hi - offsets[d]]
            for i in range(m):
                out[i] -= other[i]


class SpringKernels(NamedTuple):
    """spring_forces' two passes, called through pointers from its parallel loops: numba
    compiles a parallel loop's body several times and optimises a linked callee again in
    each copy, so they compile once, on their own: internal_forces and the two passes in
    2.9-3.3 s of CPU instead of 5.4-5.7 s (the README scene on an empty cache, three rounds
    alternately, 2026-11-26). A call through a pointer inside a parallel loop costs about
    5 ns (measured; the stepping kernel unboxes the pointers once per call, not per step)."""

    direction: KernelPointer  # _direction_forces
    gather: KernelPointer  # _gather


def spring_kernels(offsets, exists, rest, stiffness, spring_force, order, mass,
                   gravity, present=True) -> SpringKernels:
    """Pointers to the passes, typed as spring_forces calls them."""
    field, index = types.float64[:, ::1], types.int64  # positions and forces (3, N)
    return SpringKernels(
        KernelPointer(_direction_forces, (field, offsets, exists, rest, stiffness, spring_force,
                                          index, index, index), present=present),
        KernelPointer(_gather, (spring_force, offsets, order, mass, gravity, field, index,
                                index), present=present))


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True)
def spring_forces(x, offsets, order, exists, rest, stiffness, mass, gravity, spring_force,
                  passes, f):
    """f[:] = mass * gravity + the spring forces at positions x (3, N); mass is (N,), and
    spring_force[d, :, p] = force of spring (d, p) on its creating point p (0 if none);
    `passes` the SpringKernels. Both parallel loops in one kernel: the first as a parallel
    kernel of its own, called here, made the first compile 1-2 s longer (its parallel
    machinery compiled twice)."""
    n = x.shape[1]
    direction, gather = passes
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for d in range(6):
            direction(x, offsets, exists, rest, stiffness, spring_force, d, lo, hi)
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        gather(spring_force, offsets, order, mass, gravity, f, lo, hi)


@njit(cache=True, nogil=True, inline="always")
def total_force(x, v, t, s, f):
    """f[:] = every force on the points at positions x, velocities v (3, N), time t, for the
    System `s`: gravity and the cloth's internal forces (classic: in the course code's order
    of summation), then wind. For kernels (inlined into the stepping kernels); Python calls
    `total_force_now`."""
    forces_of(x, v, t, force_fields(s), f)


#: total_force called from Python: its plain function (forces_of compiled, the fields in Python)
total_force_now = total_force.py_func


@register_jitable(inline="always")
def force_fields(s) -> tuple:
    """The System's fields the forces read, as one argument of `forces_of` (plain Python
    when Python calls it, inlined in kernels). The pointer comes last: numba tries to unify
    a plain tuple starting with a function as a tuple of functions, and warns."""
    return (s.fem, s.springs, s.mass, s.gravity, s.spring_force, s.kernels.springs, s.wind,
            s.kernels.wind, s.kernels.internal)


@njit(cache=True, nogil=True, inline="always")
def forces_of(x, v, t, fields, f):
    """total_force from the System's fields (force_fields): inlined in kernels; called from
    Python it compiles once per System kind (system.StepKernels; its entry point
    unboxes these fields; one taking the System compiled again for every System type,
    2-3 s each, and unboxed all of it)."""
    fem, springs, mass, gravity, spring_force, passes, wind, wind_force, internal = fields
    internal(x, fem, springs, mass, gravity, spring_force, passes, f)
    add_other_forces(x, v, t, wind, wind_force, f)


# The kernels below take the System's fields, not the System (see system.py: one compile
# for every System type, and no half-second entry point that unboxes the whole System).


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def internal_forces(x, fem, springs, mass, gravity, spring_force, passes, f):
    """f[:] = gravity + the springs' forces (the grid's classic model; `fem` unused;
    `springs` System.springs, `passes` the SpringKernels). Called through
    System.kernels.internal (a KernelPointer), as fem_internal_forces with the FEM and
    pipeline.physics.mesh_forces' kernels for a mesh cloth."""
    offsets, order, exists, rest, stiffness = springs
    spring_forces(x, offsets, order, exists, rest, stiffness, mass, gravity, spring_force,
                  passes, f)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def fem_internal_forces(x, fem, springs, mass, gravity, spring_force, passes, f):
    """f[:] = gravity + the FEM's elastic forces (the springs' arguments unused). A kernel
    of its own, chosen in Python: one kernel testing the model would compile both models'
    forces."""
    _gravity(mass, gravity, f)
    add_fem_forces(x, fem, f)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def _gravity(mass, gravity, f):
    for a in range(3):
        for p in range(f.shape[1]):
            f[a, p] = mass[p] * gravity[a]


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def external_force(x, v, t, mass, gravity, wind, wind_force, f):
    """f[:] = gravity and the scene's other forces, without the springs (for XPBD, which
    treats the springs as constraints)."""
    _gravity(mass, gravity, f)
    add_other_forces(x, v, t, wind, wind_force, f)


@njit(cache=True, nogil=True, no_cpython_wrapper=True)
def add_other_forces(x, v, t, wind, wind_force, f):
    """f += the forces beyond gravity and springs, each through its pointer
    (System.kernels), called only when the scene has it (the pointer is None, which numba
    prunes, or absent otherwise): wind.add_wind_force when `wind.on`. Not inlined: numba
    prunes a test `is None` only of a function's own argument."""
    if wind is not None:
        if wind.on:
            wind_force(x, v, t, wind, f)


# --- helpers for the other integrators (pipeline/integrators/*), added with issue 6 --------


def elastic_energy(x: np.ndarray, s) -> float:
    """Elastic potential energy (J) of the System `s`'s model at positions x (3, N)."""
    if not s.classic:
        return fem_energy(x, s.fem)
    offsets, _, exists, rest, stiffness = s.springs
    return spring_energy(x, offsets, exists, rest, stiffness)


@njit(cache=True, nogil=True)
def spring_energy(x, offsets, exists, rest, stiffness):
    """Potential energy sum of k (|pa - pb| - rest)^2 / 2 over the enabled springs (J)."""
    n = x.shape[1]
    energy = 0.0
    for d in range(6):
        k = stiffness[d]
        if k == 0.0:
            continue
        off = offsets[d]
        for p in range(max(0, -off), n):
            if not exists[d, p]:
                continue
            q = p + off
            dx = x[0, q] - x[0, p]
            dy = x[1, q] - x[1, p]
            dz = x[2, q] - x[2, p]
            stretch = np.sqrt(dx * dx + dy * dy + dz * dz) - rest[d, p]
            energy += 0.5 * k * stretch * stretch
    return energy


@njit(cache=True, nogil=True, parallel=True)
def spring_jacobian(x, offsets, exists, rest, stiffness, unit, alpha):
    """Per-spring data of the force Jacobian at x (Baraff and Witkin 1998, section 4.2).

    For spring (d, p) to q = p + offsets[d], with u = (x_q - x_p) / l, the block
    K_s = d f_p / d x_q = k u u^T + k max(0, 1 - rest / l) (I - u u^T): the exact derivative
    of Hooke's force k (l - rest) u, except that the transverse term is dropped for
    compressed springs (it is negative there), which keeps the system matrix
    M - h^2 df/dx symmetric positive definite (the usual cloth filter, Choi and Ko 2002).
    Fills unit[d, :, p] = u and alpha[d, p] = k max(0, 1 - rest / l); alpha is -1 where the
    spring exerts no force (missing, disabled, zero length).
    """
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for d in range(6):
            k = stiffness[d]
            off = offsets[d]
            for p in range(lo, hi):
                q = p + off
                if k == 0.0 or q < 0 or not exists[d, p]:
                    alpha[d, p] = -1.0
                    continue
                dx = x[0, q] - x[0, p]
                dy = x[1, q] - x[1, p]
                dz = x[2, q] - x[2, p]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                if not length > 0.0:
                    alpha[d, p] = -1.0
                    continue
                unit[d, 0, p] = dx / length
                unit[d, 1, p] = dy / length
                unit[d, 2, p] = dz / length
                alpha[d, p] = k * max(0.0, 1.0 - rest[d, p] / length)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def _jacobian_pass(y, offsets, stiffness, unit, alpha, buffer, d, lo, hi):
    """buffer[d, :, p] = K_s (y_q - y_p) of the spring s = (d, p) for p in [lo, hi), at the
    point of `spring_jacobian` (0 where none): the product's first pass, as
    _direction_forces is the forces' (slices indexed from 0, no branch: vectorised)."""
    k, off = stiffness[d], offsets[d]
    start = min(max(lo, -off), hi)  # below, alpha is -1: no neighbour p + off
    buffer[d, :, lo:start] = 0.0
    a_d = alpha[d, start:hi]
    ux, uy, uz = unit[d, 0, start:hi], unit[d, 1, start:hi], unit[d, 2, start:hi]
    ax, ay, az = y[0, start:hi], y[1, start:hi], y[2, start:hi]
    bx, by, bz = y[0, start + off:hi + off], y[1, start + off:hi + off], y[2, start + off:hi + off]
    fx, fy, fz = buffer[d, 0, start:hi], buffer[d, 1, start:hi], buffer[d, 2, start:hi]
    for i in range(hi - start):
        a = a_d[i]
        rx = bx[i] - ax[i]
        ry = by[i] - ay[i]
        rz = bz[i] - az[i]
        along = ux[i] * rx + uy[i] * ry + uz[i] * rz
        fx[i] = 0.0 if a < 0.0 else (k - a) * along * ux[i] + a * rx
        fy[i] = 0.0 if a < 0.0 else (k - a) * along * uy[i] + a * ry
        fz[i] = 0.0 if a < 0.0 else (k - a) * along * uz[i] + a * rz


class ProductPasses(NamedTuple):
    """The springs' Jacobian product's two passes, called through pointers from its parallel
    loops (as SpringKernels are from spring_forces'): `spread` (_jacobian_pass), `gather`
    (the forces' own _gather, with no mass and no gravity: zero_mass (N,), zero_gravity
    (3,)). Absent, with arrays of the same types, for the FEM."""

    spread: KernelPointer
    gather: KernelPointer
    zero_mass: np.ndarray
    zero_gravity: np.ndarray


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True)
def spring_jacobian_product(y, offsets, order, stiffness, unit, alpha, buffer, out, passes):
    """out = K y with K = d(spring forces)/dx at the point of `spring_jacobian` (K is
    negative semi-definite): (K y)_p = sum over springs s at p of K_s (y_other - y_p).
    `buffer` is a (6, 3, N + pad) scratch like forces.spring_force_buffer; `passes` the
    ProductPasses."""
    n = y.shape[1]
    spread, gather, zero_mass, zero_gravity = passes
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for d in range(6):
            spread(y, offsets, stiffness, unit, alpha, buffer, d, lo, hi)
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        gather(buffer, offsets, order, zero_mass, zero_gravity, out, lo, hi)


@njit(cache=True, nogil=True)
def spring_jacobian_diagonal(offsets, stiffness, unit, alpha, out):
    """out[a, p] = -(K)_{pa, pa}: the diagonal of -K (>= 0) at the point of `spring_jacobian`,
    summed over the springs at p (its own and those ending at it); for a Jacobi
    preconditioner."""
    n = out.shape[1]
    out[:] = 0.0
    for d in range(6):
        k = stiffness[d]
        off = offsets[d]
        for p in range(n):
            a = alpha[d, p]
            if a < 0.0:
                continue
            q = p + off
            for ax in range(3):
                u = unit[d, ax, p]
                diag = k * u * u + a * (1.0 - u * u)
                out[ax, p] += diag
                out[ax, q] += diag


# --- the elastic force Jacobian of either model, for implicit Euler ------------------------


class JacobianKernels(NamedTuple):
    """Pointers to one model's elastic force Jacobian, for implicit Euler: `prepare` (x, fem,
    springs, unit, alpha) linearises at x, `product` (x, y, fem, springs, unit, alpha, buffer,
    out, passes) sets out = K y, `diagonal` (x, fem, springs, unit, alpha, out) sets out = the
    diagonal of -K (>= 0) per (axis, point), for a Jacobi preconditioner; `passes` the
    springs' product's ProductPasses (absent for the FEM). K is negative semi-definite:
    compressed springs, or the FEM's filtered Hessian. One signature for both models
    (`springs`: System.springs, `fem`: System.fem; each model's kernels ignore the other's),
    so the solve that calls them compiles once for both."""

    prepare: KernelPointer
    product: KernelPointer
    diagonal: KernelPointer
    passes: ProductPasses


def jacobian_kernels(system, x, unit, alpha, buffer) -> JacobianKernels:
    """The System's model's JacobianKernels, typed for positions like x (3, N) and the
    springs' scratch (unit, alpha, buffer: see spring_jacobian)."""
    from . import mesh_forces

    classic = system.classic
    mesh = isinstance(system.springs, MeshSprings)
    # a mesh cloth's own kernels need no passes: the grid's, absent, typed for no springs
    offsets, stiffness = ((direction_offsets(0), np.zeros(6)) if mesh
                          else (system.springs[0], system.springs[4]))
    field, index = types.float64[:, ::1], types.int64
    zero_mass, zero_gravity = np.zeros(x.shape[1]), np.zeros(3)
    passes = ProductPasses(
        KernelPointer(_jacobian_pass, (field, offsets, stiffness, unit, alpha, buffer, index,
                                       index, index), present=classic and not mesh),
        system.kernels.springs.gather,  # the forces' own (absent with the FEM, a mesh)
        zero_mass, zero_gravity)
    fields = (system.fem, system.springs, unit, alpha)
    if mesh:
        prepare, product, diagonal = (
            (mesh_forces.mesh_spring_prepare, mesh_forces.mesh_spring_apply,
             mesh_forces.mesh_spring_diagonal) if classic else
            (mesh_forces.mesh_fem_prepare, mesh_forces.mesh_fem_apply,
             mesh_forces.mesh_fem_diagonal))
    else:
        prepare, product, diagonal = ((spring_prepare, spring_product, spring_diagonal)
                                      if classic else (fem_prepare, fem_product, fem_diagonal))
    return JacobianKernels(
        KernelPointer(prepare, (x, *fields)),
        KernelPointer(product, (x, x, *fields, buffer, x, passes)),
        KernelPointer(diagonal, (x, *fields, x)),
        passes)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def spring_prepare(x, fem, springs, unit, alpha):
    """The springs' per-spring data at x (spring_jacobian)."""
    offsets, _, exists, rest, stiffness = springs
    spring_jacobian(x, offsets, exists, rest, stiffness, unit, alpha)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def fem_prepare(x, fem, springs, unit, alpha):
    """Nothing: the FEM's products need nothing beyond x."""


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def spring_product(x, y, fem, springs, unit, alpha, buffer, out, passes):
    """out = K y of the springs (spring_jacobian_product)."""
    offsets, order, _, _, stiffness = springs
    spring_jacobian_product(y, offsets, order, stiffness, unit, alpha, buffer, out, passes)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def fem_product(x, y, fem, springs, unit, alpha, buffer, out, passes):
    """out = K_f y of the FEM (fem_filtered_jacobian_product)."""
    fem_filtered_jacobian_product(x, fem, y, out)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def spring_diagonal(x, fem, springs, unit, alpha, out):
    """The springs' diagonal of -K (spring_jacobian_diagonal)."""
    offsets, _, _, _, stiffness = springs
    spring_jacobian_diagonal(offsets, stiffness, unit, alpha, out)


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def fem_diagonal(x, fem, springs, unit, alpha, out):
    """The FEM's diagonal of -K_f (fem_jacobian_diagonal)."""
    fem_jacobian_diagonal(x, fem, out)
