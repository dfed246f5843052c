"""Box collider: a point inside the oriented cuboid moves to just outside the nearest face
(SURFACE_OFFSET, as the plane collider keeps), with friction."""
from __future__ import annotations

import numpy as np

from clothjit import njit
from pipeline.scene import Box

KIND = 2
SCENE_TYPE = Box
SURFACE_OFFSET = 1e-4  # distance kept outside the face


def pack(b: Box, data) -> np.ndarray:
    """center (3), rotation R row-major (9), half extents (3), friction."""
    from . import euler_matrix

    return np.array([*b.center, *euler_matrix(b.rotation).ravel(), *b.half_extents,
                     b.friction], dtype=np.float64)


@njit(cache=True, nogil=True, inline="always")
def outside(params, c, x, y, z):
    """(inside, tx, ty, tz): whether (x, y, z) is strictly inside box c, and the point
    SURFACE_OFFSET outside its nearest face (the point itself when it is not inside)."""
    cx, cy, cz = params[c, 0], params[c, 1], params[c, 2]
    dx, dy, dz = x - cx, y - cy, z - cz
    # box coordinates q = R^T (p - center)
    q0 = params[c, 3] * dx + params[c, 6] * dy + params[c, 9] * dz
    q1 = params[c, 4] * dx + params[c, 7] * dy + params[c, 10] * dz
    q2 = params[c, 5] * dx + params[c, 8] * dy + params[c, 11] * dz
    h0, h1, h2 = params[c, 12], params[c, 13], params[c, 14]
    d0, d1, d2 = h0 - abs(q0), h1 - abs(q1), h2 - abs(q2)  # depth below each face pair
    if not (d0 > 0.0 and d1 > 0.0 and d2 > 0.0):
        return False, x, y, z
    out = SURFACE_OFFSET
    if d0 <= d1 and d0 <= d2:  # out through the nearest face
        q0 = h0 + out if q0 >= 0.0 else -h0 - out
    elif d1 <= d2:
        q1 = h1 + out if q1 >= 0.0 else -h1 - out
    else:
        q2 = h2 + out if q2 >= 0.0 else -h2 - out
    tx = cx + params[c, 3] * q0 + params[c, 4] * q1 + params[c, 5] * q2
    ty = cy + params[c, 6] * q0 + params[c, 7] * q1 + params[c, 8] * q2
    tz = cz + params[c, 9] * q0 + params[c, 10] * q1 + params[c, 11] * q2
    return True, tx, ty, tz


@njit(cache=True, nogil=True, inline="always")
def project(params, c, data, x, y, z, lx, ly, lz):
    inside, tx, ty, tz = outside(params, c, x, y, z)
    if not inside:
        return x, y, z
    keep = 1.0 - params[c, 15]
    return lx + keep * (tx - lx), ly + keep * (ty - ly), lz + keep * (tz - lz)
