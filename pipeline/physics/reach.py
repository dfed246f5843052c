"""Which passes can act: skipping self-collision and colliders where nothing can touch.

`fidelity: auto` (pipeline.fidelity.controller) arms a `Reach` at a frame boundary: from the positions
then (the anchor) and a motion budget it finds
  * every static collider no point can reach while no point moves more than `budget`
    from the anchor (clearance > budget), and switches it off;
  * every pair of cloth points that could come within the self-collision distance 2 t
    while no point moves more than `self_budget` relative to the cloth's mean motion (pairs
    closer than 2 t + 2 self_budget, from a k-d tree), and switches the self-collision pass
    off until one of them does come that close.
Every step, before the passes, `reach_check` verifies these premises on the positions the
passes would see; the first step that breaks one switches the passes back on for the rest
of the arming. Until then, each skipped pass would have changed nothing (a collider acts
only on a point inside it or crossing it; the self-collision pass only on a pair closer
than 2 t), so a skipped run is bit-identical to running every pass: tested.
Keyframed colliders are never switched off. `fidelity: exact` leaves the Reach disarmed
(every pass on, one branch per step).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from clothjit import njit
from pipeline.scene import Scene

from .colliders import box, mesh, plane, sphere

#: squared-distance margin of the pair test over the pass's own threshold (its rounding)
PAIR_MARGIN = 1e-7


class Reach(NamedTuple):
    """Mutable arrays read by the kernels (a field of system.System)."""

    anchor: np.ndarray  # (3, N) positions when armed
    mean_anchor: np.ndarray  # (3,) their mean
    budget_sq: np.ndarray  # (2,) allowed squared motion: [absolute, relative to the mean]
    armed: np.ndarray  # (2,) uint8: [colliders armed, self-collision armed]
    self_on: np.ndarray  # (1,) uint8: the self-collision pass runs
    pairs: np.ndarray  # (K, 2) int64 pairs that could come within 2 t
    counts: np.ndarray  # (3,) int64: steps seen, self-collision passes run, steps with a
    #                     collider skipped


def new_reach(n: int) -> Reach:
    """A disarmed Reach for n points: every pass runs."""
    return Reach(anchor=np.zeros((3, n)), mean_anchor=np.zeros(3), budget_sq=np.zeros(2),
                 armed=np.zeros(2, dtype=np.uint8), self_on=np.ones(1, dtype=np.uint8),
                 pairs=np.zeros((0, 2), dtype=np.int64), counts=np.zeros(3, dtype=np.int64))


@njit(cache=True, nogil=True, inline="always")
def _total(x, a):
    """The sum of x[a, :] in index order (np.sum's, in a loop: a kernel using numba's np.sum
    makes every process that loads it from the cache import numba.np.arraymath, whose BLAS
    check imports scipy: 0.27 s of a warm run)."""
    total = 0.0
    for p in range(x.shape[1]):
        total += x[a, p]
    return total


@njit(cache=True, nogil=True, error_model="numpy", pointer=True)
def reach_check(x, reach, active, thickness):
    """Before a step's passes: re-enable what the positions x (3, N) may now reach.
    `active` (C,) uint8 is the collider table's switch per collider."""
    r = reach
    r.counts[0] += 1
    if r.armed[0] or r.armed[1]:
        n = x.shape[1]
        # the mean motion per axis, as scalars: an array here (np.zeros) made this the
        # first kernel of a first run to compile numba's array allocation (about 0.5 s)
        m0 = _total(x, 0) / n - r.mean_anchor[0]
        m1 = _total(x, 1) / n - r.mean_anchor[1]
        m2 = _total(x, 2) / n - r.mean_anchor[2]
        far = 0.0
        drift = 0.0
        for p in range(n):
            d0 = x[0, p] - r.anchor[0, p]
            d1 = x[1, p] - r.anchor[1, p]
            d2 = x[2, p] - r.anchor[2, p]
            e0, e1, e2 = d0 - m0, d1 - m1, d2 - m2
            far = max(far, d0 * d0 + d1 * d1 + d2 * d2)
            drift = max(drift, e0 * e0 + e1 * e1 + e2 * e2)
        if r.armed[0] and not far <= r.budget_sq[0]:  # also for NaN
            r.armed[0] = 0
            active[:] = 1
        if r.armed[0]:
            r.counts[2] += 1
        if r.armed[1] and not drift <= r.budget_sq[1]:
            r.armed[1] = 0
            r.self_on[0] = 1
    if r.self_on[0] == 0:
        threshold = 2.0 * thickness
        limit = threshold * threshold * (1.0 + PAIR_MARGIN)
        for k in range(r.pairs.shape[0]):
            p, q = r.pairs[k, 0], r.pairs[k, 1]
            d2 = 0.0
            for a in range(3):
                d = x[a, p] - x[a, q]
                d2 += d * d
            if not d2 >= limit:
                r.self_on[0] = 1
                r.armed[1] = 0  # on for the rest of the arming: nothing left to watch
                break


def arm(reach: Reach, active: np.ndarray, x: np.ndarray, scene: Scene, thickness: float,
        budget: float, self_budget: float, self_collision: bool) -> Reach:
    """Arm at positions x (3, N): returns the Reach to use (its pair list may be new);
    `active` (the collider switches) is set in place."""
    reach.anchor[:] = x
    reach.mean_anchor[:] = x.mean(axis=1)
    reach.budget_sq[:] = (budget * budget, self_budget * self_budget)
    points = x.T
    for c, obj in enumerate(scene.colliders):
        active[c] = 1 if obj.keyframes else int(not clearance(obj, points) > budget)
    reach.armed[0] = not np.all(active)  # a premise to watch only where a pass is skipped
    reach.armed[1] = self_collision
    pairs = reach.pairs[:0]
    if self_collision:
        from scipy.spatial import cKDTree

        radius = 2.0 * thickness + 2.0 * self_budget
        pairs = cKDTree(points).query_pairs(radius * (1.0 + 1e-9), output_type="ndarray")
        pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
    reach = reach._replace(pairs=pairs)
    reach.self_on[0] = 0 if self_collision else 1
    if self_collision:
        reach_check(x, reach, active, thickness)  # a pair already within 2 t: pass on
        reach.counts[0] -= 1
        reach.armed[1] = reach.self_on[0] == 0
    return reach



def disarm(reach: Reach, active: np.ndarray) -> None:
    """Every pass on (fidelity exact)."""
    reach.armed[:] = 0
    reach.self_on[0] = 1
    active[:] = 1


def clearance(obj, points: np.ndarray) -> float:
    """A lower bound of the distance from `points` (N, 3) to where static collider `obj`
    can act (inf when it can act nowhere near them; 0 when it may act now)."""
    kind = type(obj)
    if kind is sphere.SCENE_TYPE:
        return float(np.min(np.linalg.norm(points - np.asarray(obj.origin), axis=1))
                     - obj.radius)
    if kind is plane.SCENE_TYPE:  # acts on a point that changes side
        n = np.asarray(obj.normal, dtype=np.float64)
        s = (points - np.asarray(obj.point)) @ (n / np.linalg.norm(n))
        if np.all(s > 0.0) or np.all(s < 0.0):
            return float(np.min(np.abs(s)))
        return 0.0
    if kind is box.SCENE_TYPE:  # acts inside the box
        from .colliders import euler_matrix

        q = (points - np.asarray(obj.center)) @ euler_matrix(obj.rotation)
        outside = np.maximum(np.abs(q) - np.asarray(obj.half_extents), 0.0)
        return float(np.min(np.linalg.norm(outside, axis=1)))
    if kind is mesh.SCENE_TYPE:  # acts inside its distance grid's box only
        low, high = mesh.grid_bounds(obj)
        outside = np.maximum(np.maximum(low - points, points - high), 0.0)
        return float(np.min(np.linalg.norm(outside, axis=1)))
    return 0.0  # an unknown kind: never skipped


def budget_for(displacement: float, thickness: float) -> tuple[float, float]:
    """(collider budget, self-collision budget) from the largest point motion of the last
    frame: room for a few frames of that motion, at least a fraction of the thickness."""
    move = 3.0 * displacement if math.isfinite(displacement) else 0.0
    return max(move, 0.5 * thickness), max(min(move, 2.0 * thickness), 0.1 * thickness)
