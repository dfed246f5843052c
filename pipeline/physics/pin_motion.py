"""Keyframed pins of a mesh cloth (`cloth.pinned` selections with `keyframes`): a hand that
holds the cloth and moves. The points a selection catches follow its keyframed pose (the
colliders' keyframe format), turning about their centroid in the file: a point p0 is at
R(t) (p0 - c) + c + T(t). A point that several keyframed selections catch follows the last.

Each step sets the pins to their pose at the end of the step before the other position
passes (so Provot and the colliders see where the hand is), and their last positions to
where they were, so the velocity the integrators estimate is the hand's.
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from clothjit import njit

from .colliders import POSE_WIDTH, max_surface_speed, pose_at


class PinMotion(NamedTuple):
    keys: np.ndarray  # (S, K, 7): time, translation (3), rotation in radians (3)
    key_count: np.ndarray  # (S,) int64 keys of each selection
    point: np.ndarray  # (P,) int64 the moving pins
    selection: np.ndarray  # (P,) int64 the selection each follows
    rest: np.ndarray  # (3, P) their positions in the file (placed)
    pivot: np.ndarray  # (S, 3) each selection's centroid in the file
    pose: np.ndarray  # (S, POSE_WIDTH) scratch


def pin_motion(points: np.ndarray, moving: list[tuple[np.ndarray, tuple]]) -> PinMotion | None:
    """The PinMotion of `moving`, (mask (N,) of the points a selection catches, its
    keyframes) pairs in scene order, for a cloth at rest at `points` (N, 3); None if empty."""
    if not moving:
        return None
    owner = np.full(len(points), -1, dtype=np.int64)
    width = max(len(keys) for _, keys in moving)
    keys = np.zeros((len(moving), width, 7))
    pivot = np.zeros((len(moving), 3))
    for s, (mask, keyframes) in enumerate(moving):
        owner[mask] = s
        pivot[s] = points[mask].mean(axis=0)
        keys[s, :len(keyframes)] = [(k.time, *k.translation, *np.radians(k.rotation))
                                    for k in keyframes]
    point = np.nonzero(owner >= 0)[0]
    return PinMotion(keys, np.array([len(k) for _, k in moving], dtype=np.int64), point,
                     owner[point], np.ascontiguousarray(points[point].T), pivot,
                     np.zeros((len(moving), POSE_WIDTH)))


def max_pin_speed(motion: PinMotion | None, moving: list[tuple[np.ndarray, tuple]],
                  points: np.ndarray) -> float:
    """A speed the keyframed pins may give the cloth at rest at `points` (N, 3), for the
    divergence guard's slack: the hand's motion carried out to twice the distance of the
    farthest point from its pivot (the cloth stretches, and a spun garment flares out)."""
    if motion is None:
        return 0.0
    reach = max(np.linalg.norm(points - c, axis=1).max() for c in motion.pivot)
    return max_surface_speed([SimpleNamespace(keyframes=k) for _, k in moving], 2.0 * reach)


@njit(cache=True, nogil=True)
def move_pins(x, last, motion, t):
    """Pins to their pose at time t (x), their last positions to where they were."""
    if motion is None:
        return
    keys, count, pose = motion.keys, motion.key_count, motion.pose
    for s in range(count.shape[0]):
        pose_at(keys[s], count[s], t, pose[s])
    for i in range(motion.point.shape[0]):
        p, s = motion.point[i], motion.selection[i]
        c, r = motion.pivot[s], pose[s]
        dx = motion.rest[0, i] - c[0]
        dy = motion.rest[1, i] - c[1]
        dz = motion.rest[2, i] - c[2]
        for a in range(3):
            last[a, p] = x[a, p]
            x[a, p] = (c[a] + r[3 * a] * dx + r[3 * a + 1] * dy + r[3 * a + 2] * dz
                       + r[9 + a])


def posed(motion: PinMotion, x: np.ndarray, t: float) -> None:
    """x (3, N) with the pins at their pose at time t (for the initial state)."""
    move_pins(x, x.copy(), motion, float(t))
