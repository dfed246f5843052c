"""Provot's stretch limit (SPEC section 2, step 5): Gauss-Seidel over the spring list.

Walking every spring in order is a serial chain, so the walk visits only the springs that
can need a correction: a pre-pass (parallel on large cloths) marks, in a 6-bit mask per
point, the springs longer than (slightly less than) their limit; every correction then
marks the later springs that share a moved point, since their lengths changed. An unmarked
spring has the same endpoints as in the pre-pass, so skipping it is exactly what the full
walk would do. Where many springs are long (a fine grid whose neighbours self-collision
pushes apart: about a tenth of them shortened every step), the marking costs more than it
skips, and the walk visits every spring in order, as the course does (DENSE_SHARE).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba.core import types

from clothjit import KernelPointer, njit, prange

from .forces import CHUNKS, PARALLEL_POINTS, _chunk

STRETCH_LIMIT = 1.1  # a spring may reach 110 % of its rest length
# after a walk that shortened at least one in DENSE_SHARE of the springs, the next visits
# every spring, with no pre-pass and no marking: one thread, a 100x100 selfCollision
# (a tenth shortened) steps 5-7 % faster so, a hanging 200x200 cloth (a twentieth) 20 %
# slower
DENSE_SHARE = 12


def stretch_limits(rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(limit, limit_sq_lo) for `limit_stretch` from the rest lengths (6, N): limit_sq_lo is
    limit**2 lowered by 1e-9 relative, a safe filter before the exact test."""
    limit = STRETCH_LIMIT * rest
    return limit, limit * limit * (1.0 - 1e-9)


def existence_bits(exists: np.ndarray) -> np.ndarray:
    """(N + pad,) uint8: bit d set when spring (d, p) exists (pad zero)."""
    n = exists.shape[1]
    bits = np.zeros(n + 2 * n + 2, dtype=np.uint8)  # pad covers p - offset for any offset
    for d in range(6):
        bits[:n] |= exists[d].astype(np.uint8) << d
    return bits


class CandidateMask(NamedTuple):
    """Scratch of `limit_stretch`, and the pointers of its pre-pass: the loop and the two
    passes it calls (linked into a parallel loop, the passes were compiled again in each
    copy numba makes of the loop's body, as forces.SpringKernels)."""

    mask: np.ndarray  # (N + pad,) uint8: bit d, spring (d, p) is to be visited
    long: np.ndarray  # (6, N) bool: spring (d, p) may be longer than its limit
    flag: KernelPointer  # _flag_long
    pack: KernelPointer  # _pack_mask
    walk: np.ndarray  # (1,) int64: the next walk visits every spring (1) or the marked (0)
    # the pre-pass (_mark_serially or _mark_in_chunks, by the cloth's size:
    # forces.PARALLEL_POINTS; limit_stretch compiles in 0.8-1.0 s without the parallel loop
    # linked, 1.6-1.9 s with it); None inside it
    mark: KernelPointer | None = None


def candidate_mask(n: int, present: bool = True) -> CandidateMask:
    """Scratch of `limit_stretch` for n points, its passes absent unless `present`."""
    mask, long = np.zeros(3 * n + 2, dtype=np.uint8), np.zeros((6, n), dtype=np.bool_)
    index, field = types.int64, types.float64[:, ::1]
    flag = KernelPointer(_flag_long, (field, index, types.float64[::1], types.bool_[::1],
                                      index, index), present=present)
    pack = KernelPointer(_pack_mask, (long, types.uint8[::1], mask, index, index),
                         present=present)
    scratch = CandidateMask(mask, long, flag, pack, np.zeros(1, dtype=np.int64))
    loop = _mark_in_chunks if n >= PARALLEL_POINTS else _mark_serially
    mark = KernelPointer(loop, (field, types.int64[::1], types.uint8[::1], field, scratch),
                         present=present)
    return scratch._replace(mark=mark)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _flag_long(x, off, limit_sq_lo_d, long_d, lo, hi):
    """long_d[p] = spring (d, p) may be longer than its limit, for p in [lo, hi)."""
    start = min(max(lo, -off), hi)
    long_d[lo:start] = False
    ax, ay, az = x[0, start:hi], x[1, start:hi], x[2, start:hi]
    bx, by, bz = x[0, start + off:hi + off], x[1, start + off:hi + off], x[2, start + off:hi + off]
    lim, out = limit_sq_lo_d[start:hi], long_d[start:hi]
    for i in range(hi - start):  # sliced, counter from 0: vectorises (see forces.py)
        dx = bx[i] - ax[i]
        dy = by[i] - ay[i]
        dz = bz[i] - az[i]
        out[i] = dx * dx + dy * dy + dz * dz > lim[i]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _pack_mask(long, exist_bits, mask, lo, hi):
    l0, l1, l2, l3, l4, l5 = (long[0, lo:hi], long[1, lo:hi], long[2, lo:hi], long[3, lo:hi],
                              long[4, lo:hi], long[5, lo:hi])
    bits, out = exist_bits[lo:hi], mask[lo:hi]
    for i in range(hi - lo):
        out[i] = (np.uint8(l0[i]) | (np.uint8(l1[i]) << 1) | (np.uint8(l2[i]) << 2)
                  | (np.uint8(l3[i]) << 3) | (np.uint8(l4[i]) << 4)
                  | (np.uint8(l5[i]) << 5)) & bits[i]


@njit(cache=True, nogil=True, no_cpython_wrapper=True, pointer=True)
def _mark_serially(x, offsets, exist_bits, limit_sq_lo, scratch):
    """The pre-pass over every point in one call of each pass."""
    mask, long, flag, pack = scratch[:4]
    n = x.shape[1]
    for d in range(6):
        flag(x, offsets[d], limit_sq_lo[d], long[d], 0, n)
    pack(long, exist_bits, mask, 0, n)


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True, pointer=True)
def _mark_in_chunks(x, offsets, exist_bits, limit_sq_lo, scratch):
    """The pre-pass over chunks of points in parallel."""
    mask, long, flag, pack = scratch[:4]
    n = x.shape[1]
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for d in range(6):
            flag(x, offsets[d], limit_sq_lo[d], long[d], lo, hi)
        pack(long, exist_bits, mask, lo, hi)


@njit(cache=True, nogil=True, inline="always")
def _mark_after(r, p, d, offsets, exist_bits, mask):
    """Mark the springs that contain point r and come after spring (d, p) in the list."""
    if r == p:
        higher = np.uint8(0x3F) & ~np.uint8((2 << d) - 1)
        mask[p] |= exist_bits[p] & higher
    for e in range(6):
        s = r - offsets[e]  # the point whose spring e ends at r
        if s > p or (s == p and e > d):
            mask[s] |= exist_bits[s] & (np.uint8(1) << np.uint8(e))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def shorten(x, p, q, dx, dy, dz, length, lim, pa, pb):
    """Shorten the spring p-q (q - p = (dx, dy, dz), of `length` > lim) to lim along its
    own direction: half to each end, all to the free end if the other (pa, pb) is pinned.
    Both ends pinned: the caller does not call."""
    s = length - lim
    cx = (dx / length) * s
    cy = (dy / length) * s
    cz = (dz / length) * s
    if not pa and not pb:
        x[0, p] += 0.5 * cx
        x[1, p] += 0.5 * cy
        x[2, p] += 0.5 * cz
        x[0, q] -= 0.5 * cx
        x[1, q] -= 0.5 * cy
        x[2, q] -= 0.5 * cz
    elif pa:
        x[0, q] -= cx
        x[1, q] -= cy
        x[2, q] -= cz
    else:
        x[0, p] += cx
        x[1, p] += cy
        x[2, p] += cz


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _limit_spring(x, p, d, offsets, limit, limit_sq_lo, pinned):
    """Shorten spring (d, p) to its limit if longer (shorten). Returns 0 if it was not
    shortened, else 1 plus 2 if its end p is pinned plus 4 if its other end is."""
    q = p + offsets[d]
    dx = x[0, q] - x[0, p]
    dy = x[1, q] - x[1, p]
    dz = x[2, q] - x[2, p]
    length_sq = dx * dx + dy * dy + dz * dz
    if length_sq <= limit_sq_lo[d, p]:
        return 0
    length = np.sqrt(length_sq)
    lim = limit[d, p]
    pa = pinned[p] != 0
    pb = pinned[q] != 0
    if not length > lim or (pa and pb):
        return 0
    shorten(x, p, q, dx, dy, dz, length, lim, pa, pb)
    return 1 + 2 * pa + 4 * pb


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True,
      pointer=True)
def limit_stretch(x, springs, exist_bits, limit, limit_sq_lo, pinned, scratch):
    """Shorten every spring longer than `limit` (= 1.1 rest) to `limit`, in list order.

    Half the correction goes to each end, all of it to the free end if one end is pinned,
    none if both are. `springs` is System.springs (the grid's: offsets first), `scratch`
    comes from candidate_mask. The walk visits the marked springs (see above), or every
    spring after a walk that shortened many (DENSE_SHARE): the same corrections either
    way. Without numba's reference counts (`_nrt=False`: nothing here allocates): numba
    counted the arrays of every inlined `_mark_after`, atomic updates that made the walk
    2.6x as long.
    """
    offsets = springs[0]
    n = x.shape[1]
    shortened = 0
    if scratch.walk[0]:
        for p in range(n):
            bits = exist_bits[p]
            for d in range(6):
                if (bits >> d) & 1:
                    shortened += _limit_spring(x, p, d, offsets, limit, limit_sq_lo,
                                               pinned) != 0
    else:
        scratch.mark(x, offsets, exist_bits, limit_sq_lo, CandidateMask(*scratch[:-1], None))
        mask = scratch.mask
        for p in range(n):
            if mask[p] == 0:
                continue
            for d in range(6):
                if not (mask[p] >> d) & 1:
                    continue
                done = _limit_spring(x, p, d, offsets, limit, limit_sq_lo, pinned)
                if done == 0:
                    continue
                shortened += 1
                if not done & 2:
                    _mark_after(p, p, d, offsets, exist_bits, mask)
                if not done & 4:
                    _mark_after(p + offsets[d], p, d, offsets, exist_bits, mask)
    scratch.walk[0] = DENSE_SHARE * shortened >= 6 * n
