"""Self-collision of the classic model (SPEC section 2, step 3).

Points are binned into boxes (floor(x/w), floor(y/h), floor(z/t)) once per step, before any
point moves; then, point by point in row-major order and in place, every other point of the
same box closer than 2 * thickness pushes the point to exactly 2 * thickness away, and the
point moves by the mean push divided by steps_per_frame.

How it is made fast without changing a bit:
- boxes are numbered by a counting sort over the dense grid of the boxes the cloth spans
  (an open-addressing hash when that grid would be large, e.g. a point flew far away), so
  nothing is allocated per step; members of a box stay in ascending point order, which fixes
  the summation order, with a copy of their positions in that order (updated as points move).
  The grid's extent comes from integer box coordinates (a vectorised loop; a float min/max
  is a serial chain);
- a point's candidates are then one contiguous run: one branch-free loop takes their squared
  distances and lists, in slot order, those below a slightly raised threshold (in a pile-up
  about a third of a box's members, at random, which a branch per member mispredicts); only
  those take the exact test on the square root, as the course code computes it. Indices are
  unsigned (no wraparound tests) and nothing is reference-counted in the loops;
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
        self.box_index = np.zeros((3, n), dtype=np.int64)  # box as integers (when finite)
        self.dist_sq = np.zeros(n, dtype=np.float64)
        self.near_slot = np.zeros(n, dtype=np.uint64)

    def as_tuple(self):
        return (self.keys, self.slot_bucket, self.slot_generation, self.generation, self.box,
                self.bucket_of, self.bucket_start, self.bucket_fill, self.members,
                self.sorted_x, self.box_index, self.dist_sq, self.near_slot)


@njit(cache=True, nogil=True, inline="always")
def cell_hash(ix, iy, iz, mask):
    """The bucket (0..mask, mask + 1 a power of 2) of the integer cell (ix, iy, iz): the
    spatial hash of self-collision's boxes, robust contact's and VBD's pair searches."""
    h = np.uint64(ix) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(iy) * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= np.uint64(iz) * np.uint64(0x165667B19E3779F9)
    h ^= h >> np.uint64(29)
    return np.int64(h & np.uint64(mask))


@njit(cache=True, nogil=True, inline="always")
def _slot(keys, slot_bucket, slot_generation, gen, nbuckets, bx, by, bz):
    mask = keys.shape[0] - 1
    s = cell_hash(bx, by, bz, mask)
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
def _axis_boxes(xa, size, box, index):
    """box[p] = floor(xa[p] / size), index[p] the same as an integer; returns (lowest index,
    highest index, every box finite and within _EMPTY_LIMIT). One vectorised loop: integer
    extremes have no serial dependence (float min/max would, NaN ordering)."""
    low = np.int64(2 ** 62)
    high = -low
    good = True
    for p in range(np.uint64(xa.shape[0])):
        v = np.floor(xa[p] / size)
        box[p] = v
        good &= abs(v) < _EMPTY_LIMIT
        q = np.int64(v)  # meaningless unless good
        index[p] = q
        low = min(low, q)
        high = max(high, q)
    return low, high, good


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)
def _number_boxes(x, w, h, t, box, index, bucket_of, cells):
    """box[:, p] = floor(x[:, p] / (w, h, t)); bucket_of[p] = index of p's box in the dense
    grid of boxes the points span. Returns the grid's cell count, or -1 (bucket_of not
    written) when it exceeds `cells` or a box coordinate is not finite (or beyond
    _EMPTY_LIMIT)."""
    low_x, high_x, good_x = _axis_boxes(x[0], w, box[0], index[0])
    low_y, high_y, good_y = _axis_boxes(x[1], h, box[1], index[1])
    low_z, high_z, good_z = _axis_boxes(x[2], t, box[2], index[2])
    if not (good_x and good_y and good_z):
        return -1
    span_x, span_y, span_z = high_x - low_x + 1, high_y - low_y + 1, high_z - low_z + 1
    if not float(span_x) * float(span_y) * float(span_z) <= cells:
        return -1
    b0, b1, b2 = index[0], index[1], index[2]
    for p in range(np.uint64(x.shape[1])):
        bucket_of[p] = ((b0[p] - low_x) * span_y + (b1[p] - low_y)) * span_z + (b2[p] - low_z)
    return span_x * span_y * span_z


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


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True)
def _bin(x, w, h, t, scratch):
    """Assign boxes, sort members by box (ascending point order inside), copy positions;
    returns how many points were binned (members[:count])."""
    (keys, slot_bucket, slot_generation, generation, box, bucket_of, start, fill, members,
     xs, index, _, _) = scratch
    n = x.shape[1]
    if n == 0:
        return 0
    nbuckets = _number_boxes(x, w, h, t, box, index, bucket_of, start.shape[0] - 2)
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
            xs[0, m] = x[0, p]
            xs[1, m] = x[1, p]
            xs[2, m] = x[2, p]
    return start[nbuckets]


@njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, pointer=True)
def _push_members(x, pinned, thickness, steps_per_frame, scratch, lo, hi):
    """The pushes of the points members[lo:hi], whole boxes, in that order. A point reads
    and moves only the members of its own box, so boxes are independent: this order and
    any split into runs of whole boxes give the course's row-major order's bits (within a
    box the members are in ascending point order). A box's slots of dist_sq and near_slot
    are its scratch. Indices are uint64 (no wraparound tests)."""
    bucket_of, start, members, xs, dist_sq, near_slot = (
        scratch[5], scratch[6], scratch[8], scratch[9], scratch[11], scratch[12])
    ax, ay, az = xs[0], xs[1], xs[2]
    threshold = 2.0 * thickness
    threshold_sq_hi = threshold * threshold * (1.0 + 1e-9)
    one = np.uint64(1)
    for jj in range(lo, hi):
        j = np.uint64(jj)
        p = np.uint64(members[j])
        if pinned[p]:
            continue
        b = np.uint64(bucket_of[p])
        first, last = np.uint64(start[b]), np.uint64(start[b + one])
        px, py, pz = ax[j], ay[j], az[j]  # x[:, p]
        # the members other than p that pass a cheap reject on the squared distance, in
        # slot order, to near_slot[first:k]; branch-free (every member is written, k steps
        # only on a near one): in a pile-up about a third of a box's members are near, at
        # random, which a branch mispredicts
        k = first
        for m in range(first, last):
            dx = px - ax[m]
            dy = py - ay[m]
            dz = pz - az[m]
            d = dx * dx + dy * dy + dz * dz
            dist_sq[m] = d
            near_slot[k] = m
            k += np.uint64(d < threshold_sq_hi) & np.uint64(m != j)
        sx = sy = sz = 0.0
        hits = 0
        for i in range(first, k):  # the exact test, on the square root as the course has it
            m = near_slot[i]
            dist = np.sqrt(dist_sq[m])
            if dist < threshold and dist > 0.0:
                push = threshold - dist
                sx += ((px - ax[m]) / dist) * push
                sy += ((py - ay[m]) / dist) * push
                sz += ((pz - az[m]) / dist) * push
                hits += 1
        if hits > 0:
            x[0, p] += (sx / hits) / steps_per_frame
            x[1, p] += (sy / hits) / steps_per_frame
            x[2, p] += (sz / hits) / steps_per_frame
            ax[j] = x[0, p]
            ay[j] = x[1, p]
            az[j] = x[2, p]


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
