"""Forces of the classic model: gravity on every point plus Hooke's law along every enabled
spring (SPEC section 2, step 1). One kernel, shared by every integrator.

Positions and forces are structure-of-arrays, shape (3, N). Springs are walked point by point
in row-major order and, per point, in direction order, accumulating into both ends exactly as
the course code does, so the result is bit-identical to a scalar reference.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .model import DIRECTION_DI, DIRECTION_DJ

_DI = DIRECTION_DI
_DJ = DIRECTION_DJ


@njit(cache=True, nogil=True)
def spring_forces(x, nw, exists, rest, stiffness, mass, gravity, f):
    """f[:] = mass * gravity + sum of spring forces at positions x (3, N)."""
    n = x.shape[1]
    gx, gy, gz = mass * gravity[0], mass * gravity[1], mass * gravity[2]
    for p in range(n):
        f[0, p] = gx
        f[1, p] = gy
        f[2, p] = gz
    for p in range(n):
        for d in range(6):
            k = stiffness[d]
            if k == 0.0 or not exists[d, p]:
                continue
            q = p + _DI[d] * nw + _DJ[d]
            dx = x[0, q] - x[0, p]
            dy = x[1, q] - x[1, p]
            dz = x[2, q] - x[2, p]
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            if not length > 0.0:
                continue  # direction undefined: no force
            s = k * (length - rest[d, p])
            fx = (dx / length) * s
            fy = (dy / length) * s
            fz = (dz / length) * s
            f[0, p] += fx
            f[1, p] += fy
            f[2, p] += fz
            f[0, q] -= fx
            f[1, q] -= fy
            f[2, q] -= fz
