"""Wind on a mesh cloth: pipeline.physics.wind's air field and per-triangle drag and lift
(the same formulas, float32 per point and per triangle as there), over the mesh's triangles
instead of the grid's bands.

Three parallel loops: the air velocity relative to each point, each triangle's per-vertex
force, then each point adds the forces of its triangles in incidence order (float64), so
the result does not depend on the number of threads.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from clothjit import njit, prange

from .forces import CHUNKS, _chunk
from .mesh_model import incidence
from .wind import GUST_MODES, _F0, _FAST, _gust, _mode_tuples, _moving_air, _set_phases, _triangle


class MeshWind(NamedTuple):
    """The wind packed for a mesh cloth (System.wind): still air has `on` False."""

    on: bool
    gusty: bool
    velocity: np.ndarray  # (3,) base wind U, m/s
    drag: float  # rho C_D / 108
    lift: float  # rho C_L / 108
    modes: np.ndarray  # (8, GUST_MODES) as wind.WindParams.modes
    phase: np.ndarray  # (GUST_MODES,) float32 scratch
    triangles: np.ndarray  # (T, 3) int64
    start: np.ndarray  # (N + 1,) int64: point p's triangles are slot[start[p]:start[p + 1]]
    slot: np.ndarray  # (3 T,) int64 triangle indices
    relative: np.ndarray  # (3, N) float32 scratch: velocity minus air velocity
    force: np.ndarray  # (3, T) float32 scratch: each triangle's per-vertex force


def pack_mesh_wind(wind, seed: int, triangles: np.ndarray, n: int) -> MeshWind:
    """The scene's `Wind` (or still air for None) for a mesh cloth of n points."""
    tris = np.ascontiguousarray(triangles, dtype=np.int64)
    start, rows = incidence(tris.reshape(-1), n)
    if wind is None:
        return MeshWind(False, False, np.zeros(3), 0.0, 0.0, np.zeros((8, GUST_MODES), order="F"),
                        np.zeros(GUST_MODES, np.float32), tris[:0], np.zeros(1, np.int64),
                        np.zeros(0, np.int64), np.zeros((3, 0), np.float32),
                        np.zeros((3, 0), np.float32))
    air = _moving_air(wind, seed, 0, 1, 1)  # the grid's gusts for the same seed
    return MeshWind(True, air.gusty, air.velocity, air.drag, air.lift, air.modes,
                    air.phase, tris, start, rows // 3, np.zeros((3, n), np.float32),
                    np.zeros((3, len(tris)), np.float32))


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, no_cpython_wrapper=True)
def _relative(x, v, w, lo, hi):
    """w.relative[:, p] = v - air velocity at the points p in [lo, hi) (float32). Apart
    from the parallel loop: numba's parallel loops cannot take the modes' tuples."""
    rel = w.relative
    ux, uy, uz = w.velocity[0], w.velocity[1], w.velocity[2]
    modes = _mode_tuples(w)
    ox, oy, oz = x[0, 0], x[1, 0], x[2, 0]
    for p in range(lo, hi):
        gx = gy = gz = _F0
        if w.gusty:
            gx, gy, gz = _gust(np.float32(x[0, p] - ox), np.float32(x[1, p] - oy),
                               np.float32(x[2, p] - oz), modes)
        rel[0, p] = np.float32(v[0, p] - ux) - gx
        rel[1, p] = np.float32(v[1, p] - uy) - gy
        rel[2, p] = np.float32(v[2, p] - uz) - gz


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST, parallel=True)
def _mesh_wind(x, v, w, f):
    n, tris, rel, force = x.shape[1], w.triangles, w.relative, w.force
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        _relative(x, v, w, lo, hi)
    drag, lift = np.float32(w.drag), np.float32(w.lift)
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, tris.shape[0])
        for t in range(lo, hi):
            a, b, d = tris[t, 0], tris[t, 1], tris[t, 2]
            fx, fy, fz = _triangle(
                np.float32(x[0, b] - x[0, a]), np.float32(x[1, b] - x[1, a]),
                np.float32(x[2, b] - x[2, a]), np.float32(x[0, d] - x[0, a]),
                np.float32(x[1, d] - x[1, a]), np.float32(x[2, d] - x[2, a]),
                rel[0, a] + rel[0, b] + rel[0, d], rel[1, a] + rel[1, b] + rel[1, d],
                rel[2, a] + rel[2, b] + rel[2, d], drag, lift)
            force[0, t], force[1, t], force[2, t] = fx, fy, fz
    start, slot = w.start, w.slot
    for c in prange(CHUNKS):
        lo, hi = _chunk(c, n)
        for p in range(lo, hi):
            for j in range(start[p], start[p + 1]):
                t = slot[j]
                f[0, p] += force[0, t]
                f[1, p] += force[1, t]
                f[2, p] += force[2, t]


@njit(cache=True, nogil=True, pointer=True)
def add_mesh_wind_force(x, v, t, w, f):
    """wind.add_wind_force for a mesh cloth: f += the aerodynamic force at positions x,
    velocities v (3, N), time t (s)."""
    if not w.on:
        return
    _set_phases(w, t, x[0, 0], x[1, 0], x[2, 0])
    _mesh_wind(x, v, w, f)
