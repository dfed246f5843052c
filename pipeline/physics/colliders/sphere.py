"""Sphere collider: a point inside is moved to the surface along the radius, with friction."""
from __future__ import annotations

import numpy as np

from clothjit import njit
from pipeline.scene import Sphere

KIND = 0
SCENE_TYPE = Sphere


def pack(s: Sphere, data) -> np.ndarray:
    return np.array([*s.origin, s.radius, s.friction], dtype=np.float64)


@njit(cache=True, nogil=True, inline="always")
def project(params, c, data, x, y, z, lx, ly, lz):
    ox, oy, oz = params[c, 0], params[c, 1], params[c, 2]
    r, friction = params[c, 3], params[c, 4]
    dx, dy, dz = x - ox, y - oy, z - oz
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    if dist <= r and dist > 0.0:
        tx = ox + r * (dx / dist)
        ty = oy + r * (dy / dist)
        tz = oz + r * (dz / dist)
        keep = 1.0 - friction
        return lx + keep * (tx - lx), ly + keep * (ty - ly), lz + keep * (tz - lz)
    return x, y, z
