"""Forces of the classic model: gravity on every point plus Hooke's law along every enabled
spring (SPEC section 2, step 1), shared by every integrator.

Positions and forces are structure-of-arrays, shape (3, N). The spring forces are computed
direction by direction into `spring_force` (6, 3, N + pad): contiguous loops the compiler
turns into SIMD code, split over the cores. Each point then gathers its forces in the order
the course code accumulates them (its own six springs in direction order, then the springs
of later points ending at it, by creating point), so the sums are bit-identical to a scalar
walk over the spring list.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .model import DIRECTION_DI, DIRECTION_DJ

CHUNKS = 16  # work items per pass; numba spreads them over the threads


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


@njit(cache=True, nogil=True, parallel=True)
def compute_spring_forces(x, offsets, exists, rest, stiffness, spring_force):
    """spring_force[d, :, p] = force of spring (d, p) on its creating point p (0 if none)."""
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for d in range(6):
            k = stiffness[d]
            off = offsets[d]
            fdx, fdy, fdz = spring_force[d, 0], spring_force[d, 1], spring_force[d, 2]
            if k == 0.0:
                fdx[lo:hi] = 0.0
                fdy[lo:hi] = 0.0
                fdz[lo:hi] = 0.0
                continue
            start = min(max(lo, -off), hi)
            fdx[lo:start] = 0.0
            fdy[lo:start] = 0.0
            fdz[lo:start] = 0.0
            for p in range(start, hi):
                q = p + off
                dx = x[0, q] - x[0, p]
                dy = x[1, q] - x[1, p]
                dz = x[2, q] - x[2, p]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                s = k * (length - rest[d, p])
                ok = exists[d, p] and length > 0.0  # zero length: direction undefined
                fdx[p] = (dx / length) * s if ok else 0.0
                fdy[p] = (dy / length) * s if ok else 0.0
                fdz[p] = (dz / length) * s if ok else 0.0


@njit(cache=True, nogil=True, inline="always")
def gathered_force(p, a, weight, spring_force, offsets, order):
    """Total force on point p along axis a: weight + own springs - springs ending at p."""
    total = weight
    for d in range(6):
        total += spring_force[d, a, p]
    for i in range(6):
        d = order[i]
        total -= spring_force[d, a, p - offsets[d]]
    return total


@njit(cache=True, nogil=True, parallel=True)
def spring_forces(x, offsets, order, exists, rest, stiffness, mass, gravity, spring_force, f):
    """f[:] = mass * gravity + the spring forces at positions x (3, N)."""
    compute_spring_forces(x, offsets, exists, rest, stiffness, spring_force)
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for a in range(3):
            weight = mass * gravity[a]
            for p in range(lo, hi):
                f[a, p] = gathered_force(p, a, weight, spring_force, offsets, order)
