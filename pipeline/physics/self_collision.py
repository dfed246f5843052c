"""Self-collision of the classic model (SPEC section 2, step 3).

Points are binned into boxes (floor(x/w), floor(y/h), floor(z/t)) once per step, before any
point moves; then, point by point in row-major order and in place, every other point of the
same box closer than 2 * thickness pushes the point to exactly 2 * thickness away, and the
point moves by the mean push divided by steps_per_frame.

How it is made fast without changing a bit:
- boxes are numbered by a counting sort over the dense grid of the boxes the cloth spans
  (an open-addressing hash when that grid would be large, e.g. a point flew far away), so
  nothing is allocated per step; members of a box stay in ascending point order, which fixes
  the summation order, with a copy of their positions in that order (updated as points move);
- a point's candidates are then one contiguous run: their squared distances come from a
  vectorised loop, and only those below a slightly raised threshold take the exact test on
  the square root, as the course code computes it.
- a point reads and moves only its own box's members, so the boxes are pushed in member
  order (box by box), and from PARALLEL_POINTS points in runs of whole boxes on the threads:
  the same bits as the course's row-major order on any thread count.
"""
from __future__ import annotations

import numpy as np

from clothjit import njit, prange

from .forces import CHUNKS

_EMPTY_LIMIT = 4.0e18  # box coordinates beyond this (or NaN) are not binned
# From this many points on, the boxes are pushed on the threads (self_collide_in_chunks)
PARALLEL_POINTS = 1000
DENSE_CELLS_PER_POINT = 8  # box grids up to this many cells per point use the counting sort


class SelfCollisionScratch:
    """Preallocated work arrays for `self_collide` (one per simulation; n = 0 when off)."""

    def __init__(self, n: int) -> None:
        cap = 16
        while cap < 2 * n + 16:
            cap <<= 1
        self.keys = np.zeros((cap, 3), dtype=np.int64)
        self.slot_bucket = np.zeros(cap, dtype=np.int64)
        self.slot_generation = np.zeros(cap, dtype=np.int64)
        self.generation = np.zeros(1, dtype=np.int64)
        self.box = np.zeros((3, n), dtype=np.float64)  # floor(x / box size) per axis
        self.bucket_of = np.zeros(n, dtype=np.int64)
        self.bucket_start = np.zeros(DENSE_CELLS_PER_POINT * n + 2, dtype=np.int64)
        self.bucket_fill = np.zeros(DENSE_CELLS_PER_POINT * n + 2, dtype=np.int64)
        self.members = np.zeros(n, dtype=np.int64)
        self.sorted_x = np.zeros((3, n), dtype=np.float64)  # positions in member order
        self.slot_of = np.zeros(n, dtype=np.int64)  # a point's index in member order
        self.dist_sq = np.zeros(n, dtype=np.float64)

    def as_tuple(self):
        return (self.keys, self.slot_bucket, self.slot_generation, self.generation, self.box,
                self.bucket_of, self.bucket_start, self.bucket_fill, self.members,
                self.sorted_x, self.slot_of, self.dist_sq)


@njit(cache=True, nogil=True, inline="always")
def _slot(keys, slot_bucket, slot_generation, gen, nbuckets, bx, by, bz):
    mask = keys.shape[0] - 1
    h = np.uint64(bx) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(by) * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= np.uint64(bz) * np.uint64(0x165667B19E3779F9)
    h ^= h >> np.uint64(29)
    s = np.int64(h & np.uint64(mask))
    while True:
        if slot_generation[s] != gen:
            slot_generation[s] = gen
            keys[s, 0] = bx
            keys[s, 1] = by
            keys[s, 2] = bz
            slot_bucket[s] = nbuckets
            return nbuckets, nbuckets + 1
        if keys[s, 0] == bx and keys[s, 1] == by and keys[s, 2] == bz:
            return slot_bucket[s], nbuckets
        s = (s + 1) & mask


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _box_coordinates(x, w, h, t, box):
    """box[:, p] = floor(x[:, p] / (w, h, t)): a vectorisable loop."""
    for a, size in ((0, w), (1, h), (2, t)):
        xa, ba = x[a], box[a]
        for p in range(xa.shape[0]):
            ba[p] = np.floor(xa[p] / size)


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _range_of(values):
    """(lowest value, number of integers from lowest to highest) of integral floats."""
    low = high = values[0]
    for v in values:
        low = min(low, v)
        high = max(high, v)
    return low, high - low + 1.0


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _number_boxes(box, bucket_of, cells):
    """bucket_of[p] = index of p's box in the dense grid of boxes the points span; returns the
    grid's cell count, or -1 (nothing written) when it exceeds `cells` or a box coordinate is
    not finite."""
    n = box.shape[1]
    low_x, span_x = _range_of(box[0])
    low_y, span_y = _range_of(box[1])
    low_z, span_z = _range_of(box[2])
    if not span_x * span_y * span_z <= cells:  # also false for NaN and infinities
        return -1
    sy, sz = np.int64(span_y), np.int64(span_z)
    b0, b1, b2 = box[0], box[1], box[2]
    for p in range(n):
        bucket_of[p] = ((np.int64(b0[p] - low_x) * sy + np.int64(b1[p] - low_y)) * sz
                        + np.int64(b2[p] - low_z))
    return np.int64(span_x) * sy * sz


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _hash_boxes(box, bucket_of, keys, slot_bucket, slot_generation, generation):
    """bucket_of[p] = a number per distinct box (-1 for non-finite); returns the count."""
    generation[0] += 1
    gen = generation[0]
    nbuckets = 0
    for p in range(box.shape[1]):
        qx, qy, qz = box[0, p], box[1, p], box[2, p]
        if not (abs(qx) < _EMPTY_LIMIT and abs(qy) < _EMPTY_LIMIT and abs(qz) < _EMPTY_LIMIT):
            bucket_of[p] = -1
            continue
        b, nbuckets = _slot(keys, slot_bucket, slot_generation, gen, nbuckets,
                            np.int64(qx), np.int64(qy), np.int64(qz))
        bucket_of[p] = b
    return nbuckets


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _bin(x, w, h, t, scratch):
    """Assign boxes, sort members by box (ascending point order inside), copy positions;
    returns how many points were binned (members[:count])."""
    (keys, slot_bucket, slot_generation, generation, box, bucket_of, start, fill, members,
     xs, slot_of, _) = scratch
    n = x.shape[1]
    _box_coordinates(x, w, h, t, box)
    nbuckets = _number_boxes(box, bucket_of, start.shape[0] - 2)
    if nbuckets < 0:
        nbuckets = _hash_boxes(box, bucket_of, keys, slot_bucket, slot_generation, generation)
    start[: nbuckets + 1] = 0
    for p in range(n):
        if bucket_of[p] >= 0:
            start[bucket_of[p] + 1] += 1
    for b in range(nbuckets):
        start[b + 1] += start[b]
    for b in range(nbuckets):  # not a slice copy: see rk4.advance
        fill[b] = start[b]
    for p in range(n):
        b = bucket_of[p]
        if b >= 0:
            m = fill[b]
            fill[b] += 1
            members[m] = p
            slot_of[p] = m
            xs[0, m] = x[0, p]
            xs[1, m] = x[1, p]
            xs[2, m] = x[2, p]
    return start[nbuckets]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _squared_distances(px, py, pz, xs, lo, hi, out):
    """out[i] = |p - xs[:, lo + i]|^2: a vectorisable loop over one box's members."""
    ax, ay, az = xs[0, lo:hi], xs[1, lo:hi], xs[2, lo:hi]
    for i in range(hi - lo):
        dx = px - ax[i]
        dy = py - ay[i]
        dz = pz - az[i]
        out[i] = dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _push_members(x, pinned, thickness, steps_per_frame, scratch, lo, hi):
    """The pushes of the points members[lo:hi], whole boxes, in that order. A point reads
    and moves only the members of its own box, so boxes are independent: this order and
    any split into runs of whole boxes give the course's row-major order's bits (within a
    box the members are in ascending point order). A box's slots of dist_sq are its
    scratch."""
    bucket_of, start, members, xs, slot_of, dist_sq = (
        scratch[5], scratch[6], scratch[8], scratch[9], scratch[10], scratch[11])
    threshold = 2.0 * thickness
    threshold_sq_hi = threshold * threshold * (1.0 + 1e-9)
    for j in range(lo, hi):
        p = members[j]
        if pinned[p]:
            continue
        b = bucket_of[p]
        first, last = start[b], start[b + 1]
        px, py, pz = x[0, p], x[1, p], x[2, p]
        near = dist_sq[first:last]
        _squared_distances(px, py, pz, xs, first, last, near)
        sx = sy = sz = 0.0
        hits = 0
        for i in range(last - first):
            if not near[i] < threshold_sq_hi:  # cheap reject; the exact test is below
                continue
            m = first + i
            if members[m] == p:
                continue
            dist = np.sqrt(near[i])
            if dist < threshold and dist > 0.0:
                push = threshold - dist
                sx += ((px - xs[0, m]) / dist) * push
                sy += ((py - xs[1, m]) / dist) * push
                sz += ((pz - xs[2, m]) / dist) * push
                hits += 1
        if hits > 0:
            x[0, p] += (sx / hits) / steps_per_frame
            x[1, p] += (sy / hits) / steps_per_frame
            x[2, p] += (sz / hits) / steps_per_frame
            m = slot_of[p]
            xs[0, m] = x[0, p]
            xs[1, m] = x[1, p]
            xs[2, m] = x[2, p]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def self_collide(x, pinned, box_w, box_h, thickness, steps_per_frame, scratch, push):
    """Push apart points of x (3, N) closer than 2 * thickness, in place (Gauss-Seidel);
    the boxes are box_w x box_h x max(box_w, box_h) (collision_box); `push` the
    _push_members pointer."""
    binned = _bin(x, box_w, box_h, max(box_w, box_h), scratch)
    push(x, pinned, thickness, steps_per_frame, scratch, 0, binned)


@njit(cache=True, nogil=True, parallel=True, no_cpython_wrapper=True, pointer=True)
def self_collide_in_chunks(x, pinned, box_w, box_h, thickness, steps_per_frame, scratch,
                           push):
    """self_collide with the boxes in CHUNKS runs of about equal member counts on the
    threads (the same bits: see _push_members)."""
    bucket_of, start, members = scratch[5], scratch[6], scratch[8]
    binned = _bin(x, box_w, box_h, max(box_w, box_h), scratch)
    if binned == 0:
        return
    for c in prange(CHUNKS):
        # each run from the start of the box holding its share's first member
        lo = start[bucket_of[members[(c * binned) // CHUNKS]]] if c > 0 else 0
        hi = (start[bucket_of[members[((c + 1) * binned) // CHUNKS]]] if c < CHUNKS - 1
              else binned)
        push(x, pinned, thickness, steps_per_frame, scratch, lo, hi)
