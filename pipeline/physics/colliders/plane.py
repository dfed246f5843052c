"""Plane collider: a point that changed side since the last step goes back to just above it."""
from __future__ import annotations

import math

import numpy as np

from clothjit import njit
from pipeline.scene import Plane

KIND = 1
SCENE_TYPE = Plane
SURFACE_OFFSET = 1e-4  # distance kept from the plane on the side the point came from


def pack(p: Plane, data) -> np.ndarray:
    nx, ny, nz = p.normal
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    return np.array(
        [*p.point, nx / length, ny / length, nz / length, p.friction], dtype=np.float64
    )


@njit(cache=True, nogil=True, inline="always")
def _sign(v):
    return (v > 0.0) - (v < 0.0)


@njit(cache=True, nogil=True, inline="always")
def project(params, c, data, x, y, z, lx, ly, lz):
    px, py, pz = params[c, 0], params[c, 1], params[c, 2]
    nx, ny, nz, friction = params[c, 3], params[c, 4], params[c, 5], params[c, 6]
    s_now = (x - px) * nx + (y - py) * ny + (z - pz) * nz
    s_last = (lx - px) * nx + (ly - py) * ny + (lz - pz) * nz
    side_now, side_last = _sign(s_now), _sign(s_last)
    if side_now == side_last:
        return x, y, z
    side = side_last if side_last != 0 else -side_now
    off = SURFACE_OFFSET * side
    tx = (x - s_now * nx) + off * nx
    ty = (y - s_now * ny) + off * ny
    tz = (z - s_now * nz) + off * nz
    keep = 1.0 - friction
    return lx + keep * (tx - lx), ly + keep * (ty - ly), lz + keep * (tz - lz)
