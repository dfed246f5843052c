"""Cloth points that start inside a collider: moved out before the first step.

A point inside a solid collider at t = 0 would be thrown out by the first collision pass
with the whole penetration depth as one step's displacement (hundreds of m/s). A point is
inside when the collider's own projection moves it (friction 0, as if it had not moved
since the last step), at the collider's pose at t = 0.

When some point starts inside, the free points are moved before the first step, at rest
(the integrators start from zero velocity): alternately every collider projects the
points inside it onto its surface and every enabled spring is brought back towards its
rest length (Jacobi position-based relaxation, pinned points fixed), until no point is
inside and no spring is strained by more than RELAX_STRAIN (5 %). Moving only the points that
were inside would leave the springs at their edge stretched by up to tens of percent,
enough to throw the cloth apart on the first step; the relaxation drapes the cloth
around the collider instead. Spring rest lengths stay those of the flat cloth. Scenes
where no point starts inside are not touched, so they simulate bit for bit as before.

Planes never move a point here: a plane only acts on points that cross it during a step,
so a cloth starting on either side stays there.
"""
from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence

import numpy as np

from pipeline.scene import Box, MeshCollider, Scene, SceneError, Sphere

from .colliders import ColliderTable, collide_all, pack_colliders
from .model import ClothModel
from .reach import clearance


class StartInsideWarning(UserWarning):
    """Cloth points started inside a collider and were moved to its surface."""


def describe(collider: object) -> str:
    """A short name of a collider for messages: its kind and where it is."""
    def v(x) -> str:
        return "[" + ", ".join(f"{c:g}" for c in x) + "]"

    if isinstance(collider, Sphere):
        return f"sphere (origin {v(collider.origin)}, radius {collider.radius:g})"
    if isinstance(collider, Box):
        return f"box (center {v(collider.center)}, half_extents {v(collider.half_extents)})"
    if isinstance(collider, MeshCollider):
        return f"mesh '{collider.path.name}' (translation {v(collider.translation)})"
    return type(collider).__name__.lower()


def still_table(colliders: Sequence[object], points: int = 0) -> ColliderTable:
    """The colliders packed with friction 0, for a cloth of `points` points: their
    projection then puts a point that has not moved since the last step exactly where it
    goes out."""
    return pack_colliders([dataclasses.replace(c, friction=0.0) for c in colliders], points)


def project_out(x: np.ndarray, pinned: np.ndarray, table: ColliderTable,
                t: float = 0.0) -> np.ndarray:
    """Project the free points of x (3, N) that are inside the colliders of `table` (from
    still_table, applied in order, at time t) out, in place; (N,) bool: which moved."""
    before = x.copy()
    collide_all(x, before, pinned, table, t, t)
    return np.any(x != before, axis=0)


RELAX_STRAIN = 0.05  # largest relative spring strain left by the relaxation
RELAX_ITERATIONS = 5000  # at most
RELAX_CHECK, RELAX_PROGRESS = 250, 0.01  # stop where 250 rounds took off less than 1 %
# beyond this strain left after the relaxation the first step throws the cloth apart: refused
UNRESOLVED_STRAIN = 0.5


def resolve_start_inside(scene: Scene, model: ClothModel) -> list[tuple[object, int]]:
    """If points of `model.x0` start inside colliders, move the cloth out (in place, see
    the module docstring) and warn (StartInsideWarning) once per such collider.
    Returns (collider, number of points that started inside it) pairs."""
    found = []
    points = model.x0.T
    for collider in scene.colliders:
        if not collider.keyframes and clearance(collider, points) > 0.0:
            continue  # no point can be inside: skip the projection (and its compilation)
        inside = project_out(model.x0.copy(), model.pinned, still_table([collider], model.n))
        if inside.any():
            found.append((collider, int(inside.sum()), np.nonzero(inside)[0]))
    if not found:
        return found
    strain = _relax(model, still_table(scene.colliders, model.n))
    if strain > UNRESOLVED_STRAIN:
        collider, count, which = found[0]
        raise SceneError(
            f"{scene.source or 'scene'}: {count} cloth point{'s' * (count != 1)} start inside "
            f"the {describe(collider)} ({_points(model, which)}), and the cloth cannot be "
            f"moved out around it: its springs would stay stretched or squeezed by "
            f"{100 * strain:.0f} % (the collider cuts through the cloth's plane); move the "
            "collider or the cloth so that they do not overlap at t = 0")
    found = [(collider, count) for collider, count, _ in found]
    for collider, count in found:
        warnings.warn(f"{count} cloth point{'s' * (count != 1)} started inside the "
                      f"{describe(collider)}: the cloth was moved out around it, at rest, "
                      f"before the first step", StartInsideWarning, stacklevel=3)
    return found


def _points(model: ClothModel, which: np.ndarray, shown: int = 4) -> str:
    """A few of the points `which` as the scene names them: [x_index, y_index] on the grid,
    vertex numbers on a mesh cloth."""
    if model.mesh is None:
        names = [f"[{p % model.nw}, {p // model.nw}]" for p in which[:shown]]
    else:
        names = [str(p) for p in which[:shown]]
    more = f" and {len(which) - shown} more" if len(which) > shown else ""
    return "points " + ", ".join(names) + more


def _relax(model: ClothModel, table: ColliderTable) -> float:
    """Jacobi position-based relaxation of model.x0 (see the module docstring); returns
    the largest spring strain left."""
    on = model.spring_enabled
    a, b, rest = model.spring_a[on], model.spring_b[on], model.spring_rest[on]
    x, n = model.x0, model.n
    free = model.pinned == 0
    degree = np.maximum(np.bincount(a, minlength=n) + np.bincount(b, minlength=n), 1)
    before = np.inf
    for k in range(RELAX_ITERATIONS):
        project_out(x, model.pinned, table)
        d = x[:, b] - x[:, a]
        length = np.sqrt(np.einsum("ij,ij->j", d, d))
        strain = length / rest - 1.0
        worst = float(np.abs(strain).max())
        if worst <= RELAX_STRAIN:
            return worst
        if k % RELAX_CHECK == 0:  # stalled (no side to drape to): no use going on
            if worst > (1.0 - RELAX_PROGRESS) * before:
                break
            before = worst
        half = 0.5 * d * (strain / np.maximum(length / rest, 1e-12))  # along d, to rest
        for k in range(3):
            corr = np.bincount(a, half[k], n) - np.bincount(b, half[k], n)
            x[k, free] += (corr / degree)[free]
    project_out(x, model.pinned, table)
    d = x[:, b] - x[:, a]
    return float(np.abs(np.sqrt(np.einsum("ij,ij->j", d, d)) / rest - 1.0).max())
