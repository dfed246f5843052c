"""Provot's stretch limit (SPEC section 2, step 5): Gauss-Seidel over the spring list."""
from __future__ import annotations

import numpy as np
from numba import njit

from .model import DIRECTION_DI, DIRECTION_DJ

_DI = DIRECTION_DI
_DJ = DIRECTION_DJ

STRETCH_LIMIT = 1.1  # a spring may reach 110 % of its rest length


@njit(cache=True, nogil=True)
def limit_stretch(x, nw, exists, limit, limit_sq_lo, pinned):
    """Shorten every spring longer than `limit` (= 1.1 rest) to `limit`, in list order.

    Half the correction goes to each end, all of it to the free end if one end is pinned.
    `limit_sq_lo` is a slightly lowered limit**2: springs below it are skipped without a square
    root; the others take the exact test `length > limit`, so the filter never changes a bit.
    """
    n = x.shape[1]
    for p in range(n):
        pa = pinned[p] != 0
        for d in range(6):
            if not exists[d, p]:
                continue
            q = p + _DI[d] * nw + _DJ[d]
            pb = pinned[q] != 0
            if pa and pb:
                continue
            dx = x[0, q] - x[0, p]
            dy = x[1, q] - x[1, p]
            dz = x[2, q] - x[2, p]
            length_sq = dx * dx + dy * dy + dz * dz
            if length_sq <= limit_sq_lo[d, p]:
                continue
            length = np.sqrt(length_sq)
            lim = limit[d, p]
            if not length > lim:
                continue
            s = length - lim
            cx = (dx / length) * s
            cy = (dy / length) * s
            cz = (dz / length) * s
            if not pa and not pb:
                x[0, p] += 0.5 * cx
                x[1, p] += 0.5 * cy
                x[2, p] += 0.5 * cz
                x[0, q] -= 0.5 * cx
                x[1, q] -= 0.5 * cy
                x[2, q] -= 0.5 * cz
            elif pa:
                x[0, q] -= cx
                x[1, q] -= cy
                x[2, q] -= cz
            else:
                x[0, p] += cx
                x[1, p] += cy
                x[2, p] += cz


def stretch_limits(rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(limit, limit_sq_lo) arrays for `limit_stretch` from the rest lengths (6, N)."""
    limit = STRETCH_LIMIT * rest
    return limit, limit * limit * (1.0 - 1e-9)
