"""Self-collision of the classic model (SPEC section 2, step 3).

Points are binned into boxes (floor(x/w), floor(y/h), floor(z/t)) once per step, before any
point moves; then, point by point in row-major order and in place, every other point of the
same box closer than 2 * thickness pushes the point to exactly 2 * thickness away, and the
point moves by the mean push divided by steps_per_frame. The box table is an open-addressing
hash with a generation stamp, so nothing is allocated or cleared per step; the members of a
box are kept in ascending point order (a counting sort), which fixes the summation order.
"""
from __future__ import annotations

import numpy as np
from numba import njit

_EMPTY_LIMIT = 4.0e18  # box coordinates beyond this (or NaN) are not binned


class SelfCollisionScratch:
    """Preallocated work arrays for `self_collide` (one per simulation)."""

    def __init__(self, n: int) -> None:
        cap = 16
        while cap < 2 * n + 16:
            cap <<= 1
        self.keys = np.zeros((cap, 3), dtype=np.int64)
        self.slot_bucket = np.zeros(cap, dtype=np.int64)
        self.slot_generation = np.zeros(cap, dtype=np.int64)
        self.generation = np.zeros(1, dtype=np.int64)
        self.bucket_of = np.zeros(n, dtype=np.int64)
        self.bucket_start = np.zeros(n + 1, dtype=np.int64)
        self.bucket_fill = np.zeros(n + 1, dtype=np.int64)
        self.members = np.zeros(n, dtype=np.int64)

    def as_tuple(self):
        return (self.keys, self.slot_bucket, self.slot_generation, self.generation,
                self.bucket_of, self.bucket_start, self.bucket_fill, self.members)


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


@njit(cache=True, nogil=True)
def self_collide(x, pinned, width, height, nw, nh, thickness, steps_per_frame, scratch):
    """Push apart points of x (3, N) closer than 2 * thickness, in place (Gauss-Seidel)."""
    keys, slot_bucket, slot_generation, generation, bucket_of, start, fill, members = scratch
    n = x.shape[1]
    w = (3.0 * width) / nw
    h = (3.0 * height) / nh
    t = max(w, h)
    threshold = 2.0 * thickness
    generation[0] += 1
    gen = generation[0]
    nbuckets = 0
    for p in range(n):
        qx = np.floor(x[0, p] / w)
        qy = np.floor(x[1, p] / h)
        qz = np.floor(x[2, p] / t)
        if not (abs(qx) < _EMPTY_LIMIT and abs(qy) < _EMPTY_LIMIT and abs(qz) < _EMPTY_LIMIT):
            bucket_of[p] = -1
            continue
        b, nbuckets = _slot(keys, slot_bucket, slot_generation, gen, nbuckets,
                            np.int64(qx), np.int64(qy), np.int64(qz))
        bucket_of[p] = b
    start[: nbuckets + 1] = 0
    for p in range(n):
        if bucket_of[p] >= 0:
            start[bucket_of[p] + 1] += 1
    for b in range(nbuckets):
        start[b + 1] += start[b]
    fill[:nbuckets] = start[:nbuckets]
    for p in range(n):
        b = bucket_of[p]
        if b >= 0:
            members[fill[b]] = p
            fill[b] += 1
    for p in range(n):
        b = bucket_of[p]
        if pinned[p] or b < 0:
            continue
        sx = sy = sz = 0.0
        count = 0
        px, py, pz = x[0, p], x[1, p], x[2, p]
        for m in range(start[b], start[b + 1]):
            c = members[m]
            if c == p:
                continue
            dx = px - x[0, c]
            dy = py - x[1, c]
            dz = pz - x[2, c]
            dist = np.sqrt(dx * dx + dy * dy + dz * dz)
            if dist < threshold and dist > 0.0:
                push = threshold - dist
                sx += (dx / dist) * push
                sy += (dy / dist) * push
                sz += (dz / dist) * push
                count += 1
        if count > 0:
            x[0, p] += (sx / count) / steps_per_frame
            x[1, p] += (sy / count) / steps_per_frame
            x[2, p] += (sz / count) / steps_per_frame
