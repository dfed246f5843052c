"""Whether keyframed pins leave Provot's stretch limit a state to keep.

Under the limit, two points can be no further apart than the limits (1.1 x rest) summed
along the shortest path of limited springs between them. Pins held further apart than that
leave no state within the limit: every step the limit then pulls the cloth towards one it
cannot reach, about a spring's excess at a time, and under robust contact it presses the
layers together faster than the contact can hold them apart (a cloth wrung into a rope by
two turning hands). Under robust contact the Simulation stops the limit from the first frame
that ends with its pins so, and says so (`LimitStop.note`); the springs then hold the cloth.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .pin_motion import PinMotion, posed

MAX_PINS = 512  # pinned points compared, evenly chosen from a larger set


class LimitReach(NamedTuple):
    """The pinned points of a mesh cloth with keyframed pins and how far apart the limit
    lets each two of them be."""

    points: np.ndarray  # (P,) int64 the pinned points
    reach: np.ndarray  # (P, P) the limits summed along the shortest path between them
    motion: PinMotion


class LimitStop(NamedTuple):
    """Where the pins first held two points beyond the limit's reach."""

    frame: int  # the first frame simulated without the limit (1: the first step on)
    time: float  # its end, s
    points: tuple[int, int]
    distance: float  # m, at `time`
    reach: float  # m

    @property
    def note(self) -> str:
        p, q = self.points
        return (f"Provot's stretch limit stopped from frame {self.frame}: at t = "
                f"{self.time:.3f} s the pins hold points {p} and {q} {self.distance:.4g} m "
                f"apart, beyond the {self.reach:.4g} m the limit lets the cloth between "
                "them reach, so no state keeps it; the springs alone hold the cloth from "
                "there")


def limit_watch(system) -> LimitReach | None:
    """The LimitReach a System's run watches: a mesh cloth under robust contact whose
    keyframed pins may pull beyond Provot's limit (contact comes first: the limit stops
    there), else None."""
    s = system
    if s.contact is None or not s.stretch_limit or s.pin_motion is None:
        return None
    structural = s.springs.structural
    return limit_reach(s.pinned, s.springs.ends[:, :structural], s.limit[0, :structural],
                       s.pin_motion)


def limit_reach(pinned: np.ndarray, ends: np.ndarray, limit: np.ndarray,
                motion: PinMotion | None) -> LimitReach | None:
    """The LimitReach of a cloth whose springs (ends (2, S) int, limits (S,)) the limit
    acts on, pinned where `pinned` (N,) is non-zero; None where no pin moves (pins at rest
    are within reach of each other) or fewer than two points are pinned."""
    points = np.flatnonzero(pinned)
    if motion is None or len(points) < 2:
        return None
    points = points[::-(-len(points) // MAX_PINS)]  # evenly, MAX_PINS at most
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    n = len(pinned)
    graph = coo_matrix((limit, (ends[0], ends[1])), shape=(n, n)).tocsr()
    reach = dijkstra(graph, directed=False, indices=points)[:, points]
    # pins that move as one (a selection's, or those at rest) keep their distances
    group = np.full(n, -1, dtype=np.int64)
    group[motion.point] = motion.selection
    same = group[points][:, None] == group[points][None, :]
    reach[same] = np.inf
    return LimitReach(points, np.ascontiguousarray(reach), motion)


def beyond_reach(r: LimitReach, x: np.ndarray, t: float) -> tuple[int, int, float, float] | None:
    """The pinned pair furthest beyond the limit's reach with the pins posed at time t on a
    copy of x (3, N), as (p, q, distance, reach); None if every pair is within it."""
    from scipy.spatial.distance import cdist

    at = x.copy()
    posed(r.motion, at, t)
    pins = at[:, r.points].T
    distance = cdist(pins, pins)
    excess = distance - r.reach  # unconnected pairs: reach inf
    i, j = np.unravel_index(np.argmax(excess), excess.shape)
    if not excess[i, j] > 0.0:
        return None
    return int(r.points[i]), int(r.points[j]), float(distance[i, j]), float(r.reach[i, j])
