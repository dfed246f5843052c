"""Static colliders (SPEC section 2, step 4).

A collider kind is one module in this package defining:
    KIND: int           its code in the packed table,
    SCENE_TYPE: type    the scene dataclass it packs,
    pack(obj) -> np.ndarray   its parameters as floats (at most PARAMS_WIDTH),
    project(params, c, x, y, z, lx, ly, lz) -> (x, y, z)   an @njit point projection
                        reading its parameters from row c of the packed table.
The packed table (kinds, params) lists the scene's colliders in scene order, and
`collide_point` applies them in that order to one point. Adding a kind: its module, plus its
entry in `_KINDS` and one branch in `collide_point` (numba compiles static dispatch only).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from . import plane, sphere

PARAMS_WIDTH = 8
_KINDS = (sphere, plane)
_BY_TYPE = {kind.SCENE_TYPE: kind for kind in _KINDS}


def pack_colliders(colliders: Sequence[object]) -> tuple[np.ndarray, np.ndarray]:
    """(kinds int64 (C,), params float64 (C, PARAMS_WIDTH)) for the kernels, in scene order."""
    kinds = np.zeros(len(colliders), dtype=np.int64)
    params = np.zeros((len(colliders), PARAMS_WIDTH), dtype=np.float64)
    for c, obj in enumerate(colliders):
        module = _BY_TYPE[type(obj)]
        kinds[c] = module.KIND
        values = module.pack(obj)
        params[c, : len(values)] = values
    return kinds, params


@njit(cache=True, nogil=True, inline="always")
def collide_point(kinds, params, x, y, z, lx, ly, lz):
    """Apply every collider, in order, to the point at (x, y, z) that was at (lx, ly, lz)."""
    for c in range(kinds.shape[0]):
        kind = kinds[c]
        if kind == sphere.KIND:
            x, y, z = sphere.project(params, c, x, y, z, lx, ly, lz)
        elif kind == plane.KIND:
            x, y, z = plane.project(params, c, x, y, z, lx, ly, lz)
    return x, y, z


@njit(cache=True, nogil=True)
def collide_all(x, last, pinned, kinds, params):
    """Apply the colliders to every free point of x (3, N)."""
    if kinds.shape[0] == 0:
        return
    for p in range(x.shape[1]):
        if pinned[p]:
            continue
        x[0, p], x[1, p], x[2, p] = collide_point(
            kinds, params, x[0, p], x[1, p], x[2, p], last[0, p], last[1, p], last[2, p]
        )
